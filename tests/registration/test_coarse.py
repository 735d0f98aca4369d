"""Prerejective RANSAC: recovers a known transform from noisy feature matches, reproducibly, with
PCL's polygon pre-rejection and Umeyama estimate checked against analytic cases."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.errors import InputError, RegistrationError
from semslam.registration import align_prerejective
from semslam.registration import _coarse_kernels as K


def _problem(seed=0, n_target=1500, n_source=700, outlier_share=0.5):
    rng = np.random.default_rng(seed)
    tgt = rng.uniform(-0.2, 0.2, (n_target, 3))
    ft = rng.normal(size=(n_target, 33))
    R = Rotation.from_euler("zyx", [50, 20, -30], degrees=True).as_matrix()
    t = np.array([0.3, -0.1, 0.5])
    idx = rng.choice(n_target, n_source, replace=False)
    src = (tgt[idx] - t) @ R + rng.normal(0, 0.001, (n_source, 3))  # p_target = R p_source + t
    fs = ft[idx] + rng.normal(0, 0.3, (n_source, 33))
    bad = rng.random(n_source) < outlier_share
    fs[bad] = rng.normal(size=(int(bad.sum()), 33))
    return src, fs, tgt, ft, R, t


def test_recovers_known_transform():
    src, fs, tgt, ft, R, t = _problem()
    res = align_prerejective(src, fs, tgt, ft, max_iterations=3000, k_correspondences=2, similarity=0.9,
                             max_correspondence_m=0.005, inlier_fraction=0.25, seed=1)
    assert res.converged
    assert res.fitness > 0.95
    T = res.T_target_source
    assert Rotation.from_matrix(T.rotation.T @ R).magnitude() < np.radians(0.5)
    assert np.linalg.norm(T.translation_m - t) < 0.003
    assert res.inlier_rmse_m < 0.003
    assert res.extras["n_prerejected"] > 0  # the polygon test did reject wrong samples


def test_seeded_and_reproducible():
    src, fs, tgt, ft, *_ = _problem(seed=3)
    kw = dict(max_iterations=500, k_correspondences=3, similarity=0.8, max_correspondence_m=0.005, inlier_fraction=0.1)
    a = align_prerejective(src, fs, tgt, ft, seed=7, **kw)
    b = align_prerejective(src, fs, tgt, ft, seed=7, **kw)
    np.testing.assert_array_equal(a.T_target_source.matrix, b.T_target_source.matrix)
    assert a.fitness == b.fitness


def test_msac_selection_and_early_stop():
    src, fs, tgt, ft, R, t = _problem(seed=4)
    res = align_prerejective(src, fs, tgt, ft, max_iterations=20000, k_correspondences=2, similarity=0.9,
                             max_correspondence_m=0.005, inlier_fraction=0.25, seed=2, selection="msac",
                             stop_fraction=0.9, batch_size=256)
    assert res.converged and res.fitness >= 0.9
    assert res.n_iterations < 20000
    # a 3-point estimate (no refit on the inliers, as PCL): centimetre-level, not millimetre-level
    assert np.linalg.norm(res.T_target_source.translation_m - t) < 0.01
    assert Rotation.from_matrix(res.T_target_source.rotation.T @ R).magnitude() < np.radians(3)


def test_no_consensus_returns_not_converged_with_centroid_guess():
    rng = np.random.default_rng(5)
    src, tgt = rng.uniform(-1, 1, (200, 3)), rng.uniform(-1, 1, (200, 3)) + 5.0
    res = align_prerejective(src, rng.normal(size=(200, 8)), tgt, rng.normal(size=(200, 8)), max_iterations=200,
                             max_correspondence_m=0.001, inlier_fraction=0.9, seed=0, init_T="centroid")
    assert not res.converged
    np.testing.assert_allclose(res.T_target_source.translation_m, tgt.mean(0) - src.mean(0))


def test_umeyama_batch_exact_on_noise_free_points():
    rng = np.random.default_rng(6)
    R = Rotation.random(5, random_state=1).as_matrix()
    t = rng.normal(size=(5, 3))
    src = rng.normal(size=(5, 4, 3))
    tgt = np.einsum("bij,bnj->bni", R, src) + t[:, None]
    R_est, t_est = K.umeyama_batch(src, tgt)
    np.testing.assert_allclose(R_est, R, atol=1e-10)
    np.testing.assert_allclose(t_est, t, atol=1e-10)


def test_polygon_prerejection_matches_definition():
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], float)
    same = tri @ Rotation.from_euler("z", 40, degrees=True).as_matrix().T + 3.0
    stretched = tri * np.array([1.5, 1.0, 1.0])  # edge 0-1 ratio 1/1.5 = 0.667
    assert K.polygon_similar(tri, same, 0.99)[0]
    assert K.polygon_similar(tri, stretched, 0.6)[0]
    assert not K.polygon_similar(tri, stretched, 0.7)[0]


def test_sample_distinct_rows():
    idx = K.sample_distinct(np.random.default_rng(0), 5, 2000, 3)
    assert idx.shape == (2000, 3)
    assert (np.diff(idx, axis=1) > 0).all() and idx.min() >= 0 and idx.max() < 5


def test_bad_inputs_raise_named_errors():
    src, fs, tgt, ft, *_ = _problem(n_target=50, n_source=20)
    with pytest.raises(InputError, match="target_features"):
        align_prerejective(src, fs[:, :5], tgt, ft)
    with pytest.raises(InputError, match="source_features"):
        align_prerejective(src, fs[:5], tgt, ft)
    with pytest.raises(InputError, match="similarity"):
        align_prerejective(src, fs, tgt, ft, similarity=1.5)
    with pytest.raises(InputError, match="selection"):
        align_prerejective(src, fs, tgt, ft, selection="msac")  # needs a finite distance
    fs_nan = fs.copy()
    fs_nan[2:] = np.nan
    with pytest.raises(RegistrationError, match="finite features"):
        align_prerejective(src, fs_nan, tgt, ft)


# -- global grid search (semslam.pose.search): kernels against brute force ----------------------

from semslam.pose import _search_kernels as SK  # noqa: E402
from semslam.pose.search import (  # noqa: E402
    DistanceField, RangeImage, pairwise_rotation_distances, so3_grid)
from semslam.symmetry import Symmetry  # noqa: E402


def test_so3_grid_is_rotations_and_covers_so3():
    G = so3_grid(4096)
    np.testing.assert_allclose(np.einsum("kji,kjl->kil", G, G), np.broadcast_to(np.eye(3), G.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(G), 1.0, atol=1e-12)
    probe = Rotation.random(300, random_state=0).as_matrix()
    d = pairwise_rotation_distances(probe, G, Symmetry())  # angle between probe and grid rotations
    assert np.degrees(d.min(axis=1).max()) < 15.0  # covering radius of 4096 rotations ~ 10-13 degrees
    np.testing.assert_array_equal(so3_grid(64), so3_grid(64))


def test_distance_field_nearest_matches_brute_force():
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    model = rng.uniform(-0.05, 0.05, (400, 3))
    f = DistanceField.build(model, cell_m=0.004, margin_m=0.02, truncation_m=0.02)
    q = rng.uniform(-0.06, 0.06, (500, 3))
    got = f.nearest_points(q)
    ijk = np.floor((q - f.origin) / f.cell_m).astype(int)
    centres = f.origin + (ijk + 0.5) * f.cell_m
    d, j = cKDTree(model).query(centres)
    inside = (ijk >= 0).all(axis=1) & (ijk < f.offsets.shape[:3]).all(axis=1) & (d <= 0.02)
    assert inside.sum() > 300
    np.testing.assert_allclose(got[inside], model[j[inside]], atol=f.quantum_m)  # int8 quantisation
    assert np.isnan(got[~inside]).all()


def test_translation_alignment_recovers_offset():
    rng = np.random.default_rng(1)
    d = rng.normal(size=(4000, 3))
    model = 0.03 * d / np.linalg.norm(d, axis=1, keepdims=True) * [1.0, 0.7, 0.5]  # an ellipsoid's surface
    f = DistanceField.build(model, cell_m=0.002)
    src = model[model[:, 2] > 0][::10] - [0.006, -0.004, 0.003]  # a partial view; truth t = (6, -4, 3) mm
    Rs = np.eye(3)[None].copy()
    ts = np.zeros((1, 3))
    cost = SK.align_and_score(Rs, ts, src, f.params, f.cell_m, f.offsets, np.array([0.03] * 5 + [0.01] * 25), 0.006)
    np.testing.assert_allclose(ts[0], [0.006, -0.004, 0.003], atol=0.0005)
    assert cost[0] < 0.1


def _visibility_brute(R, t, pts, nrm, img: RangeImage, tol):
    n_front = n_bad = 0
    for p, n in zip(pts, nrm):
        ps, ns = R.T @ (p - t), R.T @ n
        r = ps - img.viewpoint
        if ns @ r >= 0:
            continue
        n_front += 1
        q = img.F @ r
        if q[2] <= 1e-9:
            n_bad += 1
            continue
        i, j = int(np.floor((q[0] / q[2] - img.u0) / img.cell)), int(np.floor((q[1] / q[2] - img.v0) / img.cell))
        if not (0 <= i < img.range_min.shape[0] and 0 <= j < img.range_min.shape[1]):
            n_bad += 1
        elif not np.isfinite(img.range_min[i, j]) or np.linalg.norm(r) < img.range_min[i, j] - tol:
            n_bad += 1
    return n_bad / max(n_front, 1)


def test_visibility_cost_matches_brute_force_and_separates_a_flip():
    rng = np.random.default_rng(2)
    # a model: a half-sphere cap (object frame) seen from +z; its scan from a scanner 0.8 m above
    d = rng.normal(size=(1500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:, 2] = np.abs(d[:, 2])
    model, normals = 0.04 * d, d
    T_os = np.eye(4)  # scanner frame: object 0.8 m along +z, scanner looking down the object's -z
    T_os[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T_os[:3, 3] = [0.0, 0.0, 0.8]
    scan = (model[model[:, 2] > 0.005] - T_os[:3, 3]) @ T_os[:3, :3]  # R^T (p - t)
    img = RangeImage.build(scan, np.zeros(3), cell_m=0.006)
    flip = T_os.copy()
    flip[:3, :3] = np.diag([1.0, 1.0, 1.0]) @ T_os[:3, :3] @ np.diag([1.0, -1.0, -1.0])
    Rs = np.stack([T_os[:3, :3], flip[:3, :3]])
    ts = np.stack([T_os[:3, 3], flip[:3, 3]])
    got = img.visibility_cost(Rs, ts, model, normals, 0.01)
    want = [_visibility_brute(Rs[k], ts[k], model, normals, img, 0.01) for k in range(2)]
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert got[0] < 0.1 and got[1] > 0.5  # the true pose explains the scan; the flipped one does not


def test_pairwise_rotation_distances_match_symmetry_errors():
    R = Rotation.random(20, random_state=3).as_matrix()
    for sym in (Symmetry(), Symmetry("discrete", axis_object=[0, 1, 0], order=2),
                Symmetry("continuous", axis_object=[0, 0, 1])):
        D = pairwise_rotation_distances(R, R[::-1], sym)
        # rotations of T_object_scanner: object orientations are the transposes
        want = np.array([[sym.rotation_error_rad(a.T, b.T) for b in R[::-1]] for a in R])
        np.testing.assert_allclose(D, want, atol=1e-6)


# -- coarse-to-fine rotation grid, ICP candidates of the distance field, numba ICP ------------------------

def test_rotation_hierarchy_parents_are_nearest_coarse_rotations():
    from semslam.pose.search import RotationHierarchy

    fine = so3_grid(512)
    h = RotationHierarchy.build(fine, 64)
    assert len(h.coarse) == 64 and h.offsets[-1] == 512
    np.testing.assert_array_equal(np.sort(h.children), np.arange(512))  # a partition of the fine grid
    parent = np.empty(512, int)
    for c in range(64):
        parent[h.children[h.offsets[c]:h.offsets[c + 1]]] = c
    d = pairwise_rotation_distances(fine, h.coarse, Symmetry())  # brute force: nearest coarse rotation
    np.testing.assert_allclose(d[np.arange(512), parent], d.min(axis=1), atol=1e-9)
    np.testing.assert_array_equal(h.children_of(np.array([3, 1])),
                                  np.sort(np.concatenate([h.children[h.offsets[c]:h.offsets[c + 1]] for c in (1, 3)])))


def test_distance_field_icp_candidates_hold_the_nearest_points():
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(2)
    model = rng.uniform(-0.05, 0.05, (600, 3))
    f = DistanceField.build(model, cell_m=0.004, margin_m=0.02, truncation_m=0.02, n_index=8)
    assert f.index.shape == (*f.offsets.shape[:3], 8)
    ijk = np.indices(f.offsets.shape[:3]).reshape(3, -1).T
    centres = f.origin + (ijk + 0.5) * f.cell_m
    d, j = cKDTree(model).query(centres, k=8)
    cand = f.index.reshape(-1, 8)
    near = d[:, 7] <= 0.02  # all 8 within the bound: the candidates are exactly the 8 nearest, nearest first
    assert near.sum() > 1000
    np.testing.assert_array_equal(cand[near], j[near])
    none = d[:, 0] > 0.02 + np.sqrt(3) * 0.004
    assert (cand[none] == -1).all()


@pytest.mark.parametrize("rot_deg, trans_m", [(3.0, 0.004), (8.0, 0.01)])
def test_field_icp_recovers_a_known_motion_like_small_gicp(rot_deg, trans_m):
    import small_gicp

    from semslam.registration._icp_kernels import icp_plane_field

    rng = np.random.default_rng(3)
    d = rng.normal(size=(20000, 3))
    model = 0.04 * d / np.linalg.norm(d, axis=1, keepdims=True) * [1.0, 0.6, 0.4]  # an ellipsoid's surface
    cloud = small_gicp.PointCloud(model)
    tree = small_gicp.KdTree(cloud)
    small_gicp.estimate_normals(cloud, tree, num_neighbors=15)
    normals = np.ascontiguousarray(cloud.normals()[:, :3])
    f = DistanceField.build(model, cell_m=0.0025)
    T_true = np.eye(4)  # T_target_source
    T_true[:3, :3] = Rotation.from_rotvec(np.radians(rot_deg) * np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])).as_matrix()
    T_true[:3, 3] = trans_m * np.array([0.6, 0.0, -0.8])
    part = model[(model[:, 2] > 0) & (model[:, 0] > -0.02)][::7]  # a partial view, in the target frame
    src = (part - T_true[:3, 3]) @ T_true[:3, :3]  # the same points in the source frame
    T, n_it, converged, n_pairs = icp_plane_field(src, np.eye(4), f.params, f.index, model, normals, 0.02, 50,
                                                  1e-4, 1e-5)
    assert converged and n_pairs == len(src)
    ref = small_gicp.align(cloud, small_gicp.PointCloud(src), tree, init_T_target_source=np.eye(4),
                           registration_type="PLANE_ICP", max_correspondence_distance=0.02, num_threads=1,
                           max_iterations=50)
    for M in (T, np.array(ref.T_target_source)):
        np.testing.assert_allclose(M[:3, 3], T_true[:3, 3], atol=5e-4)
        assert np.degrees(Rotation.from_matrix(M[:3, :3] @ T_true[:3, :3].T).magnitude()) < 0.5
