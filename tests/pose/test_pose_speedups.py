"""Exactness of the pose and voxel-grid speed-ups: the analytic covariance Jacobian against central
differences, the greedy distinct-hypothesis selection, RadiusGrid against cKDTree, the radix argsort."""

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.pose.covariance import _xyz_rpy_covariance_of_inverse_numeric, xyz_rpy_covariance_of_inverse
from semslam.pose.search import _greedy_distinct, pairwise_rotation_distances
from semslam.symmetry import Symmetry


def test_analytic_matches_central_differences():
    rng = np.random.default_rng(0)
    for seed in range(200):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=seed).as_matrix()
        T[:3, 3] = rng.normal(size=3)
        M = rng.normal(size=(6, 6))
        C = M @ M.T * 1e-3
        got = xyz_rpy_covariance_of_inverse(T, C)
        ref = _xyz_rpy_covariance_of_inverse_numeric(T, C, 1e-6)
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-7 * np.abs(ref).max())


def test_near_gimbal_lock_falls_back_to_numeric():
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", [0.3, np.pi / 2 - 1e-5, 0.2]).as_matrix().T  # inverse near pitch 90 deg
    C = np.eye(6) * 1e-4
    got = xyz_rpy_covariance_of_inverse(T, C)
    assert np.isfinite(got).all()
    np.testing.assert_array_equal(got, _xyz_rpy_covariance_of_inverse_numeric(T, C, 1e-6))


def _greedy_full(Rs, sym, sep, n_keep):
    D = pairwise_rotation_distances(Rs, Rs, sym)
    kept = []
    for i in range(len(Rs)):
        if kept and D[i, kept].min() < sep:
            continue
        kept.append(i)
        if len(kept) >= n_keep:
            break
    return kept


def test_greedy_distinct_equals_full_matrix():
    rng = np.random.default_rng(1)
    for sym in (Symmetry(), Symmetry("continuous", np.array([0.0, 0.0, 1.0])),
                Symmetry("discrete", np.array([0.0, 0.0, 1.0]), 4)):
        for spread in (0.05, 0.3, 3.0):  # clustered orientations force the fallback to the whole matrix
            base = Rotation.random(random_state=2)
            Rs = (base * Rotation.from_rotvec(rng.normal(scale=spread, size=(150, 3)))).as_matrix()
            for n_keep in (1, 4, 10):
                assert _greedy_distinct(Rs, sym, np.radians(20.0), n_keep, head=16) == \
                    _greedy_full(Rs, sym, np.radians(20.0), n_keep)


def test_radius_grid_equals_ckdtree():
    from scipy.spatial import cKDTree

    from semslam.pose.search import RadiusGrid

    rng = np.random.default_rng(3)
    model = rng.normal(size=(3000, 3))
    model = 0.1 * model / np.linalg.norm(model, axis=1, keepdims=True)  # a sphere surface, 10 cm radius
    grid, tree = RadiusGrid.build(model, 0.006), cKDTree(model)
    queries = np.vstack([model[rng.integers(0, len(model), 2000)] + rng.normal(scale=0.004, size=(2000, 3)),
                         rng.normal(scale=0.3, size=(200, 3))])  # near the surface, and far outside the grid
    for bound in (0.006, 0.003):
        d_ref, j_ref = tree.query(queries, k=1, distance_upper_bound=bound)
        d, j = grid.query(queries, bound)
        assert 0 < np.isfinite(d_ref).sum() < len(queries)
        np.testing.assert_array_equal(d, d_ref)
        np.testing.assert_array_equal(j, j_ref)
    assert RadiusGrid.build(model * 1e3, 0.006) is None  # too many cells: the caller keeps the KD-tree


def test_voxel_radix_argsort_is_a_stable_sort():
    from semslam.segmentation._voxel_kernels import radix_argsort

    rng = np.random.default_rng(4)
    for high in (1, 50, 70_000, 2**33, 2**50):  # 1, 2, 3 and 4 passes of 16 bits
        keys = rng.integers(0, high, size=5000).astype(np.int64)
        order, sorted_keys = radix_argsort(keys, int(keys.max()))
        np.testing.assert_array_equal(order, np.argsort(keys, kind="stable"))
        np.testing.assert_array_equal(sorted_keys, keys[order])


# -- latency pass 3: pruned nearest-point search, tabulated field lookups, one-pass range image, batched ICP --------

def _lattice_model(rng, n=3000):
    """Points of a sphere surface snapped to a 1.5 mm lattice: many exactly tied nearest neighbours."""
    model = rng.normal(size=(n, 3))
    return np.unique(np.round(0.1 * model / np.linalg.norm(model, axis=1, keepdims=True) / 0.0015) * 0.0015, axis=0)


def test_radius_grid_pruned_search_equals_brute_force_with_ties():
    from semslam.pose.search import RadiusGrid

    rng = np.random.default_rng(5)
    for trial in range(4):
        model = _lattice_model(rng) if trial % 2 else 0.1 * rng.normal(size=(2000, 3))
        grid = RadiusGrid.build(model, 0.006)
        q = np.vstack([model[rng.integers(0, len(model), 400)] + rng.normal(scale=0.003, size=(400, 3)),
                       model[rng.integers(0, len(model), 100)],  # on model points: distance 0
                       model[rng.integers(0, len(model), 200)] + 0.00075 * rng.integers(-2, 3, (200, 3)),  # ties
                       rng.normal(scale=0.3, size=(50, 3))])  # mostly outside the grid
        # brute force with the kernel's arithmetic; argmin = the smallest index among ties
        dd = (q[:, None, 0] - model[None, :, 0]) ** 2 + (q[:, None, 1] - model[None, :, 1]) ** 2 + \
            (q[:, None, 2] - model[None, :, 2]) ** 2
        j_ref = np.argmin(dd, axis=1)
        best = dd[np.arange(len(q)), j_ref]
        for bound in (0.006, 0.004, 0.0015):
            inside = best < bound * bound
            d, j = grid.query(q, bound)
            assert 0 < inside.sum() < len(q)
            np.testing.assert_array_equal(d, np.where(inside, np.sqrt(best), np.inf))
            np.testing.assert_array_equal(j, np.where(inside, j_ref, len(model)))


def _align_and_score_reference(Rs, ts, src, field, truncations, tau):
    """align_and_score in numpy on DistanceField.nearest_points (the field's own lookup)."""
    ts = ts.copy()
    cost = np.empty(len(Rs))
    for h in range(len(Rs)):
        q = src @ Rs[h].T
        for tr in truncations:
            p = q + ts[h]
            d = field.nearest_points(p) - p
            ok = np.isfinite(d[:, 0]) & (np.sum(d * d, axis=1) <= tr * tr)
            if not ok.any():
                break
            ts[h] += d[ok].sum(axis=0) / ok.sum()
        p = q + ts[h]
        d2 = np.sum((field.nearest_points(p) - p) ** 2, axis=1)
        cost[h] = np.mean(np.where(np.isfinite(d2), np.minimum(d2, tau * tau) / (tau * tau), 1.0))
    return cost, ts


def test_align_and_score_matches_the_field_lookup_reference():
    from semslam.pose import _search_kernels as K
    from semslam.pose.search import DistanceField, so3_grid

    rng = np.random.default_rng(6)
    d = rng.normal(size=(6000, 3))
    model = 0.04 * d / np.linalg.norm(d, axis=1, keepdims=True) * [1.0, 0.6, 0.4]
    field = DistanceField.build(model, cell_m=0.0025)
    Rs = so3_grid(64)
    # scanner-frame points whose true T_object_scanner is (Rs[5], 0): q = Rs[5] src = the model points
    src = (model[rng.integers(0, len(model), 60)] + rng.normal(scale=0.001, size=(60, 3))) @ Rs[5]
    ts = np.ascontiguousarray(rng.normal(scale=0.01, size=(64, 3)))
    trunc = np.array([0.03, 0.015, 0.008])
    ts_k = ts.copy()
    got = K.align_and_score(Rs, ts_k, src, field.params, field.cell_m, field.offsets, trunc, 0.006)
    want, ts_ref = _align_and_score_reference(Rs, ts, src, field, trunc, 0.006)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ts_k, ts_ref, rtol=0, atol=1e-12)
    assert got[5] < 0.2 < np.median(got)  # the true orientation fits, most others do not


def test_range_image_equals_scatter_min_and_dilation():
    from semslam.pose.search import RangeImage

    rng = np.random.default_rng(7)
    for dilate in (0, 1, 2):
        pts = rng.normal(size=(300, 3)) * [0.1, 0.1, 0.02] + [0.2, 0.0, 1.5]
        img = RangeImage.build(pts, np.zeros(3), cell_m=0.008, dilate=dilate)
        q = pts @ img.F.T
        ij = np.floor((q[:, :2] / q[:, 2:3] - [img.u0, img.v0]) / img.cell).astype(int)
        ref = np.full(img.range_min.shape, np.inf)
        np.minimum.at(ref, (ij[:, 0], ij[:, 1]), np.linalg.norm(pts, axis=1))
        pad = np.pad(ref, dilate, constant_values=np.inf)
        out = ref.copy()
        for di in range(-dilate, dilate + 1):
            for dj in range(-dilate, dilate + 1):
                out = np.minimum(out, pad[dilate + di:dilate + di + ref.shape[0], dilate + dj:dilate + dj + ref.shape[1]])
        np.testing.assert_array_equal(img.range_min, out)
        assert np.isfinite(out).sum() > 50


def test_children_of_mask_equals_concatenation():
    from semslam.pose.search import RotationHierarchy, so3_grid

    h = RotationHierarchy.build(so3_grid(2048), 256)
    rng = np.random.default_rng(8)
    for k in (0, 1, 17, 128, 256):
        for sel in (rng.permutation(256)[:k], rng.integers(0, 256, k)):  # distinct, and with repeats
            parts = [h.children[h.offsets[c]:h.offsets[c + 1]] for c in sel]
            want = np.sort(np.concatenate(parts)) if parts else np.zeros(0, dtype=np.int64)
            np.testing.assert_array_equal(h.children_of(sel), want)


def test_visibility_cost_object_frame_form_matches_scanner_frame_definition():
    from semslam.pose.search import RangeImage

    rng = np.random.default_rng(9)
    d = rng.normal(size=(800, 3))
    model, normals = 0.05 * d / np.linalg.norm(d, axis=1, keepdims=True), d / np.linalg.norm(d, axis=1, keepdims=True)
    Rs = Rotation.random(40, random_state=9).as_matrix()
    ts = rng.normal(scale=0.05, size=(40, 3)) + [0.0, 0.0, -1.0]
    vp = np.array([0.01, -0.02, 0.0])
    # a scan of the sphere under the first hypothesis, seen from vp
    p_s = (model - ts[0]) @ Rs[0]
    img = RangeImage.build(p_s[np.einsum("ij,ij->i", normals @ Rs[0], p_s - vp) < 0], vp, cell_m=0.008)
    got = img.visibility_cost(Rs, ts, model, normals, 0.01)
    want = np.empty(len(Rs))
    for h in range(len(Rs)):  # the definition, vectorised, in the scanner frame
        r = (model - ts[h]) @ Rs[h] - vp
        front = np.einsum("ij,ij->i", normals @ Rs[h], r) < 0
        q = r[front] @ img.F.T
        bad = q[:, 2] <= 1e-9
        with np.errstate(divide="ignore", invalid="ignore"):
            ij = np.floor((q[:, :2] / q[:, 2:3] - [img.u0, img.v0]) / img.cell)
        inside = ~bad & (ij >= 0).all(axis=1) & (ij[:, 0] < img.range_min.shape[0]) & (ij[:, 1] < img.range_min.shape[1])
        ro = np.full(len(q), np.inf)
        ro[inside] = img.range_min[ij[inside, 0].astype(int), ij[inside, 1].astype(int)]
        bad |= ~inside | ~np.isfinite(ro) | (np.linalg.norm(r[front], axis=1) < ro - 0.01)
        want[h] = bad.sum() / max(front.sum(), 1)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert got[0] < 0.1 and got.max() > 0.5


def test_batched_field_icp_equals_single_runs():
    import small_gicp

    from semslam.registration._icp_kernels import icp_plane_field, icp_plane_field_batch
    from semslam.pose.search import DistanceField

    rng = np.random.default_rng(10)
    d = rng.normal(size=(20000, 3))
    model = 0.04 * d / np.linalg.norm(d, axis=1, keepdims=True) * [1.0, 0.6, 0.4]
    cloud = small_gicp.PointCloud(model)
    small_gicp.estimate_normals(cloud, small_gicp.KdTree(cloud), num_neighbors=15)
    normals = np.ascontiguousarray(cloud.normals()[:, :3])
    f = DistanceField.build(model, cell_m=0.0025)
    src = model[(model[:, 2] > 0)][::9]
    T0s = np.stack([np.eye(4)] * 3)
    for k in range(3):
        T0s[k, :3, :3] = Rotation.from_rotvec(rng.normal(scale=0.1, size=3)).as_matrix()
        T0s[k, :3, 3] = rng.normal(scale=0.005, size=3)
    Ts, its, conv, n_pairs = icp_plane_field_batch(src, T0s, f.params, f.index, model, normals, 0.02, 30, 1e-4, 1e-5)
    for k in range(3):
        T, it, c, n = icp_plane_field(src, T0s[k], f.params, f.index, model, normals, 0.02, 30, 1e-4, 1e-5)
        np.testing.assert_array_equal(Ts[k], T)
        assert (its[k], conv[k], n_pairs[k]) == (it, c, n)
    assert np.abs(Ts[:, :3, 3]).max() < 1e-3  # they all recover the identity


def test_pose_internals_reuse_equals_the_separate_computations():
    """_final_scores == _final_score per hypothesis; the final ICP's fitness / RMSE and the nearest points
    it hands to the covariance == the KD-tree's (inlier_statistics) and a fresh query."""
    from semslam.pose import estimate as P
    from semslam.simulation.scan_sim import mesh_model_cloud, resting_scene_pose, scan_mesh
    from semslam.registration.result import inlier_statistics
    from semslam.pose.search import RangeImage
    from semslam.simulation import builtin_objects

    obj = builtin_objects()["elbow"]
    model = P.prepare_pose_model(mesh_model_cloud(obj.mesh, seed=1))
    rng = np.random.default_rng(11)
    T = resting_scene_pose(obj.resting_poses[0], 1.2, seed=rng)
    pts = scan_mesh(obj.mesh, T, n_target_points=600, range_noise_m=0.001, seed=rng)
    pts = pts.points_xyz_m if hasattr(pts, "points_xyz_m") else pts
    cfg = model.config
    T_os = np.linalg.inv(T)
    Ts = []
    for k in range(3):
        D = np.eye(4)
        D[:3, :3] = Rotation.from_rotvec(rng.normal(scale=0.02, size=3)).as_matrix()
        D[:3, 3] = rng.normal(scale=0.002, size=3)
        Ts.append(D @ T_os)
    image = RangeImage.build(pts, np.zeros(3), cell_m=cfg.image_cell_m)
    assert P._final_scores(pts, image, model, cfg, Ts) == [P._final_score(pts, image, model, cfg, M) for M in Ts]
    res, (p, d, j) = P._icp_field_nearest(pts, model, cfg, Ts[0], cfg.icp_max_correspondence_m)
    M = res.T_target_source.matrix
    np.testing.assert_array_equal(p, pts @ M[:3, :3].T + M[:3, 3])
    fit, rmse, n_in = inlier_statistics(p, model.icp_target.tree, cfg.icp_max_correspondence_m)
    assert (res.fitness, res.inlier_rmse_m, res.n_inliers) == (fit, rmse, n_in) and fit > 0.9
    d_ref, j_ref = model.icp_target.tree.query(p, k=1, distance_upper_bound=cfg.icp_max_correspondence_m)
    np.testing.assert_array_equal(d, d_ref)
    np.testing.assert_array_equal(j[np.isfinite(d)], j_ref[np.isfinite(d_ref)])
    with_reuse = P._covariance(pts, model, cfg, obj.symmetry, M, None, (p, d, j))
    fresh = P._covariance(pts, model, cfg, obj.symmetry, M, None)
    np.testing.assert_array_equal(with_reuse[0][0], fresh[0][0])


def test_icp_step_helpers_match_numpy():
    """The allocation-free Levenberg-Marquardt step of icp_plane_field: Cholesky solve, SE(3) exponential and
    4x4 product against np.linalg.solve, scipy's rotation-vector exponential with the SE(3) V matrix, and @."""
    from scipy.linalg import expm

    from semslam.registration._icp_kernels import _exp_se3_into, _matmul44, _solve_spd6

    def exp_se3(delta):  # the matrix exponential of the twist [[w]x, rho; 0, 0]
        w, rho = delta[:3], delta[3:]
        X = np.zeros((4, 4))
        X[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
        X[:3, 3] = rho
        return expm(X)

    rng = np.random.default_rng(12)
    for _ in range(300):
        delta = rng.normal(size=6) * 10.0 ** rng.uniform(-13, 0)  # down to the small-angle branches
        E = np.empty((4, 4))
        _exp_se3_into(delta, E)
        np.testing.assert_allclose(E, exp_se3(delta), rtol=0, atol=2e-12)  # rotations < 1e-12 rad: identity
        M = rng.normal(size=(6, 6))
        A = M @ M.T + 10.0 ** rng.uniform(-6, 0) * np.eye(6)
        g = rng.normal(size=6)
        x = np.empty(6)
        assert _solve_spd6(A.copy(), g, x)
        want = -np.linalg.solve(A, g)
        np.testing.assert_allclose(x, want, rtol=0, atol=1e-9 * np.abs(want).max())
        out = np.empty((4, 4))
        _matmul44(E, E, out)
        np.testing.assert_allclose(out, E @ E, rtol=0, atol=1e-14)
    assert not _solve_spd6(np.zeros((6, 6)), np.ones(6), np.empty(6))  # singular: the caller falls back to LU


def test_icp_lu_fallback_matches_numpy_and_gives_a_zero_step_when_singular():
    """The LU solve icp_plane_field falls back to when the damped system is not numerically positive definite
    (written out: numba's np.linalg.solve brought ~200 kB of code into the cold start): np.linalg.solve on general,
    indefinite and ill-conditioned 6x6 systems, pivoting included; a zero step for a singular one (np.linalg.solve
    raised inside the kernel)."""
    from semslam.registration._icp_kernels import _solve_lu6

    rng = np.random.default_rng(5)
    for k in range(300):
        A = rng.normal(size=(6, 6))
        if k % 3 == 1:  # symmetric indefinite, as a damped Hessian that rounding made non-positive
            A = A + A.T
        elif k % 3 == 2:  # a zero leading pivot: row exchanges needed from the first column
            A[0, 0] = 0.0
        g = rng.normal(size=6)
        x = np.full(6, np.nan)
        _solve_lu6(A.copy(), g, x)
        want = -np.linalg.solve(A, g)
        np.testing.assert_allclose(x, want, rtol=0, atol=1e-9 * np.abs(want).max())
    singular = rng.normal(size=(6, 6))
    singular[:, 3] = 0.0
    x = np.full(6, np.nan)
    _solve_lu6(singular, np.ones(6), x)
    assert np.array_equal(x, np.zeros(6))


def test_icp_step_falls_back_to_lu_on_the_damped_system_not_on_a_half_factored_one():
    """The Levenberg-Marquardt step of icp_plane_field: -(H + lambda I)^-1 g whether the damped system is
    positive definite (Cholesky) or not (a rank-deficient Hessian whose rounding beat the damping: LU). The LU
    fallback solved the matrix the failed Cholesky had half overwritten, or raised inside the kernel."""
    from semslam.registration._icp_kernels import _damped_step

    rng = np.random.default_rng(8)
    Q = np.linalg.qr(rng.normal(size=(6, 6)))[0]
    for eigenvalues in ([5.0, 3.0, 1.0, 0.5, 0.2, 0.1], [5.0, 3.0, 1.0, 0.5, 0.2, -1e-3]):
        H = Q @ np.diag(eigenvalues) @ Q.T
        H = 0.5 * (H + H.T)
        g = rng.normal(size=6)
        lam = 1e-4
        A = np.empty((6, 6))
        delta = np.full(6, np.nan)
        _damped_step(H, g, lam, A, delta)
        want = -np.linalg.solve(H + lam * np.eye(6), g)
        np.testing.assert_allclose(delta, want, rtol=0, atol=1e-9 * np.abs(want).max())


def test_align_and_score_below_decides_every_hypothesis_as_the_full_cost_does():
    """Catches the early stop of the border-cut starts changing which start wins: with random bounds, the costs
    below their bound and the translations are those of align_and_score bit for bit, and a stopped cost is at least
    its bound and at most the full cost."""
    from semslam.pose import _search_kernels as K
    from semslam.pose.search import DistanceField, so3_grid

    rng = np.random.default_rng(8)
    d = rng.normal(size=(6000, 3))
    model = 0.05 * d / np.linalg.norm(d, axis=1, keepdims=True) * [1.0, 0.5, 0.3]
    field = DistanceField.build(model, cell_m=0.0025)
    Rs = so3_grid(256)
    src = np.ascontiguousarray((model[rng.integers(0, len(model), 80)] + rng.normal(scale=0.001, size=(80, 3)))
                               @ Rs[17])
    ts = np.ascontiguousarray(rng.normal(scale=0.01, size=(256, 3)))
    trunc = np.array([0.03, 0.015, 0.008])
    t_full, t_below = ts.copy(), ts.copy()
    full = K.align_and_score(Rs, t_full, src, field.params, field.cell_m, field.offsets, trunc, 0.006)
    bounds = np.ascontiguousarray(full + rng.uniform(-0.3, 0.3, len(full)))
    below = K.align_and_score_below(Rs, t_below, src, field.params, field.cell_m, field.offsets, trunc, 0.006, bounds)
    wins = full < bounds
    assert 20 < wins.sum() < 236  # both kinds among them
    np.testing.assert_array_equal(below < bounds, wins)
    np.testing.assert_array_equal(below[wins], full[wins])
    np.testing.assert_array_equal(t_below, t_full)
    assert np.all(below[~wins] >= bounds[~wins]) and np.all(below[~wins] <= full[~wins])
    assert np.any(below[~wins] < full[~wins])  # some did stop early
