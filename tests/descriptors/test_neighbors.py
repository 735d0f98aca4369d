"""Grid radius search (find_neighbors) against brute force and scipy's cKDTree."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from semslam.descriptors import _neighbors_kernels as NK, find_neighbors
from semslam.errors import DescriptorError, InputError


def brute_force(pts, r):
    d2 = ((pts[:, None, :] - pts[None, :, :]) ** 2).sum(axis=2)
    return [np.flatnonzero(row < r * r) for row in d2], d2


def rows(nb, i):
    sl = slice(nb.indptr[i], nb.indptr[i + 1])
    return nb.indices[sl], nb.sqdist_m2[sl]


def assert_same_sets(nb, expected, d2):
    assert nb.n_points == len(expected)
    np.testing.assert_array_equal(nb.counts, [len(e) for e in expected])
    for i, e in enumerate(expected):
        idx, sq = rows(nb, i)
        order = np.argsort(idx)
        np.testing.assert_array_equal(idx[order], e)
        np.testing.assert_allclose(sq[order], d2[i, e], rtol=1e-12, atol=0)


@pytest.mark.parametrize("shape", ["blob", "plane", "far_offset"])
def test_grid_matches_brute_force(shape):
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(600, 3)) * 0.1
    if shape == "plane":
        pts[:, 2] = 0.01 * pts[:, 0]  # a surface, as laser scans
    if shape == "far_offset":
        pts += [1234.5, -987.25, 55.0]  # large coordinates: cells still exact
    pts[10] = pts[11]  # a duplicate (distance 0, both included)
    r = 0.03
    nb = find_neighbors(pts, radius_m=r, method="grid")
    assert_same_sets(nb, *brute_force(pts, r))
    assert all(i in rows(nb, i)[0] for i in range(len(pts)))  # every point is its own neighbour


def test_grid_sparse_path_matches_kdtree():
    # Two clusters 30 km apart: too many cells for the dense table, the binary-search path runs.
    rng = np.random.default_rng(4)
    pts = np.vstack([rng.random((300, 3)), rng.random((300, 3)) + 3e4])
    r = 0.15
    n_cells = np.prod(np.floor((pts.max(0) - pts.min(0)) / r) + 1)
    assert n_cells > NK.DENSE_CELLS_PER_POINT * len(pts) + NK.DENSE_CELLS_MIN
    grid = find_neighbors(pts, radius_m=r, method="grid")
    tree = find_neighbors(pts, radius_m=r, method="kdtree")
    np.testing.assert_array_equal(grid.indptr, tree.indptr)
    for i in range(len(pts)):
        a, b = rows(grid, i)[0], rows(tree, i)[0]
        np.testing.assert_array_equal(np.sort(a), np.sort(b))


def test_lattice_neighbours_just_inside_the_radius_across_cells():
    # A lattice of step just below r, offset so that points sit on cell boundaries: each interior
    # point has exactly its 6 face neighbours (and itself), in the adjacent cells.
    r = 0.1
    g = np.arange(7) * r * (1 - 1e-9)
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3) + [0.0, 0.05, 0.1]
    nb = find_neighbors(pts, radius_m=r)
    assert_same_sets(nb, *brute_force(pts, r))
    interior = ((pts - pts.min(0) > 0.05) & (pts.max(0) - pts > 0.05)).all(axis=1)
    assert interior.sum() == 125 and set(nb.counts[interior]) == {7}


def test_sort_orders_rows_by_distance_then_index():
    rng = np.random.default_rng(5)
    pts = rng.random((300, 3))
    pts[7] = pts[8]
    nb = find_neighbors(pts, radius_m=0.2, sort=True)
    expected, d2 = brute_force(pts, 0.2)
    assert_same_sets(nb, expected, d2)
    for i in range(len(pts)):
        idx, sq = rows(nb, i)
        keys = list(zip(sq, idx))
        assert keys == sorted(keys)
        assert idx[0] == i or sq[0] == 0.0


def test_knn_and_edge_cases():
    pts = np.random.default_rng(6).random((50, 3))
    nb = find_neighbors(pts, k=5)
    d, i = cKDTree(pts).query(pts, k=5)
    np.testing.assert_array_equal(nb.indices.reshape(50, 5), i)
    np.testing.assert_allclose(nb.sqdist_m2.reshape(50, 5), d**2)
    one = find_neighbors(np.array([[1.0, 2.0, 3.0]]), radius_m=0.5)
    np.testing.assert_array_equal(one.indptr, [0, 1])
    np.testing.assert_array_equal(one.indices, [0])
    empty = find_neighbors(np.zeros((0, 3)), radius_m=0.5)
    assert empty.n_points == 0 and empty.indices.size == 0


def test_bad_arguments():
    pts = np.zeros((4, 3))
    with pytest.raises(InputError, match="method"):
        find_neighbors(pts, radius_m=0.1, method="octree")
    with pytest.raises(InputError, match="radius_m"):
        find_neighbors(pts, radius_m=0.0)
    with pytest.raises(InputError, match="'k' and 'radius_m'"):
        find_neighbors(pts)
    with pytest.raises(DescriptorError, match="points_xyz_m"):
        find_neighbors(np.array([[0, 0, np.nan]]), radius_m=0.1)
    far = np.array([[0.0, 0, 0], [1e60, 0, 0]])  # 1e63 radii: beyond the grid's 2^52
    with pytest.raises(DescriptorError, match="method='kdtree'"):
        find_neighbors(far, radius_m=1e-3, method="grid")
    auto = find_neighbors(far, radius_m=1e-3)  # falls back to the KD-tree
    np.testing.assert_array_equal(auto.counts, [1, 1])
    # 1e9 radii: the grid takes it (sized by occupied cells), same neighbours as the KD-tree
    wide = np.array([[0.0, 0, 0], [5e-4, 0, 0], [1e6, 0, 0], [1e6, 5e-4, 0]])
    grid = find_neighbors(wide, radius_m=1e-3, method="grid", sort=True)
    tree = find_neighbors(wide, radius_m=1e-3, method="kdtree", sort=True)
    np.testing.assert_array_equal(grid.indptr, tree.indptr)
    np.testing.assert_array_equal(grid.indices, tree.indices)


@pytest.mark.parametrize("nan_normals", ["pcl", "skip"])
def test_symmetric_spfh_is_bit_identical_to_the_row_by_row_kernel(nan_normals):
    # The grid's neighbourhoods are symmetric, so FPFH computes each pair once; ties of PCL's swap
    # test (equal normals), NaN normals and duplicates are computed from both sides.
    from dataclasses import replace

    from semslam.descriptors.fpfh import compute_fpfh, compute_spfh
    from semslam.descriptors import estimate_normals

    rng = np.random.default_rng(7)
    pts = rng.random((400, 3)) * [0.2, 0.2, 0.02]
    pts[5] = pts[6]
    nb = find_neighbors(pts, radius_m=0.03)
    assert nb.symmetric
    normals = estimate_normals(pts, neighbors=nb).normals_xyz
    normals[::7] = [0.0, 0.0, 1.0]  # many pairs with equal normals: the swap test ties
    normals[3] = np.nan
    rowwise = replace(nb, symmetric=False)
    a = compute_spfh(pts, normals, neighbors=nb, nan_normals=nan_normals)
    b = compute_spfh(pts, normals, neighbors=rowwise, nan_normals=nan_normals)
    np.testing.assert_array_equal(a, b)
    assert (a.sum(axis=1) > 0).sum() > 350
    np.testing.assert_array_equal(compute_fpfh(pts, normals, neighbors=nb, nan_normals=nan_normals),
                                  compute_fpfh(pts, normals, neighbors=rowwise, nan_normals=nan_normals))


def test_grid_with_a_far_outlier_and_a_radius_above_one_unit_matches_brute_force():
    """Catches a wrong cell index in the occupied-cell grid used when one far outlier makes the packed grid too
    big (``floor(p * cell)`` for ``floor(p / cell)``: harmless while cells are below one unit, wrong for a cloud
    in millimetres with a 40 mm radius): every radius neighbourhood must equal the brute-force one (squared
    distance < r^2, the point itself included)."""
    rng = np.random.default_rng(2)
    pts = np.vstack([rng.uniform(0.0, 300.0, size=(150, 3)), [[1e12, -1e12, 5e11]]])
    r = 40.0
    nb = find_neighbors(pts, radius_m=r, method="grid")
    d2 = ((pts[:, None, :] - pts[None, :, :]) ** 2).sum(-1)
    for i in range(len(pts)):
        got = np.sort(nb.indices[nb.indptr[i]:nb.indptr[i + 1]])
        np.testing.assert_array_equal(got, np.flatnonzero(d2[i] < r * r))
    assert nb.indptr[-1] - nb.indptr[-2] == 1 and nb.indptr[-1] > 2 * len(pts)
