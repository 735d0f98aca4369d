"""Exactness of the pose and voxel-grid speed-ups: the analytic covariance Jacobian against central
differences, the greedy distinct-hypothesis selection, RadiusGrid against cKDTree, the radix argsort."""

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.registration.covariance import _xyz_rpy_covariance_of_inverse_numeric, xyz_rpy_covariance_of_inverse
from semslam.registration.search import _greedy_distinct, pairwise_rotation_distances
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

    from semslam.registration.search import RadiusGrid

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
