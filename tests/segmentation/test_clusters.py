"""Euclidean clusters: brute-force oracle, PCL semantics (strict <, sizes, order), PCL's partition."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components
from scipy.spatial.distance import cdist

from semslam.errors import InputError
from semslam.segmentation import euclidean_labels, extract_euclidean_clusters


def brute_force_clusters(points, tol, min_size=1, max_size=None):
    """Oracle: dense distance matrix, strict < tol, scipy connected components, PCL's filtering/order."""
    _, labels = connected_components(cdist(points, points) < tol, directed=False)
    groups = [np.flatnonzero(labels == c) for c in range(labels.max() + 1)]
    groups = [g for g in groups if len(g) >= min_size and (max_size is None or len(g) <= max_size)]
    return sorted(groups, key=lambda g: (-len(g), g[0]))


def blobs(seed, n=1500):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-1, 1, size=(12, 3))
    sizes = rng.integers(5, 250, size=12)
    pts = np.concatenate([rng.normal(c, 0.04, size=(s, 3)) for c, s in zip(centres, sizes)])
    noise = rng.uniform(-1.2, 1.2, size=(n - len(pts), 3)) if n > len(pts) else np.zeros((0, 3))
    return rng.permutation(np.r_[pts, noise])


@pytest.mark.parametrize("method", ["grid", "kdtree"])
@pytest.mark.parametrize("seed, tol", [(0, 0.05), (1, 0.08), (2, 0.03), (3, 0.2)])
def test_matches_brute_force(seed, tol, method):
    pts = blobs(seed)
    got = extract_euclidean_clusters(pts, tolerance_m=tol, min_size=1, method=method)
    want = brute_force_clusters(pts, tol)
    assert len(got) == len(want)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)  # same clusters, sorted indices, same order
    assert sum(len(g) for g in got) == len(pts)


def test_min_max_size_filtering():
    pts = blobs(4)
    want = brute_force_clusters(pts, 0.06, min_size=20, max_size=150)
    got = extract_euclidean_clusters(pts, tolerance_m=0.06, min_size=20, max_size=150)
    assert [len(g) for g in got] == [len(w) for w in want] and len(got) > 2
    assert all(20 <= len(g) <= 150 for g in got)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)


def test_tolerance_is_strict():
    # unit grid, neighbours exactly 1.0 apart: tolerance 1.0 connects nothing (PCL: dist^2 < r^2)
    grid = np.stack(np.meshgrid(np.arange(4.0), np.arange(3.0), np.arange(2.0)), -1).reshape(-1, 3)
    for method in ("grid", "kdtree"):
        assert len(extract_euclidean_clusters(grid, tolerance_m=1.0, method=method)) == 24
        one = extract_euclidean_clusters(grid, tolerance_m=1.0 + 1e-9, method=method)
        assert len(one) == 1 and len(one[0]) == 24


def test_cells_two_apart_connect():
    # two points 0.0199 apart along a diagonal: they fall in grid cells 2 apart on each axis
    tol = 0.02
    d = 0.0199 / np.sqrt(3)
    pts = np.array([[0.0, 0, 0], [d, d, d], [10, 10, 10]])
    assert [len(c) for c in extract_euclidean_clusters(pts, tolerance_m=tol)] == [2, 1]


def test_ties_and_labels():
    pts = np.array([[0.0, 0, 0], [5, 0, 0], [0.1, 0, 0], [5.1, 0, 0], [9, 9, 9]])
    clusters = extract_euclidean_clusters(pts, tolerance_m=0.5)
    assert [c.tolist() for c in clusters] == [
        [0, 2],
        [1, 3],
        [4],
    ]  # equal sizes: smallest index first
    np.testing.assert_array_equal(euclidean_labels(pts, tolerance_m=0.5), [0, 1, 0, 1, 2])


def test_duplicates_empty_and_single():
    assert extract_euclidean_clusters(np.zeros((0, 3)), tolerance_m=0.1) == []
    assert [c.tolist() for c in extract_euclidean_clusters([[1.0, 2, 3]], tolerance_m=0.1)] == [[0]]
    dup = np.repeat([[0.0, 0, 0], [1, 1, 1]], 50, axis=0)
    assert [len(c) for c in extract_euclidean_clusters(dup, tolerance_m=0.01)] == [50, 50]
    assert extract_euclidean_clusters(dup, tolerance_m=0.01, min_size=51) == []


def test_very_fine_tolerance_falls_back_to_kdtree():
    pts = np.array([[0.0, 0, 0], [1e7, 0, 0], [1e-10, 0, 0]])
    assert [c.tolist() for c in extract_euclidean_clusters(pts, tolerance_m=1e-9)] == [[0, 2], [1]]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"tolerance_m": 0}, "tolerance_m"),
        ({"tolerance_m": 0.1, "min_size": 0}, "min_size"),
        ({"tolerance_m": 0.1, "min_size": 10, "max_size": 5}, "max_size"),
        ({"tolerance_m": 0.1, "method": "flann"}, "method"),
    ],
)
def test_bad_arguments(kwargs, match):
    with pytest.raises(InputError, match=match):
        extract_euclidean_clusters(np.zeros((5, 3)), **kwargs)
    with pytest.raises(InputError, match="finite"):
        extract_euclidean_clusters([[0.0, 0, np.inf]], tolerance_m=0.1)


@pytest.mark.parametrize(
    "scene", ["table_scene_mug_stereo_textured", "milk_cartoon_all_small_clorox"]
)
def test_same_partition_as_pcl_on_identical_points(real_data, test_data, scene):
    """Our voxel grid, minus PCL's plane inliers, clustered by PCL (tests/data/segmentation/make_golden.py)."""
    from semslam.io import read_point_cloud
    from semslam.segmentation import voxel_downsample

    sys.path.insert(0, str(test_data / "segmentation"))
    try:
        from make_golden import remaining_after_plane
    finally:
        sys.path.pop(0)
    golden = json.loads((test_data / "segmentation" / "pcl_golden.json").read_text())["scenes"][
        scene
    ]
    vox = voxel_downsample(
        read_point_cloud(real_data / f"{scene}.pcd").points_xyz_m, 0.005, pcl_rounding=True
    )
    rest = remaining_after_plane(vox, golden["pcl_pipeline"]["plane"])
    assert len(rest) == golden["n_remaining"]
    sizes = [len(c) for c in extract_euclidean_clusters(rest, tolerance_m=0.02, min_size=10)]
    assert sizes == golden["pcl_sizes_min10"]
    kept = [
        len(c)
        for c in extract_euclidean_clusters(rest, tolerance_m=0.02, min_size=50, max_size=25000)
    ]
    assert kept == golden["pcl_sizes_50_25000"]


def test_mug_full_resolution_matches_pcl_golden(real_data):
    """PCL 1.13 golden: after the RANSAC plane (T = 0.01, 123,726 inliers), tolerance 0.02, min 100:
    11 clusters of 52899 15692 10951 3351 1118 629 241 238 171 142 122. Removing PCL's plane (printed to
    6 digits) leaves PCL's 85,554 points, and the partition is the same, cluster for cluster."""
    from semslam.io import read_point_cloud

    pts = read_point_cloud(real_data / "table_scene_mug_stereo_textured.pcd").points_xyz_m
    plane = np.array([0.0162299, -0.837595, -0.546051, 0.528868])
    rest = pts[np.abs(pts @ plane[:3] + plane[3]) >= 0.01]
    assert len(rest) == 85554
    sizes = [len(c) for c in extract_euclidean_clusters(rest, tolerance_m=0.02, min_size=100)]
    assert sizes == [52899, 15692, 10951, 3351, 1118, 629, 241, 238, 171, 142, 122]


def test_label_and_filter_kernels_against_numpy():
    """Renumbering by first occurrence and the size filter/order, against the NumPy formulation."""
    from semslam.segmentation import _cluster_kernels as k

    rng = np.random.default_rng(11)
    roots = rng.integers(0, 40, 60)  # arbitrary root ids of 60 nodes
    point_node = rng.integers(0, 60, 3000)
    labels = k.first_occurrence_labels(roots, point_node)
    per_point = roots[point_node]
    _, first, inverse = np.unique(per_point, return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    np.testing.assert_array_equal(labels, rank[inverse])
    for lo, hi in [(1, -1), (60, 120), (80, -1), (5000, -1)]:
        members, bounds = k.clusters_from_labels(labels, lo, hi)
        sizes = np.bincount(labels)
        keep = (sizes >= lo) & ((sizes <= hi) if hi >= 0 else True)
        kept = np.flatnonzero(keep)
        kept = kept[np.argsort(-sizes[kept], kind="stable")]
        assert len(bounds) == len(kept) + 1
        for c, lab in enumerate(kept):
            np.testing.assert_array_equal(
                members[bounds[c] : bounds[c + 1]], np.flatnonzero(labels == lab)
            )


def test_grid_matches_kdtree_on_a_dense_scan_like_cloud():
    # a dense wall plus objects: most neighbour cells already share a root (the skip path)
    rng = np.random.default_rng(12)
    wall = np.c_[rng.uniform(0, 1.5, 6000), rng.uniform(0, 0.8, 6000), rng.normal(0, 0.002, 6000)]
    objs = np.concatenate(
        [rng.normal(c, 0.03, (300, 3)) for c in ([0.3, 0.3, 0.2], [1.0, 0.5, 0.15])]
    )
    pts = rng.permutation(np.r_[wall, objs, rng.uniform(0, 1.5, (200, 3))])
    a = extract_euclidean_clusters(pts, tolerance_m=0.02, min_size=1, method="grid")
    b = extract_euclidean_clusters(pts, tolerance_m=0.02, min_size=1, method="kdtree")
    assert len(a) == len(b) > 3
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(
        euclidean_labels(pts, tolerance_m=0.02),
        euclidean_labels(pts, tolerance_m=0.02, method="kdtree"),
    )
