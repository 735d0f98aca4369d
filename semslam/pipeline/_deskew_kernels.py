"""Kernel of :mod:`semslam.pipeline.deskew`. Don't call directly: use :func:`~semslam.pipeline.deskew.deskew_points`."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def deskew_kernel(points: np.ndarray, stamps: np.ndarray, grid: np.ndarray, R: np.ndarray, p: np.ndarray,
                   R_vs: np.ndarray, t_vs: np.ndarray, R_ref: np.ndarray,
                   p_ref: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Each point (scanner frame at its own stamp) into the scanner frame at the reference pose: the motion's
    rotation and position interpolated linearly between its samples (10 ms apart: rotation steps of a fraction of a
    degree), clamped at its ends; non-finite stamps leave their points as they are."""
    n, m = points.shape[0], grid.shape[0]
    out = points.copy()
    Rv = np.empty((3, 3))
    pv = np.empty(3)
    x = np.empty(3)
    y = np.empty(3)
    j = 0
    for i in range(n):
        t = stamps[i]
        if not np.isfinite(t):
            continue
        if t <= grid[0]:
            j, w = 0, 0.0
        elif t >= grid[m - 1]:
            j, w = m - 2, 1.0
        else:
            if t < grid[j] or t > grid[j + 1]:  # stamps mostly ordered by line: search from the last interval
                lo, hi = 0, m - 1
                while hi - lo > 1:
                    mid = (lo + hi) // 2
                    if grid[mid] <= t:
                        lo = mid
                    else:
                        hi = mid
                j = lo
            w = (t - grid[j]) / (grid[j + 1] - grid[j])
        for a in range(3):
            pv[a] = (1.0 - w) * p[j, a] + w * p[j + 1, a]
            for b in range(3):
                Rv[a, b] = (1.0 - w) * R[j, a, b] + w * R[j + 1, a, b]
        for a in range(3):  # vehicle frame at the point's stamp
            x[a] = R_vs[a, 0] * points[i, 0] + R_vs[a, 1] * points[i, 1] + R_vs[a, 2] * points[i, 2] + t_vs[a]
        for a in range(3):  # world (relative)
            y[a] = Rv[a, 0] * x[0] + Rv[a, 1] * x[1] + Rv[a, 2] * x[2] + pv[a] - p_ref[a]
        for a in range(3):  # vehicle frame at the reference stamp
            x[a] = R_ref[0, a] * y[0] + R_ref[1, a] * y[1] + R_ref[2, a] * y[2] - t_vs[a]
        for a in range(3):  # scanner frame at the reference stamp
            out[i, a] = R_vs[0, a] * x[0] + R_vs[1, a] * x[1] + R_vs[2, a] * x[2]
    return out
