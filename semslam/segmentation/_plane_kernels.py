"""Numba kernels of RMSAC plane fitting. Private: call :func:`semslam.segmentation.fit_plane_rmsac`,
which validates its input. Every function takes C-contiguous float64 arrays.

Random numbers come from a SplitMix64 generator whose state lives in a 1-element uint64 array, seeded
by the caller from a numpy Generator: runs are reproducible and independent of numba's global RNG.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)


@njit(cache=True, nogil=True)
def _splitmix64(state):
    """Next 64-bit value of SplitMix64 (Steele et al. 2014); advances ``state[0]``."""
    z = state[0] + _GOLDEN
    state[0] = z
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


@njit(cache=True, nogil=True)
def _randint(state, n):
    """Uniform integer in [0, n) (modulo bias < n / 2**64, negligible)."""
    return np.int64(_splitmix64(state) % np.uint64(n))


@njit(cache=True, nogil=True)
def rmsac_plane(
    points, threshold, log_one_minus_p, max_iterations, n_pretest, seed, max_degenerate
):
    """Randomized MSAC for a plane.

    Cost of a hypothesis ``(n, d)`` (unit normal): ``sum_i min(|n.p_i + d|, T)``, lowest wins. Before
    scoring, a hypothesis must pass the T(d,d) pre-test: ``n_pretest`` random points (with
    replacement) all within T; the first hypothesis is always scored. The iteration count adapts as
    ``k = log(1-p) / log(1 - w**3)`` with w the best inlier fraction (inlier: distance < T). Every
    non-degenerate hypothesis counts as an iteration, pre-test failure or not, and
    ``max_iterations`` is always honoured. Degenerate samples (repeated or collinear points) are
    redrawn, at most ``max_degenerate`` times in total.

    Parameters
    ----------
    points : (N, 3) float64
    threshold : float, metres
    log_one_minus_p : float, log(1 - confidence)
    max_iterations, n_pretest, max_degenerate : int
    seed : uint64 array of shape (1,), the SplitMix64 state (advanced in place)

    Returns
    -------
    coefficients : (4,) float64, unit normal, zeros when no hypothesis was found
    n_iterations, n_scored, n_degenerate, n_inliers : int
    """
    n = points.shape[0]
    best = np.zeros(4)
    best_penalty = np.inf
    best_inliers = 0
    k = 1.0
    it = 0
    n_scored = 0
    n_degenerate = 0
    eps = np.finfo(np.float64).eps
    while it < k and it < max_iterations:
        degenerate, a, b, c, d = _sample_plane(points, seed, n)
        if degenerate:
            n_degenerate += 1
            if n_degenerate > max_degenerate:
                break
            continue
        if n_scored > 0 and n_pretest > 0:
            if not _passes_pretest(points, a, b, c, d, threshold, n_pretest, seed, n):
                it += 1
                continue
        penalty, count, complete = _msac_penalty(points, a, b, c, d, threshold, best_penalty)
        n_scored += 1
        it += 1
        if complete and penalty < best_penalty:
            best_penalty = penalty
            best_inliers = count
            best[0] = a
            best[1] = b
            best[2] = c
            best[3] = d
            w = count / n
            p_no_outliers = 1.0 - w * w * w
            p_no_outliers = min(max(p_no_outliers, eps), 1.0 - eps)
            k = log_one_minus_p / np.log(p_no_outliers)
    return best, it, n_scored, n_degenerate, best_inliers


@njit(cache=True, inline="always")
def _sample_plane(points, seed, n):
    """Plane ``(a, b, c, d)`` (unit normal) through three random points of :func:`rmsac_plane`, drawn in
    order i0, i1, i2: ``(degenerate, a, b, c, d)``, ``degenerate`` True (and the plane zero) when the
    points are repeated or collinear (sin(angle) < 1e-6)."""
    i0 = _randint(seed, n)
    i1 = _randint(seed, n)
    i2 = _randint(seed, n)
    ux = points[i1, 0] - points[i0, 0]
    uy = points[i1, 1] - points[i0, 1]
    uz = points[i1, 2] - points[i0, 2]
    vx = points[i2, 0] - points[i0, 0]
    vy = points[i2, 1] - points[i0, 1]
    vz = points[i2, 2] - points[i0, 2]
    a = uy * vz - uz * vy
    b = uz * vx - ux * vz
    c = ux * vy - uy * vx
    cross2 = a * a + b * b + c * c
    # sin(angle) < 1e-6, or a repeated point: no well-defined plane
    if (
        cross2 <= 1e-12 * (ux * ux + uy * uy + uz * uz) * (vx * vx + vy * vy + vz * vz)
        or cross2 == 0.0
    ):
        return True, 0.0, 0.0, 0.0, 0.0
    norm = np.sqrt(cross2)
    a /= norm
    b /= norm
    c /= norm
    d = -(a * points[i0, 0] + b * points[i0, 1] + c * points[i0, 2])
    return False, a, b, c, d


@njit(cache=True, inline="always")
def _passes_pretest(points, a, b, c, d, threshold, n_pretest, seed, n):
    """T(d,d) pre-test of :func:`rmsac_plane`: ``n_pretest`` random points (with replacement) all
    within ``threshold`` of the plane; stops drawing at the first one beyond."""
    for _ in range(n_pretest):
        j = _randint(seed, n)
        if abs(a * points[j, 0] + b * points[j, 1] + c * points[j, 2] + d) > threshold:
            return False
    return True


@njit(cache=True, inline="always")
def _msac_penalty(points, a, b, c, d, threshold, best_penalty):
    """MSAC cost ``sum_i min(|n.p_i + d|, T)`` of a plane and its inlier count (distance < T), in point
    order: ``(penalty, count, complete)``, ``complete`` False when scoring stopped early because the
    cost reached ``best_penalty`` (the plane cannot win any more: exact)."""
    n = points.shape[0]
    penalty = 0.0
    count = 0
    for i in range(n):
        dist = abs(a * points[i, 0] + b * points[i, 1] + c * points[i, 2] + d)
        if dist < threshold:
            penalty += dist
            count += 1
        else:
            penalty += threshold
        if penalty >= best_penalty:  # cannot win any more: stop scoring (exact)
            return penalty, count, False
    return penalty, count, True


@njit(cache=True, nogil=True)
def plane_distances(points, coefficients):
    """Absolute distances ``|a x + b y + c z + d|`` of (N, 3) points to a unit-normal plane, (N,)."""
    n = points.shape[0]
    out = np.empty(n)
    a, b, c, d = coefficients[0], coefficients[1], coefficients[2], coefficients[3]
    for i in range(n):
        out[i] = abs(a * points[i, 0] + b * points[i, 1] + c * points[i, 2] + d)
    return out


@njit(cache=True, nogil=True)
def mean_and_covariance(points, indices):
    """Centroid (3,) and covariance (3, 3) (divided by M) of ``points[indices]``; two passes for
    accuracy far from the origin. ``indices`` (M,) int64, M >= 1. Sums accumulate in scalars
    (registers), in index order."""
    m = indices.shape[0]
    sx = 0.0
    sy = 0.0
    sz = 0.0
    for r in range(m):
        i = indices[r]
        sx += points[i, 0]
        sy += points[i, 1]
        sz += points[i, 2]
    return _covariance_about(points, indices, m, sx / m, sy / m, sz / m)


@njit(cache=True, nogil=True)
def _covariance_about(points, indices, m, mx, my, mz):
    """Mean (3,) and covariance (3, 3) / m about (mx, my, mz) of the points at ``indices``, or of
    the first ``m`` points when ``indices`` is empty."""
    cxx = 0.0
    cxy = 0.0
    cxz = 0.0
    cyy = 0.0
    cyz = 0.0
    czz = 0.0
    use_all = indices.shape[0] == 0
    for r in range(m):
        i = r if use_all else indices[r]
        dx = points[i, 0] - mx
        dy = points[i, 1] - my
        dz = points[i, 2] - mz
        cxx += dx * dx
        cxy += dx * dy
        cxz += dx * dz
        cyy += dy * dy
        cyz += dy * dz
        czz += dz * dz
    mean = np.empty(3)
    mean[0] = mx
    mean[1] = my
    mean[2] = mz
    cov = np.empty((3, 3))
    cov[0, 0] = cxx / m
    cov[0, 1] = cxy / m
    cov[0, 2] = cxz / m
    cov[1, 1] = cyy / m
    cov[1, 2] = cyz / m
    cov[2, 2] = czz / m
    cov[1, 0] = cov[0, 1]
    cov[2, 0] = cov[0, 2]
    cov[2, 1] = cov[1, 2]
    return mean, cov


@njit(cache=True, nogil=True)
def mean_and_covariance_all(points):
    """:func:`mean_and_covariance` of all the (N, 3) points (same arithmetic, no index array)."""
    m = points.shape[0]
    sx = 0.0
    sy = 0.0
    sz = 0.0
    for i in range(m):
        sx += points[i, 0]
        sy += points[i, 1]
        sz += points[i, 2]
    return _covariance_about(points, np.empty(0, np.int64), m, sx / m, sy / m, sz / m)


@njit(cache=True, nogil=True)
def inliers_and_sum(points, coefficients, threshold):
    """Sorted indices (int64) of the points at distance strictly below ``threshold`` of a
    unit-normal plane (:func:`plane_distances` below the threshold), and the sum (3,) of their
    coordinates accumulated in index order (the first pass of :func:`mean_and_covariance`, bit
    for bit). One pass: the indices are a view of an (N,) buffer; no distance array is stored."""
    n = points.shape[0]
    a, b, c, d = coefficients[0], coefficients[1], coefficients[2], coefficients[3]
    idx = np.empty(n, np.int64)
    sx = 0.0
    sy = 0.0
    sz = 0.0
    j = 0
    for i in range(n):
        x = points[i, 0]
        y = points[i, 1]
        z = points[i, 2]
        if abs(a * x + b * y + c * z + d) < threshold:
            idx[j] = i
            j += 1
            sx += x
            sy += y
            sz += z
    sums = np.empty(3)
    sums[0] = sx
    sums[1] = sy
    sums[2] = sz
    return idx[:j], sums


@njit(cache=True, nogil=True)
def inliers_and_squares(points, coefficients, threshold):
    """Sorted inlier indices (int64) as :func:`inliers_and_sum`, and their squared distances
    (equal to ``plane_distances(points, coefficients)[inliers] ** 2``)."""
    n = points.shape[0]
    a, b, c, d = coefficients[0], coefficients[1], coefficients[2], coefficients[3]
    idx = np.empty(n, np.int64)
    sq = np.empty(n)
    j = 0
    for i in range(n):
        v = abs(a * points[i, 0] + b * points[i, 1] + c * points[i, 2] + d)
        if v < threshold:
            idx[j] = i
            sq[j] = v * v
            j += 1
    return idx[:j], sq[:j]


@njit(cache=True, nogil=True)
def covariance_from_sum(points, indices, sums):
    """:func:`mean_and_covariance` of ``points[indices]`` (M >= 1) given the coordinate sums (3,)
    of :func:`inliers_and_sum` (same result, one pass fewer)."""
    m = indices.shape[0]
    return _covariance_about(points, indices, m, sums[0] / m, sums[1] / m, sums[2] / m)


@njit(cache=True, nogil=True)
def complement(remaining, removed, n):
    """``remaining`` (R,) without the entries at the sorted, unique positions ``removed`` (K,);
    an empty ``remaining`` stands for ``arange(n)``."""
    all_points = remaining.shape[0] == 0
    r = n if all_points else remaining.shape[0]
    out = np.empty(r - removed.shape[0], np.int64)
    j = 0
    o = 0
    for i in range(r):
        if j < removed.shape[0] and removed[j] == i:
            j += 1
        else:
            out[o] = i if all_points else remaining[i]
            o += 1
    return out
