"""Numba kernels of PCL's VFH in float32: the point-pair features as PCL computes them and the 308-bin histogram.
Don't call directly; use :func:`semslam.descriptors.compute_vfh`."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# ---------------------------------------------------------------------------------------------------------------
# float32 versions, as PCL computes them (its points, normals and features are floats). Eigen's Vector4f dot
# product and norm reduce with SSE as (x x' + z z') + (y y' + w w'); w w' is 0 here except where noted. ``math``
# functions of float32 arguments call the C library's float versions (acosf, atan2f, sqrtf) as PCL's std:: calls.
# ---------------------------------------------------------------------------------------------------------------

_F32_ZERO = np.float32(0.0)


@njit(cache=True, inline="always")
def _dot3_f32(ax, ay, az, bx, by, bz):  # pragma: no cover - compiled
    """Eigen ``Vector4f::dot`` with both w = 0: ``(ax bx + az bz) + ay by`` in float32."""
    return (ax * bx + az * bz) + ay * by


@njit(cache=True, inline="always")
def pair_features_f32(p1, n1, p2, n2):  # pragma: no cover - compiled
    """PCL ``computePairFeatures`` in float32, step for step: returns (ok, f1, f2, f3, f4), float32.

    Inputs are float32 arrays of 3. Same definition as :func:`~._pair_kernels.pair_features_sym`; the only
    differences are the precision (every product, sum, division, square root, ``acosf`` and ``atan2f`` rounded
    to float32 as in PCL) and Eigen's summation order, so a feature on a bin edge falls in the same bin as PCL's.
    """
    dx = p2[0] - p1[0]
    dy = p2[1] - p1[1]
    dz = p2[2] - p1[2]
    f4 = math.sqrt(_dot3_f32(dx, dy, dz, dx, dy, dz))
    if f4 == 0.0:
        return False, _F32_ZERO, _F32_ZERO, _F32_ZERO, _F32_ZERO
    ux, uy, uz = n1[0], n1[1], n1[2]
    mx, my, mz = n2[0], n2[1], n2[2]
    a1 = _dot3_f32(ux, uy, uz, dx, dy, dz) / f4
    a2 = _dot3_f32(mx, my, mz, dx, dy, dz) / f4
    if math.acos(abs(a1)) > math.acos(abs(a2)):
        ux, uy, uz = n2[0], n2[1], n2[2]
        mx, my, mz = n1[0], n1[1], n1[2]
        dx, dy, dz = -dx, -dy, -dz
        f3 = -a2
    else:
        f3 = a1
    vx = dy * uz - dz * uy
    vy = dz * ux - dx * uz
    vz = dx * uy - dy * ux
    vn = math.sqrt(_dot3_f32(vx, vy, vz, vx, vy, vz))
    if vn == 0.0:
        return False, _F32_ZERO, _F32_ZERO, _F32_ZERO, _F32_ZERO
    vx = vx / vn
    vy = vy / vn
    vz = vz / vn
    wx = uy * vz - uz * vy
    wy = uz * vx - ux * vz
    wz = ux * vy - uy * vx
    f2 = _dot3_f32(vx, vy, vz, mx, my, mz)
    f1 = math.atan2(_dot3_f32(wx, wy, wz, mx, my, mz), _dot3_f32(ux, uy, uz, mx, my, mz))
    return True, f1, f2, f3, f4


#: PCL's ``d_pi_ = 1 / (2 pi)`` is a float; its bin index is computed in double from the float feature.
_VFH_D_PI = float(np.float32(1.0) / (np.float32(2.0) * np.float32(math.pi)))
_VFH_NB = 45
_VFH_NB_VP = 128


@njit(cache=True, inline="always")
def _vfh_clamp_floor(x, nbins):  # pragma: no cover - compiled
    if x != x:
        return 0
    b = math.floor(x)
    if b < 0:
        return 0
    if b >= nbins:
        return nbins - 1
    return int(b)


@njit(cache=True, nogil=True)
def vfh_f32(points, normals, valid, viewpoint, legacy_f23, pcl_4d, normalize_bins, size_mode, out):  # pragma: no cover
    """PCL ``VFHEstimation::computeFeature`` in float32: fills ``out`` (308,) float32 and returns 0; returns 1
    when the distance normaliser is zero, 2 when the viewpoint direction is (the caller raises).

    ``points`` (N, 3), ``normals`` (N, 3), ``viewpoint`` (3,): float32; ``valid[i]``: normal i is finite (the
    others are left out of the mean normal and of both histograms, and n counts only the valid ones).
    Steps as PCL 1.13: centroid = float sum of every point / N (``compute3DCentroid``, w = 1); mean normal =
    float sum / n, not re-normalised; each valid point's :func:`pair_features_f32` against (centroid, mean
    normal) binned as ``floor(45 ((f + pi) d_pi))`` in double (f2/f3 as ``floor(45 (f + 1) / 2)`` when
    ``legacy_f23``), adding the float ``100 / (n - 1)`` (1 without ``normalize_bins``) in point order.
    ``size_mode``: 0 no f4, 1 ``floor(f4 * 100 + 0.5)`` in float (``pcl_round``), 2 ``floor(45 f4 / dmax)``
    in double, with dmax the float norm of (centroid - farthest point) as a 4-vector with w = 1 when
    ``pcl_4d`` (3-vector otherwise). Viewpoint: d = (viewpoint - centroid) normalised as the 4-vector
    (d, -1) when ``pcl_4d`` (3-vector otherwise); each valid normal adds the float ``100 / n`` at
    ``floor(128 (n . d + 1) / 2)`` (dot in float, the rest in double).
    """
    n_all = points.shape[0]
    centroid = _vfh_centroid_f32(points)
    mean_normal, n = _vfh_mean_normal_f32(normals, valid)
    fv = np.float32(n)
    one = np.float32(1.0)
    dist_norm = 1.0
    if size_mode == 2:
        dist_norm = _vfh_max_distance_f32(points, centroid, pcl_4d)
        if dist_norm == 0.0:
            return 1
    incr = np.float32(100.0) / np.float32(n - 1) if normalize_bins else one
    for i in range(n_all):
        if not valid[i]:
            continue
        ok, f1, f2, f3, f4 = pair_features_f32(centroid, mean_normal, points[i], normals[i])
        if not ok:
            continue
        out[_vfh_clamp_floor(_VFH_NB * ((float(f1) + math.pi) * _VFH_D_PI), _VFH_NB)] += incr
        if legacy_f23:
            out[_VFH_NB + _vfh_clamp_floor(_VFH_NB * ((float(f2) + 1.0) * 0.5), _VFH_NB)] += incr
            out[2 * _VFH_NB + _vfh_clamp_floor(_VFH_NB * ((float(f3) + 1.0) * 0.5), _VFH_NB)] += incr
        else:
            out[_VFH_NB + _vfh_clamp_floor(_VFH_NB * ((float(f2) + math.pi) * _VFH_D_PI), _VFH_NB)] += incr
            out[2 * _VFH_NB + _vfh_clamp_floor(_VFH_NB * ((float(f3) + math.pi) * _VFH_D_PI), _VFH_NB)] += incr
        if size_mode == 1:
            b = math.floor(f4 * np.float32(100.0) + np.float32(0.5))
            out[3 * _VFH_NB + min(max(int(b), 0), _VFH_NB - 1)] += incr
        elif size_mode == 2:
            out[3 * _VFH_NB + _vfh_clamp_floor(_VFH_NB * (float(f4) / dist_norm), _VFH_NB)] += incr
    incr_vp = np.float32(100.0) / fv if normalize_bins else one
    return _vfh_add_viewpoint(out, normals, valid, viewpoint, centroid, pcl_4d, incr_vp)


@njit(cache=True, nogil=True)
def _vfh_centroid_f32(points):  # pragma: no cover - compiled
    """PCL ``compute3DCentroid`` (w = 1) of (N, 3) float32 points: float sum in point order / N, (3,) float32."""
    n_all = points.shape[0]
    cx = _F32_ZERO
    cy = _F32_ZERO
    cz = _F32_ZERO
    for i in range(n_all):
        cx += points[i, 0]
        cy += points[i, 1]
        cz += points[i, 2]
    fn = np.float32(n_all)
    centroid = np.empty(3, np.float32)
    centroid[0] = cx / fn
    centroid[1] = cy / fn
    centroid[2] = cz / fn
    return centroid


@njit(cache=True, nogil=True)
def _vfh_mean_normal_f32(normals, valid):  # pragma: no cover - compiled
    """Float sum of the valid normals in point order / their count n, not re-normalised: ((3,) float32, n)."""
    mnx = _F32_ZERO
    mny = _F32_ZERO
    mnz = _F32_ZERO
    n = 0
    for i in range(normals.shape[0]):
        if valid[i]:
            mnx += normals[i, 0]
            mny += normals[i, 1]
            mnz += normals[i, 2]
            n += 1
    fv = np.float32(n)
    mean_normal = np.empty(3, np.float32)
    mean_normal[0] = mnx / fv
    mean_normal[1] = mny / fv
    mean_normal[2] = mnz / fv
    return mean_normal, n


@njit(cache=True, nogil=True)
def _vfh_max_distance_f32(points, centroid, pcl_4d):  # pragma: no cover - compiled
    """VFH's distance normaliser dmax (double from float32): pcl::getMaxDistance, the first point of largest
    Vector3f norm ((x^2 + y^2) + z^2) of (centroid - point), then the norm of (centroid - that point) as a
    4-vector whose w is 1 - 0 when ``pcl_4d`` (3-vector otherwise)."""
    one = np.float32(1.0)
    best = np.float32(-np.inf)
    best_i = 0
    for i in range(points.shape[0]):
        ex = centroid[0] - points[i, 0]
        ey = centroid[1] - points[i, 1]
        ez = centroid[2] - points[i, 2]
        d = math.sqrt((ex * ex + ey * ey) + ez * ez)
        if d > best:
            best = d
            best_i = i
    ex = centroid[0] - points[best_i, 0]
    ey = centroid[1] - points[best_i, 1]
    ez = centroid[2] - points[best_i, 2]
    if pcl_4d:
        return float(math.sqrt((ex * ex + ez * ez) + (ey * ey + one)))
    return float(math.sqrt(_dot3_f32(ex, ey, ez, ex, ey, ez)))


@njit(cache=True, nogil=True)
def _vfh_add_viewpoint(out, normals, valid, viewpoint, centroid, pcl_4d, incr_vp):  # pragma: no cover - compiled
    """The 128 viewpoint bins of :func:`vfh_f32`: 0, or 2 (nothing added) when the direction is zero."""
    one = np.float32(1.0)
    ex = viewpoint[0] - centroid[0]
    ey = viewpoint[1] - centroid[1]
    ez = viewpoint[2] - centroid[2]
    if pcl_4d:
        z = (ex * ex + ez * ez) + (ey * ey + one)  # the 4-vector (vp, 0) - (c, 1): w = -1
    else:
        z = _dot3_f32(ex, ey, ez, ex, ey, ez)
    if not z > 0.0:
        return 2
    s = math.sqrt(z)
    ex = ex / s
    ey = ey / s
    ez = ez / s
    base = 4 * _VFH_NB
    for i in range(normals.shape[0]):
        if not valid[i]:
            continue
        alpha = (float(_dot3_f32(normals[i, 0], normals[i, 1], normals[i, 2], ex, ey, ez)) + 1.0) * 0.5
        out[base + _vfh_clamp_floor(alpha * _VFH_NB_VP, _VFH_NB_VP)] += incr_vp
    return 0
