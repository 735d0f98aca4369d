"""Normal estimation against PCL's unit-test values, PCL 1.13 golden normals and brute force."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.descriptors import estimate_normals, find_neighbors
from semslam.errors import DescriptorError, InputError


def golden(test_data, name):
    for line in (test_data / "descriptors" / "pcl-1.13.txt").read_text().splitlines():
        if line.startswith(name + " "):
            return line.split()[1:]
    raise KeyError(name)


@pytest.fixture(scope="module")
def bun0(test_data):
    return np.load(test_data / "descriptors" / "bun0.npy").astype(np.float64)


def test_whole_cloud_matches_pcl_unit_test(bun0):
    # test_normal_estimation.cpp: k-search over all 397 points gives one normal everywhere.
    res = estimate_normals(bun0[:, :3], k=len(bun0))
    expected = np.array([-0.035592, -0.369596, -0.928511])  # flipped towards (0, 0, 0)
    np.testing.assert_allclose(res.normals_xyz, np.tile(expected, (len(bun0), 1)), atol=1e-4)
    np.testing.assert_allclose(res.curvature, 0.0693136, atol=1e-5)
    d = -res.normals_xyz[0] @ bun0[0, :3]
    assert d == pytest.approx(0.0799743, abs=1e-5)


def test_k10_matches_pcl_golden(test_data, bun0):
    res = estimate_normals(bun0[:, :3], k=10)
    for i in range(3):
        vals = golden(test_data, f"NORMAL_bun0_k10[{i}]")
        np.testing.assert_allclose(res.normals_xyz[i], np.array(vals[:3], float), atol=2e-5)
        assert res.curvature[i] == pytest.approx(float(vals[4]), abs=2e-6)


def test_against_brute_force_radius_and_viewpoint():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(300, 3)) * [1.0, 1.0, 0.05]
    vp = np.array([0.3, -0.2, 5.0])
    res = estimate_normals(pts, radius_m=0.4, viewpoint_xyz_m=vp)
    for i in rng.choice(len(pts), 25, replace=False):
        nb = pts[np.linalg.norm(pts - pts[i], axis=1) < 0.4]
        if len(nb) < 3:
            assert np.isnan(res.normals_xyz[i]).all() and np.isnan(res.curvature[i])
            continue
        w, v = np.linalg.eigh(np.cov(nb.T, bias=True))
        n = v[:, 0] * np.sign((vp - pts[i]) @ v[:, 0])
        np.testing.assert_allclose(res.normals_xyz[i], n, atol=1e-9)
        assert res.curvature[i] == pytest.approx(w[0] / w.sum(), rel=1e-9)
        assert res.n_neighbors[i] == len(nb)
    assert np.all((res.normals_xyz @ [0, 0, 1])[res.valid] > 0)


def test_shared_neighbors_give_the_same_result(bun0):
    nb = find_neighbors(bun0[:, :3], radius_m=0.01)
    a = estimate_normals(bun0[:, :3], neighbors=nb)
    b = estimate_normals(bun0[:, :3], radius_m=0.01)
    np.testing.assert_array_equal(a.normals_xyz, b.normals_xyz)


def test_sparse_and_duplicate_points_give_nan_rows_not_garbage():
    pts = np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0], [5, 5, 5], [9, 9, 9.0]])
    res = estimate_normals(pts, radius_m=0.5)
    assert np.isnan(res.normals_xyz).all()  # 3 coincident points: undefined; others: < 3 neighbours
    assert not res.valid.any()


def test_bad_input_names_the_argument():
    with pytest.raises(DescriptorError, match="points_xyz_m"):
        estimate_normals(np.zeros((4, 2)), k=3)
    with pytest.raises(DescriptorError, match="points_xyz_m"):
        estimate_normals(np.array([[0, 0, np.nan]] * 4), k=3)
    with pytest.raises(DescriptorError, match="'k', 'radius_m'"):
        estimate_normals(np.zeros((4, 3)), k=3, radius_m=0.1)
    with pytest.raises(InputError, match="radius_m"):
        estimate_normals(np.zeros((4, 3)), radius_m=-1.0)


def test_fused_radius_kernel_equals_search_then_normals():
    """estimate_normals(radius_m=...) runs the grid search and the normals in one kernel: bit-identical to
    find_neighbors(method="grid") then the CSR kernel, counts included, on clouds with empty cells, duplicates,
    isolated points and points exactly one radius apart."""
    from semslam.descriptors._normals_kernels import normals_from_neighborhoods

    rng = np.random.default_rng(11)
    grid = np.stack(np.meshgrid(*[np.arange(6) * 0.01] * 3), -1).reshape(-1, 3)  # spacing = radius exactly
    clouds = [rng.normal(size=(400, 3)) * [0.1, 0.1, 0.01], grid, np.vstack([grid[:40], grid[:40]]),
              rng.uniform(-1, 1, size=(200, 3))]
    for pts in clouds:
        for radius in (0.01, 0.015, 0.05):
            vp = rng.normal(size=3)
            got = estimate_normals(pts, radius_m=radius, viewpoint_xyz_m=vp)
            nb = find_neighbors(pts, radius_m=radius, method="grid")
            normals, curvature = normals_from_neighborhoods(np.ascontiguousarray(pts, float), nb.indptr, nb.indices, vp)
            np.testing.assert_array_equal(got.normals_xyz, normals)
            np.testing.assert_array_equal(got.curvature, curvature)
            np.testing.assert_array_equal(got.n_neighbors, nb.counts)
            assert got.n_neighbors.dtype == np.int64
    assert estimate_normals(np.zeros((0, 3)), radius_m=0.1).normals_xyz.shape == (0, 3)
