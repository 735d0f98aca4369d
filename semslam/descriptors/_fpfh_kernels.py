"""Numba kernels of FPFH over radius neighbourhoods streamed from the grid search, without storing them.
Don't call directly; use :func:`semslam.descriptors.fpfh.compute_fpfh`.

Memory is O(N) (the grid, the SPFH and the FPFH histograms) instead of 16 bytes per neighbour pair
of the compressed-row neighbourhoods (~1 GB for a dense 90k-point scan). Neighbours come in
:func:`~._neighbors_kernels.gather`'s order, the order of ``find_neighbors``' rows, so the result is
bit for bit that of :func:`~._pair_kernels.spfh_symmetric` / :func:`~._pair_kernels.fpfh_from_spfh`
on those rows (and of :func:`~._pair_kernels.spfh` on capped rows).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._neighbors_kernels import _block, _bucket, cell_end, gather
from ._pair_kernels import N_BINS, _add_pair_both, _bin, _fpfh_row, pair_features


@njit(cache=True, nogil=True)
def streamed_fpfh(points, normals, valid, skip_invalid, origin, cell_m, radius_m, max_nn):  # pragma: no cover
    """FPFH (N, 33) of every point over its radius neighbourhood (at most ``max_nn`` nearest when > 0).
    Returns (fpfh, n_neighbors (N,) int64 before any cap, capped: bool)."""
    grid = _bucket(points, origin, cell_m)
    order, skeys, spts, scells, start, dims = grid
    n = order.shape[0]
    r2 = radius_m * radius_m
    lo = np.empty(9, dtype=np.int64)
    hi = np.empty(9, dtype=np.int64)
    buf_i = np.empty(n, dtype=np.int64)
    buf_d = np.empty(n)
    counts = np.zeros(n, dtype=np.int64)
    incr = np.zeros(n)
    # pass 1: neighbour counts (valid ones with skip_invalid): SPFH increments 100 / (k - 1)
    s0 = 0
    while s0 < n:
        s1 = cell_end(s0, skeys)
        n_cols = _block(s0, skeys, scells, start, dims, lo, hi)
        for s in range(s0, s1):
            m = gather(s, order, spts, lo, hi, n_cols, r2, 0, buf_i, buf_d)
            i = order[s]
            counts[i] = m
            if skip_invalid and not valid[i]:
                continue
            k = 0
            for u in range(m):  # (unused when capped: _spfh_row counts the capped rows itself)
                if valid[buf_i[u]] or not skip_invalid:
                    k += 1
            if k >= 2:
                incr[i] = 100.0 / (k - 1)
        s0 = s1
    capped = max_nn > 0 and n > 0 and counts.max() > max_nn
    cap = max_nn if capped else 0
    spfh = np.zeros((n, 3 * N_BINS))
    # pass 2: SPFH; symmetric neighbourhoods compute each pair once (as spfh_symmetric)
    s0 = 0
    while s0 < n:
        s1 = cell_end(s0, skeys)
        n_cols = _block(s0, skeys, scells, start, dims, lo, hi)
        for s in range(s0, s1):
            i = order[s]
            if incr[i] == 0.0 and not capped:
                continue
            m = gather(s, order, spts, lo, hi, n_cols, r2, cap, buf_i, buf_d)
            if capped:
                _spfh_row(points, normals, valid, skip_invalid, i, buf_i, m, spfh)
                continue
            for u in range(m):
                j = buf_i[u]
                if j <= i or (skip_invalid and not valid[j]):
                    continue
                _add_pair_both(spfh, points, normals, i, j, incr)
        s0 = s1
    # pass 3: FPFH, the 1/d^2-weighted sum of the neighbours' SPFH (as fpfh_from_spfh)
    out = np.zeros((n, 3 * N_BINS))
    s0 = 0
    while s0 < n:
        s1 = cell_end(s0, skeys)
        n_cols = _block(s0, skeys, scells, start, dims, lo, hi)
        for s in range(s0, s1):
            m = gather(s, order, spts, lo, hi, n_cols, r2, cap, buf_i, buf_d)
            _fpfh_row(spfh, order[s], buf_i, buf_d, m, out)
        s0 = s1
    return out, counts, capped


@njit(cache=True, inline="always")
def _spfh_row(points, normals, valid, skip_invalid, i, nbrs, m, out):  # pragma: no cover - compiled
    """One row of :func:`~._pair_kernels.spfh` from the neighbour list ``nbrs[:m]``."""
    if skip_invalid and not valid[i]:
        return
    k = 0
    for u in range(m):
        if valid[nbrs[u]] or not skip_invalid:
            k += 1
    if k < 2:
        return
    incr = 100.0 / (k - 1)
    for u in range(m):
        j = nbrs[u]
        if j == i or (skip_invalid and not valid[j]):
            continue
        ok, f1, f2, f3, f4 = pair_features(points[i], normals[i], points[j], normals[j])
        out[i, _bin(N_BINS * ((f1 + math.pi) / (2.0 * math.pi)), N_BINS)] += incr
        out[i, N_BINS + _bin(N_BINS * ((f2 + 1.0) * 0.5), N_BINS)] += incr
        out[i, 2 * N_BINS + _bin(N_BINS * ((f3 + 1.0) * 0.5), N_BINS)] += incr
