"""Voxel-grid down-sampling with PCL ``VoxelGrid`` semantics.

Each point ``p`` falls in the voxel ``floor(p / leaf_m)`` (per axis, in the points' own frame, no
offset); every occupied voxel is replaced by the centroid (mean) of its points. Output order follows
PCL: voxels sorted by their linear index ``i + j*nx + k*nx*ny`` relative to the minimum voxel, i.e.
z slowest, then y, then x fastest.

Differences from PCL 1.13: PCL computes the voxel index as ``floor(p * (1/leaf))`` in float32 and
averages in float32. By default we compute ``floor(p / leaf)`` in float64, so a point lying within
float32 rounding of a voxel boundary may land in the neighbouring voxel (PCL's mug scene at 5 mm:
32,895 voxels against PCL's 32,921). ``pcl_rounding=True`` reproduces PCL's float32 index
arithmetic, and then the voxel counts agree exactly (tests/segmentation/test_voxel.py); centroids stay float64
means (they differ from PCL's float32 sums by ~1e-7 relative). PCL also refuses to filter (returns
the input) when the grid has more than 2**31 voxels; we use 64-bit keys and fall back to a
row-wise sort when even those would overflow.

Implementation (``_voxel_kernels``): one pass computes every point's key and packs it with the
point index in one int64 (``key << 32 | index``); a stable LSD radix sort orders the words; the
voxel of each point is read off the sorted words, and one sequential pass over the points sums
each voxel in input order (so centroids equal a plain per-voxel mean in input order, bit for bit).
Grids of more than 2**31 voxels sort (key, index) pairs instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_float_array, check_positive
from . import _voxel_kernels as _k


@dataclass(frozen=True, eq=False)
class VoxelGridResult:
    """Result of :func:`voxel_grid`.

    Attributes
    ----------
    points_xyz_m : ndarray of shape (M, 3)
        Centroid of each occupied voxel, metres, same frame as the input, PCL order.
    point_voxel : ndarray of shape (N,), int64
        For every input point, the row of ``points_xyz_m`` (its voxel) it was averaged into.
    counts : ndarray of shape (M,), int64
        Number of input points in each voxel.
    leaf_m : float
        Voxel edge length, metres.
    """

    points_xyz_m: np.ndarray
    point_voxel: np.ndarray
    counts: np.ndarray
    leaf_m: float

    @property
    def n_voxels(self) -> int:
        return len(self.points_xyz_m)


def voxel_grid(
    points_xyz_m: np.ndarray, leaf_m: float, *, pcl_rounding: bool = False
) -> VoxelGridResult:
    """Down-sample a cloud to one centroid per occupied voxel, keeping the point-to-voxel map.

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Points in metres (any frame); must be finite. N may be 0.
    leaf_m : float
        Voxel edge length in metres, > 0.
    pcl_rounding : bool
        Compute the voxel index as PCL 1.13 does, ``floor(float32(p) * float32(1 / leaf))``, so
        that voxel membership (and counts) match PCL exactly. Default: float64 ``floor(p / leaf)``.

    Returns
    -------
    VoxelGridResult
        Centroids in PCL's output order and, per input point, the index of its voxel.
    """
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller="voxel_grid")
    leaf = check_positive("leaf_m", leaf_m, caller="voxel_grid")
    return _voxel_grid(pts, leaf, bool(pcl_rounding))[0]


_NO_VALUES = np.zeros(0)
_NO_VALUES.setflags(write=False)


def _read_only(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` (no copy). numba compiles, and loads from its cache, one specialisation of a
    kernel per read-only flag of its array arguments: passing read-only views makes the scan's call (the
    read-only arrays of a PointCloud) and the later calls on clusters share one (~8 ms each on a cold start)."""
    if not a.flags.writeable:
        return a
    view = a.view()
    view.setflags(write=False)
    return view


def _voxel_grid(
    pts: np.ndarray, leaf: float, pcl_rounding: bool, values: np.ndarray | None = None
) -> tuple[VoxelGridResult, np.ndarray | None, tuple[np.ndarray, np.ndarray] | None]:
    """:func:`voxel_grid` on validated input (C-contiguous finite float64 (N, 3), leaf > 0); the
    per-voxel mean (M,) of the optional per-point ``values`` (N,) float64 (None when not given),
    equal to ``np.bincount(point_voxel, weights=values) / counts`` bit for bit; and the points of
    each voxel as ``(packed, start)`` for ``_voxel_kernels.points_of_voxels`` (None on the
    fallback paths)."""
    if len(pts) == 0:
        empty = VoxelGridResult(
            np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64), leaf
        )
        return empty, (None if values is None else np.zeros(0)), None
    pts = _read_only(pts)
    values = None if values is None else _read_only(values)
    lo, hi = _k.coord_bounds(pts, leaf, pcl_rounding)
    extent = hi - lo + 1.0  # voxels per axis (float: may exceed int64)
    n_keys = float(np.prod(extent))
    if n_keys <= 2.0**31 and len(pts) < 2**32:  # key and point index packed in one int64
        packed = _k.sorted_packed_keys(
            pts, leaf, pcl_rounding, lo, int(extent[0]), int(extent[1]), int(n_keys) - 1
        )
        centroids, counts, inverse, means, start = _k.centroids_from_packed(
            pts, _NO_VALUES if values is None else values, packed
        )
        result = VoxelGridResult(centroids, inverse, counts, leaf)
        return result, (None if values is None else means), (packed, start)
    if n_keys < 2.0**62:
        ijk, lo, _ = _k.voxel_coords(pts, leaf, pcl_rounding)
        keys = _k.packed_keys(ijk, lo, int(extent[0]), int(extent[1]))
        order, sorted_keys = _k.radix_argsort(keys, int(n_keys) - 1)  # stable
        centroids, counts, inverse = _k.centroids_from_order(pts, sorted_keys, order)
    else:  # astronomically sparse grid: sort rows (k, j, i) instead of packed keys
        ijk, _, _ = _k.voxel_coords(pts, leaf, pcl_rounding)
        _, inverse, counts = np.unique(
            ijk[:, ::-1], axis=0, return_inverse=True, return_counts=True
        )
        inverse = inverse.reshape(-1).astype(np.int64)
        centroids = np.stack([np.bincount(inverse, weights=pts[:, a]) for a in range(3)], axis=1)
        centroids /= counts[:, None]
    result = VoxelGridResult(centroids, inverse, counts.astype(np.int64), leaf)
    if values is None:
        return result, None, None
    means = np.bincount(inverse, weights=values, minlength=len(counts)) / result.counts
    return result, means, None


def voxel_downsample(
    points_xyz_m: np.ndarray, leaf_m: float, *, pcl_rounding: bool = False
) -> np.ndarray:
    """Centroid of the points of each occupied voxel of edge ``leaf_m`` (PCL ``VoxelGrid``).

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Points in metres; must be finite.
    leaf_m : float
        Voxel edge length in metres, > 0.
    pcl_rounding : bool
        Voxel index computed in float32 exactly as PCL 1.13 does (see :func:`voxel_grid`).

    Returns
    -------
    ndarray of shape (M, 3)
        Voxel centroids in metres, sorted by voxel index (z slowest, x fastest) as PCL outputs them.
    """
    return voxel_grid(points_xyz_m, leaf_m, pcl_rounding=pcl_rounding).points_xyz_m
