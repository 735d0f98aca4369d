"""Kernel of :mod:`semslam.pipeline.deskew`. Don't call directly: use :func:`~semslam.pipeline.deskew.deskew_points`."""

from __future__ import annotations

import numpy as np
from numba import njit


#: points whose stamps are this close (s) to the stamp a transform was computed for share it: at 1 m/s and 1 rad/s,
#: 4 m away, 0.2 mm (a per-point-stamped 100k scan: 17 -> ~2 ms)
STAMP_SHARE_S = 5e-5


@njit(cache=True, nogil=True)
def _transform_at(t: float, grid: np.ndarray, R: np.ndarray, p: np.ndarray, R_vs: np.ndarray, t_vs: np.ndarray,
                  R_ref: np.ndarray, p_ref: np.ndarray, j: int, M: np.ndarray, c: np.ndarray,
                  B: np.ndarray, A: np.ndarray, d: np.ndarray) -> int:  # pragma: no cover
    """``M``, ``c`` of ``x_ref = M x + c`` for a point ``x`` of the sensor frame at ``t`` (the motion interpolated
    linearly between its samples, clamped at its ends); returns the interval used (the next search starts there).
    ``B``, ``A`` (3, 3) and ``d`` (3,) are scratch space."""
    m = grid.shape[0]
    if t <= grid[0]:
        j, w = 0, 0.0
    elif t >= grid[m - 1]:
        j, w = m - 2, 1.0
    else:
        if t < grid[j] or t > grid[j + 1]:
            lo, hi = 0, m - 1
            while hi - lo > 1:
                mid = (lo + hi) // 2
                if grid[mid] <= t:
                    lo = mid
                else:
                    hi = mid
            j = lo
        w = (t - grid[j]) / (grid[j + 1] - grid[j])
    # x_ref = R_vs^T (R_ref^T (Rv (R_vs x + t_vs) + pv - p_ref) - t_vs), in scalars (no temporary arrays)
    # B = R_ref^T Rv, d = R_ref^T (pv - p_ref), A = R_vs^T B
    for a in range(3):
        for b in range(3):
            acc = 0.0
            for k in range(3):
                acc += R_ref[k, a] * ((1.0 - w) * R[j, k, b] + w * R[j + 1, k, b])
            B[a, b] = acc
        acc = 0.0
        for k in range(3):
            acc += R_ref[k, a] * ((1.0 - w) * p[j, k] + w * p[j + 1, k] - p_ref[k])
        d[a] = acc
    for a in range(3):
        for b in range(3):
            A[a, b] = R_vs[0, a] * B[0, b] + R_vs[1, a] * B[1, b] + R_vs[2, a] * B[2, b]
    for a in range(3):
        for b in range(3):
            M[a, b] = A[a, 0] * R_vs[0, b] + A[a, 1] * R_vs[1, b] + A[a, 2] * R_vs[2, b]
        c[a] = A[a, 0] * t_vs[0] + A[a, 1] * t_vs[1] + A[a, 2] * t_vs[2] + \
            R_vs[0, a] * (d[0] - t_vs[0]) + R_vs[1, a] * (d[1] - t_vs[1]) + R_vs[2, a] * (d[2] - t_vs[2])
    return j


@njit(cache=True, nogil=True)
def deskew_kernel(points: np.ndarray, stamps: np.ndarray, grid: np.ndarray, R: np.ndarray, p: np.ndarray,
                  R_vs: np.ndarray, t_vs: np.ndarray, R_ref: np.ndarray, p_ref: np.ndarray,
                  out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Each point (scanner frame at its own stamp) into the scanner frame at the reference pose: the motion's
    rotation and position interpolated linearly between its samples (10 ms apart: rotation steps of a fraction of a
    degree), clamped at its ends; non-finite stamps leave their points as they are. The transform is computed once
    per run of stamps within ``STAMP_SHARE_S`` of its first (a line scanner's points share their line's stamp).
    Written to ``out`` (N, 3), which the caller allocates (an array numba returns has a base: PointCloud copies it).
    """
    n = points.shape[0]
    M, B, A = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    c, d = np.empty(3), np.empty(3)
    j = 0
    last = np.nan
    for i in range(n):
        t = stamps[i]
        if not np.isfinite(t):  # left as it is
            out[i, 0], out[i, 1], out[i, 2] = points[i, 0], points[i, 1], points[i, 2]
            continue
        if not abs(t - last) <= STAMP_SHARE_S:
            j = _transform_at(t, grid, R, p, R_vs, t_vs, R_ref, p_ref, j, M, c, B, A, d)
            last = t
        x0, x1, x2 = points[i, 0], points[i, 1], points[i, 2]
        for a in range(3):
            out[i, a] = M[a, 0] * x0 + M[a, 1] * x1 + M[a, 2] * x2 + c[a]
