"""Numba kernels of the plausibility checks (:mod:`semslam.recognition.plausibility`): the angular extent of a
scan seen from its viewpoint, a cluster's mean and scatter, and its extent along its principal axes. Private."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def scan_angular_extent(points, viewpoint):
    """Same result as :func:`semslam.recognition.plausibility.scan_angular_extent` (4,) in one pass.

    The sweep angle ``atan2(x, z)`` increases with ``x / z`` when ``z > 0`` and the in-line angle
    ``asin(y / r)`` with ``y / r``: the extremes are found on those ratios and the trigonometric functions
    are evaluated on the extreme points only (on every point when some ``z <= 0``).
    """
    n = points.shape[0]
    out = np.array([np.inf, -np.inf, np.inf, -np.inf])
    if n == 0:
        return out
    all_front = True
    lo_s, hi_s, lo_i, hi_i = np.inf, -np.inf, np.inf, -np.inf
    i_lo_s = i_hi_s = 0
    for k in range(n):
        x = points[k, 0] - viewpoint[0]
        y = points[k, 1] - viewpoint[1]
        z = points[k, 2] - viewpoint[2]
        r = np.sqrt(x * x + y * y + z * z)
        b = min(max(y / max(r, 1e-12), -1.0), 1.0)
        lo_i = min(lo_i, b)
        hi_i = max(hi_i, b)
        if z > 0.0:
            s = x / z
            if s < lo_s:
                lo_s, i_lo_s = s, k
            if s > hi_s:
                hi_s, i_hi_s = s, k
        else:
            all_front = False
    out[2], out[3] = np.arcsin(lo_i), np.arcsin(hi_i)
    if all_front:
        out[0] = np.arctan2(points[i_lo_s, 0] - viewpoint[0], points[i_lo_s, 2] - viewpoint[2])
        out[1] = np.arctan2(points[i_hi_s, 0] - viewpoint[0], points[i_hi_s, 2] - viewpoint[2])
    else:
        for k in range(n):
            a = np.arctan2(points[k, 0] - viewpoint[0], points[k, 2] - viewpoint[2])
            out[0] = min(out[0], a)
            out[1] = max(out[1], a)
    return out


@njit(cache=True, nogil=True)
def mean_and_scatter(points):
    """Mean (3,) of the points (N, 3), N >= 1, and their scatter matrix sum (p - mean)(p - mean)^T (3, 3)."""
    n = points.shape[0]
    mean = np.zeros(3)
    for k in range(n):
        for j in range(3):
            mean[j] += points[k, j]
    for j in range(3):
        mean[j] /= n
    s = np.zeros((3, 3))
    for k in range(n):
        x = points[k, 0] - mean[0]
        y = points[k, 1] - mean[1]
        z = points[k, 2] - mean[2]
        s[0, 0] += x * x
        s[0, 1] += x * y
        s[0, 2] += x * z
        s[1, 1] += y * y
        s[1, 2] += y * z
        s[2, 2] += z * z
    s[1, 0] = s[0, 1]
    s[2, 0] = s[0, 2]
    s[2, 1] = s[1, 2]
    return mean, s


@njit(cache=True, nogil=True)
def projected_extent(points, mean, axes):
    """Max minus min (3,) of the centred points (N, 3), N >= 1, projected on the columns of ``axes`` (3, 3)."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for k in range(points.shape[0]):
        x = points[k, 0] - mean[0]
        y = points[k, 1] - mean[1]
        z = points[k, 2] - mean[2]
        for j in range(3):
            p = x * axes[0, j] + y * axes[1, j] + z * axes[2, j]
            lo[j] = min(lo[j], p)
            hi[j] = max(hi[j], p)
    return hi - lo
