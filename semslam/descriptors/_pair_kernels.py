"""Numba kernels of PCL's point-pair features, SPFH and FPFH. Don't call directly; use
:func:`semslam.descriptors.fpfh.compute_fpfh`."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

N_BINS = 11


@njit(cache=True, inline="always")
def pair_features(p1, n1, p2, n2):  # pragma: no cover - compiled
    """PCL ``computePairFeatures``: returns (ok, f1, f2, f3, f4); f1..f4 = 0 when not ok.
    See :func:`pair_features_sym`."""
    ok, f1, f2, f3, f4, _ = pair_features_sym(p1, n1, p2, n2)
    return ok, f1, f2, f3, f4


@njit(cache=True, inline="always")
def pair_features_sym(p1, n1, p2, n2):  # pragma: no cover - compiled
    """PCL ``computePairFeatures``: returns (ok, f1, f2, f3, f4, symmetric); f1..f4 = 0 when not ok.

    f1 = atan2(w.n2, u.n2), f2 = v.n2, f3 = u.d/|d|, f4 = |d| with the Darboux frame u = n1,
    v = d x u / |d x u|, w = u x v, after swapping the points so that the source is the one whose
    normal makes the smaller angle with the line joining them.

    ``symmetric``: the features of (p2, n2, p1, n1) are bit for bit the same (the swapped call
    swaps back, with exactly negated dot products); False only when the swap test ties (or a
    normal is NaN), where both calls keep their own source point.
    """
    dx = p2[0] - p1[0]
    dy = p2[1] - p1[1]
    dz = p2[2] - p1[2]
    f4 = math.sqrt(dx * dx + dy * dy + dz * dz)
    if f4 == 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, True
    a1 = (n1[0] * dx + n1[1] * dy + n1[2] * dz) / f4
    a2 = (n2[0] * dx + n2[1] * dy + n2[2] * dz) / f4
    ux, uy, uz = n1[0], n1[1], n1[2]
    mx, my, mz = n2[0], n2[1], n2[2]
    c1 = math.acos(abs(a1))
    c2 = math.acos(abs(a2))
    symmetric = c1 > c2 or c2 > c1
    if c1 > c2:
        ux, uy, uz = n2[0], n2[1], n2[2]
        mx, my, mz = n1[0], n1[1], n1[2]
        dx, dy, dz = -dx, -dy, -dz
        f3 = -a2
    else:
        f3 = a1
    vx = dy * uz - dz * uy
    vy = dz * ux - dx * uz
    vz = dx * uy - dy * ux
    vn = math.sqrt(vx * vx + vy * vy + vz * vz)
    if vn == 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, symmetric
    vx /= vn
    vy /= vn
    vz /= vn
    wx = uy * vz - uz * vy
    wy = uz * vx - ux * vz
    wz = ux * vy - uy * vx
    f2 = vx * mx + vy * my + vz * mz
    f1 = math.atan2(wx * mx + wy * my + wz * mz, ux * mx + uy * my + uz * mz)
    return True, f1, f2, f3, f4, symmetric


@njit(cache=True, inline="always")
def _bin(value, nbins):  # pragma: no cover - compiled
    if value != value:  # NaN (a NaN normal): C's int cast gives INT_MIN, clamped to bin 0 by PCL
        return 0
    b = int(math.floor(value))
    if b < 0:
        return 0
    if b >= nbins:
        return nbins - 1
    return b


@njit(cache=True, nogil=True)
def spfh(points, normals, indptr, indices, valid, skip_invalid):  # pragma: no cover - compiled
    """SPFH (N, 33) of every point over its CSR neighbourhood (which contains the point itself).

    As PCL's ``computePointSPFHSignature``: each neighbour q != p adds 100/(k-1) to the f1, f2, f3
    11-bin blocks (a failed pair, e.g. coincident points, counts as f = 0 like PCL). With
    ``skip_invalid``, points whose ``valid`` is False (no finite normal) are left out of every
    neighbourhood and their own row is zero; otherwise they are kept as PCL does (their NaN
    features fall in bin 0; ``normals`` must then hold the NaNs).
    """
    n = len(indptr) - 1
    out = np.zeros((n, 3 * N_BINS))
    for i in range(n):
        if skip_invalid and not valid[i]:
            continue
        k = 0
        for t in range(indptr[i], indptr[i + 1]):
            if valid[indices[t]] or not skip_invalid:
                k += 1
        if k < 2:
            continue
        incr = 100.0 / (k - 1)
        for t in range(indptr[i], indptr[i + 1]):
            j = indices[t]
            if j == i or (skip_invalid and not valid[j]):
                continue
            ok, f1, f2, f3, f4 = pair_features(points[i], normals[i], points[j], normals[j])
            out[i, _bin(N_BINS * ((f1 + math.pi) / (2.0 * math.pi)), N_BINS)] += incr
            out[i, N_BINS + _bin(N_BINS * ((f2 + 1.0) * 0.5), N_BINS)] += incr
            out[i, 2 * N_BINS + _bin(N_BINS * ((f3 + 1.0) * 0.5), N_BINS)] += incr
    return out


@njit(cache=True, inline="always")
def _add_pair(out, i, f1, f2, f3, incr):  # pragma: no cover - compiled
    out[i, _bin(N_BINS * ((f1 + math.pi) / (2.0 * math.pi)), N_BINS)] += incr
    out[i, N_BINS + _bin(N_BINS * ((f2 + 1.0) * 0.5), N_BINS)] += incr
    out[i, 2 * N_BINS + _bin(N_BINS * ((f3 + 1.0) * 0.5), N_BINS)] += incr


@njit(cache=True, nogil=True)
def spfh_symmetric(points, normals, indptr, indices, valid, skip_invalid):  # pragma: no cover
    """:func:`spfh` for symmetric neighbourhoods (j in row i <=> i in row j, as radius searches):
    each pair's features are computed once and binned into both rows, unless the swap test ties
    (then each side computes its own). Same result bit for bit: every row only ever adds its
    own constant increment, so the order of the additions does not matter.
    """
    n = len(indptr) - 1
    out = np.zeros((n, 3 * N_BINS))
    incr = np.zeros(n)
    for i in range(n):
        if skip_invalid and not valid[i]:
            continue
        k = 0
        for t in range(indptr[i], indptr[i + 1]):
            if valid[indices[t]] or not skip_invalid:
                k += 1
        if k >= 2:
            incr[i] = 100.0 / (k - 1)
    for i in range(n):
        if incr[i] == 0.0:
            continue
        for t in range(indptr[i], indptr[i + 1]):
            j = indices[t]
            if j <= i or (skip_invalid and not valid[j]):
                continue
            _add_pair_both(out, points, normals, i, j, incr)
    return out


@njit(cache=True, inline="always")
def _add_pair_both(out, points, normals, i, j, incr):  # pragma: no cover - compiled
    """Bin the pair (i, j) into both rows: its features computed once, unless the swap test ties (then each side
    computes its own)."""
    _, f1, f2, f3, _, sym = pair_features_sym(points[i], normals[i], points[j], normals[j])
    _add_pair(out, i, f1, f2, f3, incr[i])
    if not sym:
        _, f1, f2, f3, _, sym = pair_features_sym(points[j], normals[j], points[i], normals[i])
    _add_pair(out, j, f1, f2, f3, incr[j])


@njit(cache=True, nogil=True)
def fpfh_from_spfh(spfh_hist, indptr, indices, sqdist):  # pragma: no cover - compiled
    """FPFH (N, 33): for each point, sum of its neighbours' SPFH weighted by 1/d^2 (neighbours at
    distance 0, the point itself included, are skipped; the point's own SPFH is not added), then each
    11-bin block rescaled to sum to 100 (left zero when empty), as PCL's ``weightPointSPFHSignature``.
    """
    n = len(indptr) - 1
    out = np.zeros((n, spfh_hist.shape[1]))
    for i in range(n):
        a, e = indptr[i], indptr[i + 1]
        _fpfh_row(spfh_hist, i, indices[a:e], sqdist[a:e], e - a, out)
    return out


@njit(cache=True, inline="always")
def _fpfh_row(spfh, i, nbrs, sqd, m, out):  # pragma: no cover - compiled
    """One row of :func:`fpfh_from_spfh` from ``nbrs[:m]`` and their squared distances."""
    nb = spfh.shape[1]
    for u in range(m):
        d2 = sqd[u]
        if d2 == 0.0:
            continue
        w = 1.0 / d2
        j = nbrs[u]
        for b in range(nb):
            out[i, b] += spfh[j, b] * w
    for blk in range(3):
        s = 0.0
        for b in range(blk * N_BINS, (blk + 1) * N_BINS):
            s += out[i, b]
        if s != 0.0:
            s = 100.0 / s
            for b in range(blk * N_BINS, (blk + 1) * N_BINS):
                out[i, b] *= s
