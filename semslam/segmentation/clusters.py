"""Euclidean cluster extraction with PCL ``EuclideanClusterExtraction`` semantics.

Two points are neighbours when their distance is strictly below the tolerance; clusters are the
connected components of that graph (PCL's breadth-first flood fill finds the same partition, since
components are unique). A cluster is kept when ``min_size <= size <= max_size``; its indices are
sorted; clusters are sorted by size, largest first (ties: the cluster with the smallest point index
first; PCL leaves ties in an unspecified order).

Methods: ``"grid"`` (default) is a numba union-find over grid cells (see ``_cluster_kernels``);
``"kdtree"`` uses scipy's ``cKDTree.query_pairs`` and a union-find over the point pairs. Both give
the same partition; the grid is ~10x faster on dense scans (benchmarks/segmentation.py).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from .._validation import as_float_array, check_choice, check_int, check_positive
from ..errors import InputError
from . import _cluster_kernels as _k

__all__ = ["euclidean_labels", "extract_euclidean_clusters"]


def euclidean_labels(
    points_xyz_m: np.ndarray, *, tolerance_m: float, method: str = "grid"
) -> np.ndarray:
    """Connected-component label of every point under "distance < tolerance_m".

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Points in metres, finite.
    tolerance_m : float
        Neighbour distance in metres (> 0), strict.
    method : {"grid", "kdtree"}
        Neighbour search (same result).

    Returns
    -------
    ndarray of shape (N,), int64
        Labels ``0 .. C-1``, numbered by the smallest point index of each component.
    """
    caller = "euclidean_labels"
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller=caller)
    tol = check_positive("tolerance_m", tolerance_m, caller=caller)
    check_choice("method", method, ("grid", "kdtree"), caller=caller)
    n = len(pts)
    if n == 0:
        return np.zeros(0, np.int64)
    roots = None
    if method == "grid":
        roots = _grid_roots(pts, tol)
    if roots is None:  # kdtree requested, or a grid too fine for 64-bit keys
        pairs = cKDTree(pts).query_pairs(tol, output_type="ndarray").astype(np.int64)
        if len(pairs):
            diff = pts[pairs[:, 0]] - pts[pairs[:, 1]]
            pairs = pairs[np.einsum("ij,ij->i", diff, diff) < tol * tol]  # strict, as the grid
        roots = _k.pair_components(n, np.ascontiguousarray(pairs))
    # renumber by first occurrence: label of the component of the smallest point index first
    _, first, inverse = np.unique(roots, return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    return rank[inverse.reshape(-1)]


def _grid_roots(pts: np.ndarray, tol: float) -> np.ndarray | None:
    cell = tol / math.sqrt(3.0) * (1.0 - 1e-9)
    ijk = np.floor((pts - pts.min(axis=0)) / cell)
    extent = ijk.max(axis=0) + 5.0  # +2 padding on each side, +1
    if float(np.prod(extent)) >= 2.0**62:
        return None
    ijk = ijk.astype(np.int64) + 2
    nx, ny = int(extent[0]), int(extent[1])
    keys = ijk[:, 0] + nx * (ijk[:, 1] + ny * ijk[:, 2])
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]])
    cell_keys = sorted_keys[starts]
    cell_start = np.r_[starts, len(pts)].astype(np.int64)
    cell_roots = _k.grid_components(pts, order, cell_keys, cell_start, nx, ny, float(tol))
    point_cell = np.empty(len(pts), np.int64)
    point_cell[order] = np.repeat(np.arange(len(cell_keys)), np.diff(cell_start))
    return cell_roots[point_cell]


def extract_euclidean_clusters(
    points_xyz_m: np.ndarray,
    *,
    tolerance_m: float,
    min_size: int = 1,
    max_size: int | None = None,
    method: str = "grid",
) -> list[np.ndarray]:
    """Euclidean clusters of a cloud, as PCL's ``EuclideanClusterExtraction``.

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Points in metres, finite. N may be 0 (no cluster).
    tolerance_m : float
        Two points closer than this (strictly, metres) belong to the same cluster.
    min_size : int
        Smallest cluster kept (>= 1).
    max_size : int, optional
        Largest cluster kept (>= min_size); default: no limit.
    method : {"grid", "kdtree"}
        Neighbour search; both give the same clusters.

    Returns
    -------
    list of ndarray of int64
        One sorted index array (into ``points_xyz_m``) per cluster, largest cluster first.
    """
    caller = "extract_euclidean_clusters"
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller=caller)
    lo = check_int("min_size", min_size, caller=caller, minimum=1)
    hi = None if max_size is None else check_int("max_size", max_size, caller=caller, minimum=1)
    if hi is not None and hi < lo:
        raise InputError(
            f"The 'max_size' argument of {caller} must be >= min_size={lo}. Got {hi} instead."
        )
    labels = euclidean_labels(pts, tolerance_m=tolerance_m, method=method)
    if len(labels) == 0:
        return []
    sizes = np.bincount(labels)
    keep = sizes >= lo
    if hi is not None:
        keep &= sizes <= hi
    kept = np.flatnonzero(keep)  # labels are numbered by first point index: tie order
    kept = kept[np.argsort(-sizes[kept], kind="stable")]
    order = np.argsort(labels, kind="stable")  # indices ascending within each label
    bounds = np.r_[0, np.cumsum(sizes)]
    return [order[bounds[c] : bounds[c + 1]].astype(np.int64) for c in kept]
