"""Numba kernel of PCL's VFH angle histograms. Don't call directly; use
:func:`semslam.descriptors.compute_vfh`."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._pair_kernels import pair_features

NB = 45
#: PCL's d_pi_ = 1 / (2 pi) is a float.
D_PI = float(np.float32(1.0) / (np.float32(2.0) * np.float32(math.pi)))


@njit(cache=True)
def _clamp_floor(x, nbins):  # pragma: no cover - compiled
    if x != x:
        return 0
    b = math.floor(x)
    if b < 0:
        return 0
    if b >= nbins:
        return nbins - 1
    return b


@njit(cache=True, nogil=True)
def vfh_angles(centroid, mean_normal, points, normals, legacy_f23, incr, size_mode, dist_norm, out):  # pragma: no cover
    """Fill ``out`` (180,) = f1 | f2 | f3 | f4 with the pair features of (centroid, mean normal)
    against every (point, normal), each adding ``incr``; pairs PCL rejects (point at the centroid,
    normal parallel to the offset) are skipped. f2/f3 are binned as f1 (PCL >= 1.10.1) unless
    ``legacy_f23``. ``size_mode``: 0 no f4, 1 f4 = round(100 d), 2 f4 = floor(45 d / dist_norm).
    """
    for i in range(points.shape[0]):
        ok, f1, f2, f3, f4 = pair_features(centroid, mean_normal, points[i], normals[i])
        if not ok:
            continue
        out[_clamp_floor(NB * ((f1 + math.pi) * D_PI), NB)] += incr
        if legacy_f23:
            out[NB + _clamp_floor(NB * ((f2 + 1.0) * 0.5), NB)] += incr
            out[2 * NB + _clamp_floor(NB * ((f3 + 1.0) * 0.5), NB)] += incr
        else:
            out[NB + _clamp_floor(NB * ((f2 + math.pi) * D_PI), NB)] += incr
            out[2 * NB + _clamp_floor(NB * ((f3 + math.pi) * D_PI), NB)] += incr
        if size_mode == 1:
            b = math.floor(f4 * 100.0 + 0.5)
            out[3 * NB + min(max(b, 0), NB - 1)] += incr
        elif size_mode == 2:
            out[3 * NB + _clamp_floor(NB * (f4 / dist_norm), NB)] += incr
