"""Numba kernels of PCL's ESF (Ensemble of Shape Functions, 640 bins) in float32 arithmetic (glibc's ``rand()``
is in :mod:`._glibc_rand_kernels`). Don't call directly; use :func:`semslam.descriptors.compute_esf`.

Every float operation below is float32 and in PCL 1.13's order (Eigen's 4-vector reductions sum
as (x*x + z*z) + (y*y + 0)), so that the PCL sampler reproduces PCL bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

GRID = 64
GRID_H = 32
PAD = GRID + 2
BINS = 64
F0 = np.float32(0.0)
F05 = np.float32(0.5)
F1 = np.float32(1.0)
F2 = np.float32(2.0)
F32 = np.float32(32.0)
F63 = np.float32(63.0)
F_AREA = np.float32(0.001)
PIH = np.float32(np.float32(math.pi) / np.float32(2.0))
WEIGHTS = np.array([0.5, 0.5, 0.5, 0.5, 0.5, 1.0, 1.0, 2.0, 2.0, 2.0], dtype=np.float32)


# ---------------------------------------------------------------- ESF
@njit(cache=True, nogil=True)
def _vox(v):  # pragma: no cover - compiled
    if v < F0:
        return math.floor(v) + GRID_H
    return math.ceil(v) + GRID_H - 1


@njit(cache=True, nogil=True)
def esf_prepare(points):  # pragma: no cover - compiled
    """Scale float32 points (N, 3) into the 64^3 voxel sphere as PCL does and mark the occupancy grid.

    Returns (local (N, 3) float32, vox (N, 3) int64 voxel coordinates of the points, lut (66^3,)
    uint8 flat padded grid (see ``_flat``), maxd float32). ``maxd == 0`` means that all points
    coincide.
    """
    n = points.shape[0]
    sx = F0
    sy = F0
    sz = F0
    for i in range(n):
        sx += points[i, 0]
        sy += points[i, 1]
        sz += points[i, 2]
    fn = np.float32(n)
    cx = sx / fn
    cy = sy / fn
    cz = sz / fn
    local = np.empty((n, 3), dtype=np.float32)
    maxd = F0
    for i in range(n):
        x = points[i, 0] - cx
        y = points[i, 1] - cy
        z = points[i, 2] - cz
        local[i, 0] = x
        local[i, 1] = y
        local[i, 2] = z
        d = np.sqrt((x * x + y * y) + z * z)
        if d > maxd:
            maxd = d
    lut = np.zeros(PAD * PAD * PAD, dtype=np.uint8)
    vox = np.zeros((n, 3), dtype=np.int64)
    if maxd == F0:
        return local, vox, lut, maxd
    scale = F1 / maxd * F32
    for i in range(n):
        local[i, 0] = local[i, 0] * scale
        local[i, 1] = local[i, 1] * scale
        local[i, 2] = local[i, 2] * scale
        xx = _vox(local[i, 0])
        yy = _vox(local[i, 1])
        zz = _vox(local[i, 2])
        vox[i, 0] = xx
        vox[i, 1] = yy
        vox[i, 2] = zz
        for a in range(xx - 1, xx + 2):
            for b in range(yy - 1, yy + 2):
                for c in range(zz - 1, zz + 2):
                    if 0 <= a < GRID and 0 <= b < GRID and 0 <= c < GRID:
                        lut[_flat(a, b, c)] = 1
    return local, vox, lut, maxd


@njit(cache=True, inline="always")
def _flat(x, y, z):  # pragma: no cover - compiled
    # The grid is padded by one empty voxel on each side: PCL reads outside its 64^3 grid when a
    # point lands exactly on the sphere's boundary (voxel 64, undefined behaviour); here it is empty.
    return ((x + 1) * PAD + (y + 1)) * PAD + (z + 1)


@njit(cache=True, nogil=True)
def _lci(lut, x1, y1, z1, x2, y2, z2):  # pragma: no cover - compiled
    """PCL's 3-D Bresenham line test: (n_in, n_visited), the occupied and visited voxels of the line.

    The major axis has length L; L voxels are visited (start included, end excluded; 1 if L = 0).
    Not inlined on purpose: as its own function the stepping loop keeps its state in registers.
    """
    dx = x2 - x1
    dy = y2 - y1
    dz = z2 - z1
    sx = -PAD * PAD if dx < 0 else PAD * PAD  # flat-index steps
    sy = -PAD if dy < 0 else PAD
    sz = -1 if dz < 0 else 1
    l_ = abs(dx)
    m = abs(dy)
    n = abs(dz)
    # major axis a (length la, step sa), minor axes b and c
    if l_ >= m and l_ >= n:
        la, sa, lb, sb, lc, sc = l_, sx, m, sy, n, sz
    elif m >= l_ and m >= n:
        la, sa, lb, sb, lc, sc = m, sy, l_, sx, n, sz
    else:
        # PCL's third branch: err_1 drives y, err_2 drives x
        la, sa, lb, sb, lc, sc = n, sz, m, sy, l_, sx
    a2 = 2 * la
    b2 = 2 * lb
    c2 = 2 * lc
    e1 = b2 - la
    e2 = c2 - la
    idx = _flat(x1, y1, z1)
    inside = 0
    for _ in range(1, la):
        inside += lut[np.uintp(idx)]  # unsigned: no negative-index wrap-around test (idx is in the padded grid)
        s1 = e1 > 0  # branch-free steps (the branches are unpredictable)
        s2 = e2 > 0
        idx += sb * s1 + sc * s2
        e1 -= a2 * s1
        e2 -= a2 * s2
        e1 += b2
        e2 += c2
        idx += sa
    inside += lut[np.uintp(idx)]
    return inside, max(la, 1)


@njit(cache=True, inline="always")
def _line_class(inside, count):  # pragma: no cover - compiled
    """PCL's class of a line (0 in / 1 out / 2 mixed) and its in-ratio (mixed lines only)."""
    if inside >= count - 1:
        return 0, F0
    if inside <= 7:
        return 1, F0
    return 2, np.float32(inside) / np.float32(count)


@njit(cache=True, nogil=True)
def _round(x):  # pragma: no cover - compiled
    """pcl_round for float32 x >= 0 (half away from zero); -1 for NaN."""
    if x != x:
        return -1
    return math.floor(x + F05)


@njit(cache=True, nogil=True)
def _angle_bin(c):  # pragma: no cover - compiled
    return _round(np.float32(math.acos(abs(c))) / PIH * F63)


@njit(cache=True, nogil=True)
def _norm4(x, y, z):  # pragma: no cover - compiled
    return np.sqrt((x * x + z * z) + y * y)


@njit(cache=True, nogil=True)
def _dot4(ax, ay, az, bx, by, bz):  # pragma: no cover - compiled
    return (ax * bx + az * bz) + ay * by


@njit(cache=True, nogil=True)
def _dist(px, py, pz, qx, qy, qz):  # pragma: no cover - compiled
    dx = qx - px
    dy = qy - py
    dz = qz - pz
    return np.sqrt((dx * dx + dy * dy) + dz * dz)


# Per-triple results of esf_evaluate: integer columns, then float32 columns.
_I_OK, _I_TH1, _I_TH2, _I_TH3, _I_C1, _I_C2, _I_C3, _I_CLS, _I_N1, _I_N2, _I_N3 = range(11)
_F_D1, _F_D2, _F_D3, _F_R1, _F_R2, _F_R3, _F_AREA, _F_WT = range(8)


@njit(cache=True, parallel=True, nogil=True)
def esf_evaluate(local, vox, lut, triples, out_i, out_f):  # pragma: no cover - compiled
    """Evaluate every candidate index triple (M, 3) independently (both cores), storing the results per
    triple (``out_i[t, 0]`` = accepted; ``out_i`` any integer type, int16 is enough) so that :func:`esf_cutoff`
    finds the first ``n_samples`` accepted in draw order, as PCL takes them, and :func:`esf_histogram` bins them.

    A triple is accepted when its points differ, its triangle is not degenerate (Heron's
    s(s-a)(s-b)(s-c) > 0.001) and its three angle bins are valid. Per accepted triple: the angle bins, the
    classes (0 in, 1 out, 2 mixed), in-ratios and voxel counts of the lines 1-2, 1-3, 2-3, the side lengths,
    the square-rooted area and the triangle's in-ratio weight.
    """
    m = triples.shape[0]
    for t in prange(m):
        out_i[t, _I_OK] = 0
        i1 = triples[t, 0]
        i2 = triples[t, 1]
        i3 = triples[t, 2]
        if i1 == i2 or i1 == i3 or i2 == i3:
            continue
        ok, th1, th2, th3, heron = _triangle_angle_bins(local, i1, i2, i3)
        if not ok:
            continue
        in1, n1 = _lci(lut, vox[i1, 0], vox[i1, 1], vox[i1, 2], vox[i2, 0], vox[i2, 1], vox[i2, 2])
        in2, n2 = _lci(lut, vox[i1, 0], vox[i1, 1], vox[i1, 2], vox[i3, 0], vox[i3, 1], vox[i3, 2])
        in3, n3 = _lci(lut, vox[i2, 0], vox[i2, 1], vox[i2, 2], vox[i3, 0], vox[i3, 1], vox[i3, 2])
        c1, r1 = _line_class(in1, n1)
        c2, r2 = _line_class(in2, n2)
        c3, r3 = _line_class(in3, n3)
        cls, wt = _triangle_class(in1 + in2 + in3, n1 + n2 + n3)
        out_i[t, _I_OK] = 1
        out_i[t, _I_TH1] = th1
        out_i[t, _I_TH2] = th2
        out_i[t, _I_TH3] = th3
        out_i[t, _I_C1] = c1
        out_i[t, _I_C2] = c2
        out_i[t, _I_C3] = c3
        out_i[t, _I_CLS] = cls
        out_i[t, _I_N1] = n1
        out_i[t, _I_N2] = n2
        out_i[t, _I_N3] = n3
        _store_triangle_floats(out_f, t, local, i1, i2, i3, r1, r2, r3, heron, wt)


@njit(cache=True, inline="always")
def _triangle_angle_bins(local, i1, i2, i3):  # pragma: no cover - compiled
    """(ok, th1, th2, th3, heron) of the triangle of points i1, i2, i3 of ``local``: ``ok`` False (the rest
    zero) when it is degenerate (Heron's s(s-a)(s-b)(s-c) <= 0.001) or an angle bin is not in [0, BINS)."""
    x1 = local[i1, 0]
    y1 = local[i1, 1]
    z1 = local[i1, 2]
    v21x = local[i2, 0] - x1
    v21y = local[i2, 1] - y1
    v21z = local[i2, 2] - z1
    v31x = local[i3, 0] - x1
    v31y = local[i3, 1] - y1
    v31z = local[i3, 2] - z1
    v23x = local[i2, 0] - local[i3, 0]
    v23y = local[i2, 1] - local[i3, 1]
    v23z = local[i2, 2] - local[i3, 2]
    a = _norm4(v21x, v21y, v21z)
    b = _norm4(v31x, v31y, v31z)
    c = _norm4(v23x, v23y, v23z)
    s = (a + b + c) * F05
    heron = s * (s - a) * (s - b) * (s - c)
    if heron <= F_AREA:
        return False, 0, 0, 0, F0
    v21x /= a
    v21y /= a
    v21z /= a
    v31x /= b
    v31y /= b
    v31z /= b
    v23x /= c
    v23y /= c
    v23z /= c
    th1 = _angle_bin(_dot4(v21x, v21y, v21z, v31x, v31y, v31z))
    th2 = _angle_bin(_dot4(v23x, v23y, v23z, v31x, v31y, v31z))
    th3 = _angle_bin(_dot4(v23x, v23y, v23z, v21x, v21y, v21z))
    if th1 < 0 or th1 >= BINS or th2 < 0 or th2 >= BINS or th3 < 0 or th3 >= BINS:
        return False, 0, 0, 0, F0
    return True, th1, th2, th3, heron


@njit(cache=True, inline="always")
def _triangle_class(vs, pc):  # pragma: no cover - compiled
    """PCL's class of a triangle (0 in / 1 out / 2 mixed) and its in-ratio weight from the occupied (``vs``) and
    visited (``pc``) voxels of its three lines."""
    if vs <= 21:
        return 1, F0
    if pc - vs < 4:
        return 0, F1
    return 2, np.float32(vs) / np.float32(pc)


@njit(cache=True, inline="always")
def _store_triangle_floats(out_f, t, local, i1, i2, i3, r1, r2, r3, heron, wt):  # pragma: no cover - compiled
    """Row ``t`` of :func:`esf_evaluate`'s float32 results: side lengths, line in-ratios, square-rooted area and
    the triangle's in-ratio weight."""
    out_f[t, _F_D1] = _dist(local[i1, 0], local[i1, 1], local[i1, 2], local[i2, 0], local[i2, 1], local[i2, 2])
    out_f[t, _F_D2] = _dist(local[i1, 0], local[i1, 1], local[i1, 2], local[i3, 0], local[i3, 1], local[i3, 2])
    out_f[t, _F_D3] = _dist(local[i2, 0], local[i2, 1], local[i2, 2], local[i3, 0], local[i3, 1], local[i3, 2])
    out_f[t, _F_R1] = r1
    out_f[t, _F_R2] = r2
    out_f[t, _F_R3] = r3
    out_f[t, _F_AREA] = np.sqrt(np.sqrt(heron))
    out_f[t, _F_WT] = wt


@njit(cache=True, nogil=True)
def esf_cutoff(out_i, lo, hi, n_needed):  # pragma: no cover - compiled
    """Scan the evaluated triples lo..hi-1 in draw order: (accepted, end) where ``accepted`` counts the accepted
    ones up to ``n_needed`` and ``end`` is the row after the last one counted (``hi`` if fewer)."""
    k = 0
    t = lo
    while t < hi and k < n_needed:
        k += out_i[t, _I_OK]
        t += 1
    return k, t


@njit(cache=True, nogil=True)
def esf_histogram(out_i, out_f, end):  # pragma: no cover - compiled
    """The 640-bin float32 ESF of the accepted triples among rows 0..end-1 of :func:`esf_evaluate`'s output
    (PCL's block order, weights and sum-to-1).

    PCL accumulates in draw order, in float32; here every histogram is an integer count (A3: the sum of the
    visited-voxel counts that PCL adds, divided by 32 at the end). Both are exact, hence equal: every float32
    partial sum of PCL is a multiple of 1/32 below 2^19 (at most 20000 samples x 3 angles x 65/32 per bin)
    or an integer below 2^24, all of which float32 represents exactly. (Serial: ~0.4 ms, too little for a
    parallel region to pay on a busy 2-core machine.)
    """
    maxd2 = F0
    maxd3 = F0
    for t in range(end):
        if out_i[t, _I_OK]:
            maxd2 = max(maxd2, out_f[t, _F_D1], out_f[t, _F_D2], out_f[t, _F_D3])
            maxd3 = max(maxd3, out_f[t, _F_AREA])
    # A3 sums (3 x 64: in, out, mix), D3 (3 x 64), D2 (3 x 64), mixed-line ratios (64): the output's order
    c = np.zeros(10 * BINS, dtype=np.int64)
    for t in range(end):
        if out_i[t, _I_OK] == 0:
            continue
        cls = out_i[t, _I_CLS]
        c[cls * BINS + out_i[t, _I_TH1]] += out_i[t, _I_N3]
        c[cls * BINS + out_i[t, _I_TH2]] += out_i[t, _I_N1]
        c[cls * BINS + out_i[t, _I_TH3]] += out_i[t, _I_N2]
        for j in range(3):
            line_cls = out_i[t, _I_C1 + j]
            if line_cls == 2:
                c[9 * BINS + _round(out_f[t, _F_R1 + j] * F63)] += 1
            # d > 0 and finite (accepted triangle): pcl_round without its NaN case
            c[(6 + line_cls) * BINS + math.floor(out_f[t, _F_D1 + j] / maxd2 * F63 + F05)] += 1
        idx = _round(out_f[t, _F_AREA] / maxd3 * F63)
        if 0 <= idx < BINS:
            w = out_f[t, _F_WT]
            d3_cls = 0 if w >= 0.999 else (1 if w <= 0.001 else 2)
            c[(3 + d3_cls) * BINS + idx] += 1
    hist = np.empty(10 * BINS, dtype=np.float32)
    for b in range(10 * BINS):
        hist[b] = np.float32(c[b]) / F32 if b < 3 * BINS else np.float32(c[b])
    for b in range(BINS):  # PCL halves D2-in and the ratio block before weighting
        hist[6 * BINS + b] = hist[6 * BINS + b] * F05
        hist[9 * BINS + b] = hist[9 * BINS + b] * F05
    for b in range(10 * BINS):
        hist[b] = hist[b] * WEIGHTS[b // BINS]
    total = F0
    for b in range(10 * BINS):
        total += hist[b]
    for b in range(10 * BINS):
        hist[b] = hist[b] / total
    return hist
