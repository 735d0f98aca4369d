"""Numba kernels of the voxel grid. Private: call :func:`semslam.segmentation.voxel_grid`."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
def packed_keys(ijk, lo, nx, ny):
    """Linear voxel index ``i + nx*(j + ny*k)`` relative to ``lo`` (PCL's order: x fastest), (N,) int64."""
    n = ijk.shape[0]
    keys = np.empty(n, np.int64)
    for i in range(n):
        keys[i] = np.int64(ijk[i, 0] - lo[0]) + nx * (
            np.int64(ijk[i, 1] - lo[1]) + ny * np.int64(ijk[i, 2] - lo[2])
        )
    return keys


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
def radix_argsort(keys, max_key):
    """Stable argsort (N,) int64 of non-negative int64 ``keys`` <= ``max_key``, and the sorted keys:
    LSD radix sort on 11-bit digits (3 passes for keys < 2**33). 2048 buckets keep the scatter
    targets in cache (16-bit digits were ~3x slower on 100k keys). Equal keys keep their input
    order, so each centroid is summed in input order."""
    n = keys.shape[0]
    order = np.arange(n)
    k_cur = keys.copy()
    order_tmp = np.empty(n, np.int64)
    k_tmp = np.empty(n, np.int64)
    n_buckets = 2048
    count = np.empty(n_buckets + 1, np.int64)
    shift = 0
    while shift == 0 or (shift < 63 and (max_key >> shift) > 0):
        count[:] = 0
        for i in range(n):
            count[((k_cur[i] >> shift) & 0x7FF) + 1] += 1
        if count[1] == n:  # every key has digit 0 here: nothing to move
            shift += 11
            continue
        for d in range(n_buckets):
            count[d + 1] += count[d]
        for i in range(n):
            d = (k_cur[i] >> shift) & 0x7FF
            r = count[d]
            count[d] = r + 1
            order_tmp[r] = order[i]
            k_tmp[r] = k_cur[i]
        order, order_tmp = order_tmp, order
        k_cur, k_tmp = k_tmp, k_cur
        shift += 11
    return order, k_cur


@njit(cache=True, nogil=True)
def coord_bounds(points, leaf, pcl_rounding):
    """Per-axis minimum and maximum (3,) each of the voxel coordinates of :func:`voxel_coords`,
    computed from the coordinate extremes (floor and the division are monotone, so
    ``min(floor(p / leaf)) == floor(min(p) / leaf)``) without storing the (N, 3) coordinates."""
    n = points.shape[0]
    pmin = np.full(3, np.inf)
    pmax = np.full(3, -np.inf)
    for i in range(n):
        for a in range(3):
            v = points[i, a]
            pmin[a] = min(pmin[a], v)
            pmax[a] = max(pmax[a], v)
    lo = np.empty(3)
    hi = np.empty(3)
    inv32 = np.float32(1.0 / leaf)
    for a in range(3):
        if pcl_rounding:
            lo[a] = np.floor(np.float32(np.float32(pmin[a]) * inv32))
            hi[a] = np.floor(np.float32(np.float32(pmax[a]) * inv32))
        else:
            lo[a] = np.floor(pmin[a] / leaf)
            hi[a] = np.floor(pmax[a] / leaf)
    return lo, hi


@njit(cache=True, nogil=True)
def sorted_packed_keys(points, leaf, pcl_rounding, lo, nx, ny, max_key):
    """Stable sort of the points by voxel key, as one (N,) int64 array ``key << 32 | point index``.

    Requires ``max_key < 2**31`` and N < 2**32. Keys are computed as :func:`voxel_coords` +
    :func:`packed_keys` do (same float arithmetic), then LSD radix-sorted on the key digits only
    (at most 12 bits per pass, passes balanced); packing index and key in one word halves the
    bytes each pass scatters. Points of one voxel stay in input order (stable).
    """
    n = points.shape[0]
    key_bits = 1
    while (max_key >> key_bits) > 0:
        key_bits += 1
    n_pass = (key_bits + 11) // 12
    bits = (key_bits + n_pass - 1) // n_pass
    n_buckets = 1 << bits
    digit_mask = n_buckets - 1
    count = np.zeros((n_pass, n_buckets), np.int64)
    cur = np.empty(n, np.int64)
    inv32 = np.float32(1.0 / leaf)
    for i in range(n):
        if pcl_rounding:
            vx = np.floor(np.float32(np.float32(points[i, 0]) * inv32))
            vy = np.floor(np.float32(np.float32(points[i, 1]) * inv32))
            vz = np.floor(np.float32(np.float32(points[i, 2]) * inv32))
        else:
            vx = np.floor(points[i, 0] / leaf)
            vy = np.floor(points[i, 1] / leaf)
            vz = np.floor(points[i, 2] / leaf)
        key = np.int64(vx - lo[0]) + nx * (np.int64(vy - lo[1]) + ny * np.int64(vz - lo[2]))
        cur[i] = (key << 32) | i
        for q in range(n_pass):
            count[q, (key >> (q * bits)) & digit_mask] += 1
    tmp = np.empty(n, np.int64)
    for q in range(n_pass):
        if count[q, 0] == n:  # this digit is 0 for every key: nothing moves
            continue
        total = 0
        for d in range(n_buckets):
            c = count[q, d]
            count[q, d] = total
            total += c
        shift = 32 + q * bits
        for i in range(n):
            v = cur[i]
            d = (v >> shift) & digit_mask
            r = count[q, d]
            count[q, d] = r + 1
            tmp[r] = v
        cur, tmp = tmp, cur
    return cur


@njit(cache=True, nogil=True)
def centroids_from_packed(points, values, packed):
    """Centroids (M, 3), counts (M,), voxel row of every point (N,) and per-voxel means (M,) of
    ``values`` ((N,), or (0,) for none) from the sorted words of :func:`sorted_packed_keys`; and
    ``start`` (M + 1,): voxel v holds the points ``packed[start[v]:start[v + 1]] & (2**32 - 1)``.

    The voxel of every point is read off the sorted words, then the coordinates and values are
    summed in one sequential pass over the points (input order, as :func:`centroids_from_order`
    and ``np.bincount`` sum them): the scattered accesses go to the per-voxel sums, which scan
    order keeps local, instead of gathering the points in voxel order (~30 % faster).
    """
    n = points.shape[0]
    has_values = values.shape[0] == n
    start = np.empty(n + 1, np.int64)  # M + 1 <= N + 1 entries used
    point_voxel = np.empty(n, np.int64)
    v = -1
    prev = -1
    for r in range(n):
        word = packed[r]
        key = word >> 32
        if key != prev:
            v += 1
            prev = key
            start[v] = r
        point_voxel[word & 0xFFFFFFFF] = v
    m = v + 1
    start[m] = n
    start = start[: m + 1]
    sums = np.zeros((m, 3))
    means = np.zeros(m if has_values else 0)
    for i in range(n):
        v = point_voxel[i]
        sums[v, 0] += points[i, 0]
        sums[v, 1] += points[i, 1]
        sums[v, 2] += points[i, 2]
        if has_values:
            means[v] += values[i]
    counts = np.empty(m, np.int64)
    for v in range(m):
        c = start[v + 1] - start[v]
        counts[v] = c
        sums[v, 0] /= c
        sums[v, 1] /= c
        sums[v, 2] /= c
        if has_values:
            means[v] /= c
    return sums, counts, point_voxel, means, start


@njit(cache=True, nogil=True)
def points_of_voxels(packed, start, voxels):
    """Sorted indices (int64) of the points of the given voxels (distinct), from the words and run
    starts of :func:`sorted_packed_keys` / :func:`centroids_from_packed`."""
    total = 0
    for v in voxels:
        total += start[v + 1] - start[v]
    out = np.empty(total, np.int64)
    j = 0
    for v in voxels:
        for r in range(start[v], start[v + 1]):
            out[j] = packed[r] & 0xFFFFFFFF
            j += 1
    out.sort()
    return out


@njit(cache=True, nogil=True)
def points_in_voxels(point_voxel, voxels, n_voxels):
    """Sorted indices (int64) of the points whose voxel ``point_voxel[i]`` is one of ``voxels``
    (any order, values in [0, n_voxels))."""
    selected = np.zeros(n_voxels, np.bool_)
    for v in voxels:
        selected[v] = True
    n = point_voxel.shape[0]
    count = 0
    for i in range(n):
        if selected[point_voxel[i]]:
            count += 1
    out = np.empty(count, np.int64)
    j = 0
    for i in range(n):
        if selected[point_voxel[i]]:
            out[j] = i
            j += 1
    return out
