"""Numba kernel of the fixed-radius neighbour search on a uniform grid (voxel hash). Don't call
directly; use :func:`semslam.descriptors.find_neighbors`.

Points are bucketed into cubic cells of side ``cell_m`` >= the radius (counting sort when the
bounding grid is small, a stable argsort of the cell keys otherwise), so every neighbour of a
point lies in the 3x3x3 block of cells around it. For each (x, y) column of that block the
three z-cells are contiguous in key order: one range of the sorted points per column, found by
a dense cell table or by binary search.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..segmentation._voxel_kernels import radix_argsort  # a stable sort without numba's mergesort code

#: Dense cell table when the bounding grid has at most this many cells per point (+ a constant).
DENSE_CELLS_PER_POINT = 8
DENSE_CELLS_MIN = 1 << 16
#: Clouds spanning fewer cells than this along every axis get cells relative to their minimum (packed
#: keys); wider ones (far outliers) get compressed absolute cells (:func:`_compressed_cells`).
DIRECT_CELLS_PER_AXIS = float(1 << 20)
#: Largest ``max |p| / cell`` the grid accepts (floor stays exact in int64); beyond it, KD-tree search.
MAX_ABS_CELLS = float(1 << 52)


@njit(cache=True, nogil=True)
def _bucket(points, origin, cell_m):  # pragma: no cover - compiled
    """Sort the points by grid cell (stable: by index within a cell).

    ``points`` (N, 3) float64; ``origin`` (3,) their minimum on every axis (cell (0, 0, 0) starts
    there); ``cell_m`` the cell side, slightly above the radius (see ``find_neighbors``) and large
    enough that the cell keys n_x n_y n_z fit in int64.

    Returns (order (N,) the point indices in cell order, skeys (N,) their cell keys, spts (N, 3)
    their coordinates, cells (N, 3) their cell coordinates, start the table of n_x n_y n_z + 1
    cell starts in the sorted order (empty when the grid is too large: binary search instead),
    dims (3,) the grid size).
    """
    n = points.shape[0]
    cells = np.empty((n, 3), dtype=np.int64)
    dims = np.ones(3, dtype=np.int64)
    span = 0.0
    for i in range(n):
        for a in range(3):
            span = max(span, (points[i, a] - origin[a]) / cell_m)
    if span < DIRECT_CELLS_PER_AXIS:
        for i in range(n):
            for a in range(3):
                c = math.floor((points[i, a] - origin[a]) / cell_m)
                cells[i, a] = c
                dims[a] = max(dims[a], c + 1)
    else:
        _compressed_cells(points, origin, cell_m, cells, dims)
    ny = dims[1]
    nz = dims[2]
    keys = np.empty(n, dtype=np.int64)
    for i in range(n):
        keys[i] = (cells[i, 0] * ny + cells[i, 1]) * nz + cells[i, 2]
    n_cells = dims[0] * ny * nz
    if n_cells <= DENSE_CELLS_PER_POINT * n + DENSE_CELLS_MIN:  # counting sort, dense table
        start = np.zeros(n_cells + 1, dtype=np.int64)
        for i in range(n):
            start[keys[i] + 1] += 1
        for c in range(n_cells):
            start[c + 1] += start[c]
        fill = start[:-1].copy()
        order = np.empty(n, dtype=np.int64)
        for i in range(n):
            order[fill[keys[i]]] = i
            fill[keys[i]] += 1
    else:
        start = np.zeros(0, dtype=np.int64)
        order = radix_argsort(keys, n_cells - 1)[0]  # stable, as np.argsort(kind="stable")
    skeys = np.empty(n, dtype=np.int64)
    spts = np.empty((n, 3))
    scells = np.empty((n, 3), dtype=np.int64)
    for s in range(n):
        i = order[s]
        skeys[s] = keys[i]
        for a in range(3):
            spts[s, a] = points[i, a]
            scells[s, a] = cells[i, a]
    return order, skeys, spts, scells, start, dims


@njit(cache=True, nogil=True)
def _compressed_cells(points, origin, cell_m, cells, dims):  # pragma: no cover - compiled
    """Cells of a cloud spanning too many cells for packed keys (one point at 1e9 m): absolute cell
    coordinates ``floor(p / cell_m)`` (precise near 0 whatever the outliers), then on each axis the
    occupied coordinates renumbered in order, consecutive ones 1 apart and the others 2 apart, so that
    cells stay adjacent exactly when they were. The grid then has at most 2 N cells per axis: its size
    follows the occupied cells, not the extent."""
    n = points.shape[0]
    big = 0.0
    for i in range(n):
        for a in range(3):
            big = max(big, abs(points[i, a]) / cell_m)
    shift = np.zeros(3) if big < MAX_ABS_CELLS else origin  # relative cells: the caller checks the span
    total = 1.0
    raw = np.empty(n, dtype=np.int64)
    for a in range(3):
        lowest = 0
        highest = 0
        for i in range(n):
            raw[i] = math.floor((points[i, a] - shift[a]) / cell_m)
            lowest = raw[i] if i == 0 else min(lowest, raw[i])
            highest = raw[i] if i == 0 else max(highest, raw[i])
        for i in range(n):
            raw[i] -= lowest  # < 2**53 (MAX_ABS_CELLS): no overflow
        order, sorted_raw = radix_argsort(raw, highest - lowest)
        comp = 0  # the occupied coordinates in order, renumbered
        for s in range(n):
            if s > 0 and sorted_raw[s] != sorted_raw[s - 1]:
                comp += 1 if sorted_raw[s] - sorted_raw[s - 1] == 1 else 2
            cells[order[s], a] = comp
        dims[a] = comp + 1
        total *= float(dims[a])
    if total >= 4.0e18:
        raise ValueError("too many occupied grid cells for 64-bit cell keys")


@njit(cache=True, inline="always")
def _first_at_least(sorted_keys, key):  # pragma: no cover - compiled
    """First position of ``sorted_keys`` (ascending) whose key is >= ``key`` (``np.searchsorted`` side "left",
    written out: numba's brings ~100 kB of code into every kernel a cold process loads)."""
    lo = 0
    hi = sorted_keys.shape[0]
    while lo < hi:
        mid = (lo + hi) >> 1
        if sorted_keys[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, inline="always")
def _block(s0, skeys, scells, start, dims, lo, hi):  # pragma: no cover - compiled
    """Ranges lo[c]:hi[c] of the sorted points in the 3x3x3 cells around sorted point s0's cell,
    one per (x, y) column; returns their number."""
    nx = dims[0]
    ny = dims[1]
    nz = dims[2]
    cx = scells[s0, 0]
    cy = scells[s0, 1]
    cz = scells[s0, 2]
    zlo = max(cz - 1, 0)
    zhi = min(cz + 1, nz - 1)
    n_cols = 0
    for ax in range(max(cx - 1, 0), min(cx + 2, nx)):
        for ay in range(max(cy - 1, 0), min(cy + 2, ny)):
            base = (ax * ny + ay) * nz
            if start.size:
                a = start[base + zlo]
                b = start[base + zhi + 1]
            else:
                a = _first_at_least(skeys, base + zlo)
                b = _first_at_least(skeys, base + zhi + 1)
            if b > a:
                lo[n_cols] = a
                hi[n_cols] = b
                n_cols += 1
    return n_cols


@njit(cache=True, nogil=True)
def grid_bucket_count(points, origin, cell_m, radius_m):  # pragma: no cover - compiled
    """Bucket the points (see :func:`_bucket`) and count the points closer than ``radius_m`` to
    each point (itself included). Returns (grid, counts (N,)) where grid is the tuple
    :func:`grid_fill` takes. (One kernel rather than two: each costs ~25 ms to load from the
    cache on the first call.)"""
    grid = _bucket(points, origin, cell_m)
    return grid, _count(*grid, radius_m)


@njit(cache=True, nogil=True)
def _count(order, skeys, spts, scells, start, dims, radius_m):  # pragma: no cover - compiled
    """Number of points closer than ``radius_m`` to each point (itself included), shape (N,)."""
    n = order.shape[0]
    r2 = radius_m * radius_m
    counts = np.empty(n, dtype=np.int64)
    lo = np.empty(9, dtype=np.int64)
    hi = np.empty(9, dtype=np.int64)
    s0 = 0
    while s0 < n:
        s1 = s0 + 1  # the points s0..s1-1 share a cell
        while s1 < n and skeys[s1] == skeys[s0]:
            s1 += 1
        n_cols = _block(s0, skeys, scells, start, dims, lo, hi)
        for s in range(s0, s1):
            px = spts[s, 0]
            py = spts[s, 1]
            pz = spts[s, 2]
            k = 0
            for c in range(n_cols):
                for t in range(lo[c], hi[c]):
                    dx = spts[t, 0] - px
                    dy = spts[t, 1] - py
                    dz = spts[t, 2] - pz
                    k += ((dx * dx + dy * dy) + dz * dz) < r2
            counts[order[s]] = k
        s0 = s1
    return counts


@njit(cache=True, inline="always")
def gather(s, order, spts, lo, hi, n_cols, r2, max_nn, buf_i, buf_d):  # pragma: no cover - compiled
    """Neighbours (squared distance < r2) of sorted point ``s`` into ``buf_i`` (indices) and ``buf_d``
    (squared distances), column by column (x, then y), by cell z, then by increasing index; returns their
    number. With ``max_nn`` > 0 and more neighbours than that, only the ``max_nn`` nearest are kept, by
    increasing distance (ties in search order), as a FLANN radius search with ``max_nn``."""
    px = spts[s, 0]
    py = spts[s, 1]
    pz = spts[s, 2]
    m = 0
    for c in range(n_cols):
        for t in range(lo[c], hi[c]):
            dx = spts[t, 0] - px
            dy = spts[t, 1] - py
            dz = spts[t, 2] - pz
            d2 = (dx * dx + dy * dy) + dz * dz
            if d2 < r2:
                buf_i[m] = order[t]
                buf_d[m] = d2
                m += 1
    if max_nn > 0 and m > max_nn:
        key = np.argsort(buf_d[:m], kind="mergesort")[:max_nn]
        sel_i = buf_i[key]
        sel_d = buf_d[key]
        buf_i[:max_nn] = sel_i
        buf_d[:max_nn] = sel_d
        m = max_nn
    return m


@njit(cache=True, inline="always")
def cell_end(s0, skeys):  # pragma: no cover - compiled
    """First sorted position after ``s0`` in another cell."""
    s1 = s0 + 1
    n = skeys.shape[0]
    while s1 < n and skeys[s1] == skeys[s0]:
        s1 += 1
    return s1


@njit(cache=True, nogil=True)
def grid_fill(order, skeys, spts, scells, start, dims, radius_m, max_nn, indptr, indices, sqdist):  # pragma: no cover
    """Fill the CSR ``indices`` and ``sqdist`` (squared distance < radius^2) given ``indptr`` from
    :func:`grid_bucket_count` (row sizes capped at ``max_nn`` when > 0). Rows in :func:`gather`'s order."""
    n = order.shape[0]
    r2 = radius_m * radius_m
    lo = np.empty(9, dtype=np.int64)
    hi = np.empty(9, dtype=np.int64)
    rowmax = 0
    for i in range(n):
        rowmax = max(rowmax, indptr[i + 1] - indptr[i])
    cap = 0 if max_nn <= 0 else max_nn
    size = n if cap > 0 else rowmax
    buf_i = np.empty(size, dtype=np.int64)
    buf_d = np.empty(size)
    s0 = 0
    while s0 < n:
        s1 = cell_end(s0, skeys)
        n_cols = _block(s0, skeys, scells, start, dims, lo, hi)
        for s in range(s0, s1):
            m = gather(s, order, spts, lo, hi, n_cols, r2, cap, buf_i, buf_d)
            a = indptr[order[s]]
            for u in range(m):
                indices[a + u] = buf_i[u]
                sqdist[a + u] = buf_d[u]
        s0 = s1


@njit(cache=True, nogil=True)
def sort_rows(indptr, indices, sqdist):  # pragma: no cover - compiled
    """Sort every CSR row in place by increasing squared distance, then index (insertion sort:
    rows are short)."""
    for i in range(len(indptr) - 1):
        for t in range(indptr[i] + 1, indptr[i + 1]):
            d = sqdist[t]
            j = indices[t]
            u = t - 1
            while u >= indptr[i] and (sqdist[u] > d or (sqdist[u] == d and indices[u] > j)):
                sqdist[u + 1] = sqdist[u]
                indices[u + 1] = indices[u]
                u -= 1
            sqdist[u + 1] = d
            indices[u + 1] = j
