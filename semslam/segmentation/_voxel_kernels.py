"""Numba kernels of the voxel grid. Private: call :func:`semslam.segmentation.voxel_grid`."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def voxel_coords(points, leaf, pcl_rounding):
    """Integer voxel coordinates (N, 3) float64 = floor(p / leaf), or PCL's float32
    floor(float32(p) * float32(1 / leaf)); and their per-axis minimum and maximum (3,) each."""
    n = points.shape[0]
    ijk = np.empty((n, 3))
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    inv32 = np.float32(1.0 / leaf)
    for i in range(n):
        for a in range(3):
            if pcl_rounding:
                v = np.floor(np.float32(np.float32(points[i, a]) * inv32))
            else:
                v = np.floor(points[i, a] / leaf)
            ijk[i, a] = v
            lo[a] = min(lo[a], v)
            hi[a] = max(hi[a], v)
    return ijk, lo, hi


@njit(cache=True)
def packed_keys(ijk, lo, nx, ny):
    """Linear voxel index ``i + nx*(j + ny*k)`` relative to ``lo`` (PCL's order: x fastest), (N,) int64."""
    n = ijk.shape[0]
    keys = np.empty(n, np.int64)
    for i in range(n):
        keys[i] = np.int64(ijk[i, 0] - lo[0]) + nx * (
            np.int64(ijk[i, 1] - lo[1]) + ny * np.int64(ijk[i, 2] - lo[2])
        )
    return keys


@njit(cache=True)
def centroids_from_order(points, sorted_keys, order):
    """Given ``order`` sorting the points by key and ``sorted_keys = keys[order]``: centroids (M, 3),
    counts (M,), and the voxel row of every point (N,), voxels in ascending key order."""
    n = points.shape[0]
    m = 1
    for r in range(1, n):
        if sorted_keys[r] != sorted_keys[r - 1]:
            m += 1
    sums = np.zeros((m, 3))
    counts = np.zeros(m, np.int64)
    point_voxel = np.empty(n, np.int64)
    v = 0
    for r in range(n):
        if r > 0 and sorted_keys[r] != sorted_keys[r - 1]:
            v += 1
        p = order[r]
        sums[v, 0] += points[p, 0]
        sums[v, 1] += points[p, 1]
        sums[v, 2] += points[p, 2]
        counts[v] += 1
        point_voxel[p] = v
    for v in range(m):
        sums[v, 0] /= counts[v]
        sums[v, 1] /= counts[v]
        sums[v, 2] /= counts[v]
    return sums, counts, point_voxel


@njit(cache=True)
def radix_argsort(keys, max_key):
    """Stable argsort (N,) int64 of non-negative int64 ``keys`` <= ``max_key``: LSD radix sort on 16-bit
    digits (2 passes for keys < 2**32; ~3x faster than ``np.argsort`` on 100k keys). Points of one voxel
    keep their input order, so each centroid is summed in input order."""
    n = keys.shape[0]
    order = np.arange(n)
    k_cur = keys.copy()
    order_tmp = np.empty(n, np.int64)
    k_tmp = np.empty(n, np.int64)
    count = np.empty(65537, np.int64)
    shift = 0
    while shift == 0 or (shift < 63 and (max_key >> shift) > 0):
        count[:] = 0
        for i in range(n):
            count[((k_cur[i] >> shift) & 0xFFFF) + 1] += 1
        for d in range(65536):
            count[d + 1] += count[d]
        for i in range(n):
            d = (k_cur[i] >> shift) & 0xFFFF
            r = count[d]
            count[d] = r + 1
            order_tmp[r] = order[i]
            k_tmp[r] = k_cur[i]
        order, order_tmp = order_tmp, order
        k_cur, k_tmp = k_tmp, k_cur
        shift += 16
    return order, k_cur
