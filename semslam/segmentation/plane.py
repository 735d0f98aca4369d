"""Plane fitting by RMSAC (randomized M-estimator sample consensus) and dominant-plane removal.

RMSAC as in PCL's ``sample_consensus/impl/rmsac.hpp`` (the seed papers' choice), with three fixes:

* cost: MSAC's truncated loss ``sum_i min(d_i, T)`` with ``d_i = |n.p_i + d|`` (PCL's, linear in
  the distance, not Torr's quadratic: we keep PCL's so that the selected models match);
* the T(d,d) pre-test draws ``n_pretest`` points (default 1, as PCL 1.15; PCL <= 1.14 drew 10 % of
  the cloud, so that only the first hypothesis was ever scored) and ``max_iterations`` is ALWAYS
  honoured (PCL 1.13 skips the cap after a failed pre-test and ran > 10 min on the mug scene);
* a hypothesis whose partial cost already exceeds the best one stops being scored (exact, faster).

The winner is refined as PCL's ``optimizeModelCoefficients`` does (least squares = PCA of the
inliers), then the inliers are re-selected within T. Inliers are the points with distance < T.
Sign convention: the normal is oriented so that the origin of the points' frame (the scanner, for
scanner-frame clouds) is on its positive side, i.e. ``d >= 0``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .._validation import as_float_array, as_rng, check_int, check_positive
from ..errors import InputError, SegmentationError
from . import _plane_kernels as _k

__all__ = ["PlaneModel", "PlaneRemovalResult", "fit_plane_rmsac", "remove_dominant_planes"]


@dataclass(frozen=True, eq=False)
class PlaneModel:
    """A plane ``a x + b y + c z + d = 0`` found by sample consensus.

    Attributes
    ----------
    coefficients : ndarray of shape (4,)
        ``(a, b, c, d)`` with ``(a, b, c)`` a unit normal and ``d`` in metres, ``d >= 0`` (the frame
        origin is on the normal's side).
    inlier_indices : ndarray of shape (M,), int64, or None
        Sorted indices (into the cloud that was fitted) of the points closer than the threshold;
        None when not kept (see :func:`remove_dominant_planes`).
    n_inliers : int
        Number of inliers M.
    n_points : int
        Number of points the plane was fitted on.
    rmse_m : float
        Root-mean-square distance of the inliers to the plane, metres.
    distance_threshold_m : float
        Inlier threshold T, metres.
    n_iterations : int
        Hypotheses drawn (pre-test failures included, degenerate samples excluded).
    n_scored : int
        Hypotheses scored on the whole cloud (passed the pre-test).
    n_degenerate : int
        Samples rejected as degenerate (repeated or collinear points).
    """

    coefficients: np.ndarray
    inlier_indices: np.ndarray | None
    n_inliers: int
    n_points: int
    rmse_m: float
    distance_threshold_m: float
    n_iterations: int
    n_scored: int
    n_degenerate: int

    @property
    def normal_xyz(self) -> np.ndarray:
        """Unit normal (3,)."""
        return self.coefficients[:3]

    @property
    def offset_m(self) -> float:
        """``d``: distance from the frame origin to the plane, metres."""
        return float(self.coefficients[3])

    @property
    def inlier_fraction(self) -> float:
        return self.n_inliers / self.n_points if self.n_points else 0.0

    def distances_m(self, points_xyz_m: np.ndarray) -> np.ndarray:
        """Absolute point-to-plane distances (N,), metres, of (N, 3) points."""
        pts = as_float_array(
            "points_xyz_m", points_xyz_m, (None, 3), caller="PlaneModel.distances_m"
        )
        return _k.plane_distances(pts, self.coefficients)

    def project(self, points_xyz_m: np.ndarray) -> np.ndarray:
        """Orthogonal projection (N, 3) of (N, 3) points onto the plane, metres."""
        pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller="PlaneModel.project")
        n = self.coefficients[:3]
        return pts - np.outer(pts @ n + self.coefficients[3], n)

    def to_dict(self) -> dict:
        return {
            "coefficients": [float(v) for v in self.coefficients],
            "n_inliers": self.n_inliers,
            "n_points": self.n_points,
            "rmse_m": self.rmse_m,
            "distance_threshold_m": self.distance_threshold_m,
            "n_iterations": self.n_iterations,
            "n_scored": self.n_scored,
            "n_degenerate": self.n_degenerate,
        }


def _check_spread(pts: np.ndarray, caller: str, name: str = "points_xyz_m") -> None:
    """Raise SegmentationError when fewer than 3 points or all points (nearly) collinear."""
    if len(pts) < 3:
        raise SegmentationError(
            f"The {name!r} argument of {caller} must hold at least 3 points to fit a plane. Got {len(pts)} instead."
        )
    eig = _spread_eigenvalues(pts)
    if (not eig[2] > 0 or eig[1] <= 1e-12 * eig[2]) and len(pts) > 3:
        # A few far outliers (one point at 1e9 m) dwarf the spread of all the others: judge the core instead.
        lo, hi = np.percentile(pts, [1.0, 99.0], axis=0)
        core = pts[((pts >= lo - (hi - lo)) & (pts <= hi + (hi - lo))).all(axis=1)]
        if len(core) >= 3:
            eig_core = _spread_eigenvalues(core)
            if eig_core[2] > 0 and eig_core[1] > 1e-12 * eig_core[2]:
                eig = eig_core
    if not eig[2] > 0 or eig[1] <= 1e-12 * eig[2]:
        what = "identical" if not eig[2] > 0 else "collinear"
        raise SegmentationError(
            f"The {name!r} argument of {caller} must not be degenerate: all {len(pts)} points are {what}, "
            "so no plane is defined."
        )


def _spread_eigenvalues(pts: np.ndarray) -> np.ndarray:
    _, cov = _k.mean_and_covariance_all(pts)
    return np.linalg.eigvalsh(cov)


def _orient(coefficients: np.ndarray) -> np.ndarray:
    return -coefficients if coefficients[3] < 0 else coefficients


def fit_plane_rmsac(
    points_xyz_m: np.ndarray,
    *,
    distance_threshold_m: float,
    confidence: float = 0.99,
    max_iterations: int = 1000,
    n_pretest: int = 1,
    refine: bool = True,
    seed: int | np.random.Generator | None = 0,
) -> PlaneModel:
    """Fit the dominant plane of a cloud by RMSAC.

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Points in metres (any frame), finite, N >= 3, not all collinear.
    distance_threshold_m : float
        Inlier threshold T in metres (> 0): inliers have ``|n.p + d| < T``.
    confidence : float
        Probability p in (0, 1) of drawing at least one all-inlier sample; sets the adaptive
        iteration count ``k = log(1 - p) / log(1 - w**3)``.
    max_iterations : int
        Hard cap (>= 1) on hypotheses drawn; always honoured.
    n_pretest : int
        Points (>= 0) of the randomized T(d,d) pre-test; 0 scores every hypothesis (plain MSAC).
    refine : bool
        Refit the plane by least squares (PCA) on the inliers, then re-select the inliers.
    seed : int, numpy Generator or None
        Randomness; an int gives reproducible results.

    Returns
    -------
    PlaneModel
        Coefficients with unit normal and ``d >= 0``; inlier indices into ``points_xyz_m``.

    Raises
    ------
    SegmentationError
        Fewer than 3 points, all points identical or collinear.
    InputError
        Bad arguments (NaN points, threshold <= 0, confidence outside (0, 1), ...).
    """
    caller = "fit_plane_rmsac"
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller=caller)
    thr = check_positive("distance_threshold_m", distance_threshold_m, caller=caller)
    conf, max_it, n_pre, rng = _check_sampling(confidence, max_iterations, n_pretest, seed, caller)
    return _fit(pts, thr, conf, max_it, n_pre, bool(refine), rng, caller)


def _check_sampling(confidence, max_iterations, n_pretest, seed, caller: str):
    """Validated RMSAC sampling arguments: confidence in (0, 1), iteration cap >= 1, pre-test size >= 0, RNG."""
    conf = check_positive("confidence", confidence, caller=caller)
    if not conf < 1.0:
        raise InputError(f"The 'confidence' argument of {caller} must be in (0, 1). Got {confidence!r} instead.")
    max_it = check_int("max_iterations", max_iterations, caller=caller, minimum=1)
    n_pre = check_int("n_pretest", n_pretest, caller=caller, minimum=0)
    return conf, max_it, n_pre, as_rng(seed, caller=caller)


def _fit(
    pts: np.ndarray,
    thr: float,
    conf: float,
    max_it: int,
    n_pre: int,
    refine: bool,
    rng: np.random.Generator,
    caller: str,
) -> PlaneModel:
    """fit_plane_rmsac on validated arguments."""
    _check_spread(pts, caller)
    state = np.array([rng.integers(0, 2**63, dtype=np.int64)], dtype=np.int64).view(np.uint64)
    coeffs, n_it, n_scored, n_degenerate, _ = _k.rmsac_plane(
        pts, thr, math.log(1.0 - conf), max_it, n_pre, state, max(1000, 10 * max_it)
    )
    if n_scored == 0:
        raise SegmentationError(
            f"fit_plane_rmsac drew {n_degenerate} degenerate samples (repeated or collinear points) out of "
            f"{len(pts)} points and found no plane hypothesis."
        )
    inliers, sums = _k.inliers_and_sum(pts, coeffs, thr)
    if refine and len(inliers) >= 3:
        refined = _least_squares_plane(pts, inliers, sums)
        if refined is not None:
            coeffs = refined
    inliers, squares = _k.inliers_and_squares(pts, coeffs, thr)
    coeffs = _orient(coeffs)
    rmse = float(np.sqrt(np.mean(squares))) if len(inliers) else math.nan
    return PlaneModel(
        coefficients=coeffs,
        inlier_indices=inliers,
        n_inliers=len(inliers),
        n_points=len(pts),
        rmse_m=rmse,
        distance_threshold_m=thr,
        n_iterations=int(n_it),
        n_scored=int(n_scored),
        n_degenerate=int(n_degenerate),
    )


def _least_squares_plane(
    pts: np.ndarray, indices: np.ndarray, sums: np.ndarray | None = None
) -> np.ndarray | None:
    """Total-least-squares plane (4,) of ``pts[indices]``: normal = smallest-eigenvalue eigenvector
    of the covariance. None when the points are collinear (no unique plane). ``sums``: the (3,)
    coordinate sums of those points in index order, when already known."""
    if sums is None:
        centroid, cov = _k.mean_and_covariance(pts, indices)
    else:
        centroid, cov = _k.covariance_from_sum(pts, indices, sums)
    eigval, eigvec = np.linalg.eigh(cov)
    if not eigval[2] > 0 or eigval[1] <= 1e-12 * eigval[2]:
        return None
    normal = eigvec[:, 0]
    return np.array([normal[0], normal[1], normal[2], -float(normal @ centroid)])


@dataclass(frozen=True, eq=False)
class PlaneRemovalResult:
    """Result of :func:`remove_dominant_planes`.

    Attributes
    ----------
    remaining_indices : ndarray of shape (R,), int64
        Sorted indices (into the input) of the points on none of the removed planes.
    planes : list of PlaneModel
        Removed planes, in removal order; their ``inlier_indices`` index the INPUT cloud when kept,
        else are None.
    n_points : int
        Number of input points.
    stop_reason : str
        Why no further plane was removed (``"max_planes reached"``, a too-small plane, ...).
    """

    remaining_indices: np.ndarray
    planes: list[PlaneModel] = field(default_factory=list)
    n_points: int = 0
    stop_reason: str = ""

    @property
    def n_removed(self) -> int:
        return self.n_points - len(self.remaining_indices)

    def to_dict(self) -> dict:
        return {
            "n_points": self.n_points,
            "n_remaining": len(self.remaining_indices),
            "planes": [p.to_dict() for p in self.planes],
            "stop_reason": self.stop_reason,
        }


def remove_dominant_planes(
    points_xyz_m: np.ndarray,
    *,
    distance_threshold_m: float,
    max_planes: int = 1,
    min_inliers: int | None = None,
    keep_inliers: bool = False,
    confidence: float = 0.99,
    max_iterations: int = 1000,
    n_pretest: int = 1,
    seed: int | np.random.Generator | None = 0,
) -> PlaneRemovalResult:
    """Remove up to ``max_planes`` dominant planes (tank floor, walls) one after the other.

    Each round fits a plane by :func:`fit_plane_rmsac` on the points left and removes its inliers;
    it stops when ``max_planes`` planes were removed, when the next plane has fewer than
    ``min_inliers`` inliers (that plane is not removed), or when fewer than 3 non-collinear points
    remain. The reason is recorded in ``stop_reason``; this never raises for a scene that runs out
    of points after a plane.

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Points in metres, finite. N >= 3 and not all collinear, else SegmentationError.
    distance_threshold_m : float
        Inlier threshold T in metres.
    max_planes : int
        Maximum number of planes to remove (>= 0).
    min_inliers : int, optional
        Smallest plane removed (>= 3). Default: 5 % of N (at least 3).
    keep_inliers : bool
        Keep each plane's inlier indices (into the input) in the result; otherwise they are None
        and only ``n_inliers`` is kept.
    confidence, max_iterations, n_pretest :
        As in :func:`fit_plane_rmsac`, for every plane.
    seed : int, numpy Generator or None
        Randomness of the whole sequence.

    Returns
    -------
    PlaneRemovalResult
    """
    caller = "remove_dominant_planes"
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller=caller)
    thr = check_positive("distance_threshold_m", distance_threshold_m, caller=caller)
    k_max = check_int("max_planes", max_planes, caller=caller, minimum=0)
    min_in = (
        max(3, math.ceil(0.05 * len(pts)))
        if min_inliers is None
        else check_int("min_inliers", min_inliers, caller=caller, minimum=3)
    )
    conf, max_it, n_pre, rng = _check_sampling(confidence, max_iterations, n_pretest, seed, caller)
    return _remove_planes(
        pts, thr, k_max, min_in, bool(keep_inliers), conf, max_it, n_pre, rng, caller
    )


def _remove_planes(
    pts: np.ndarray,
    thr: float,
    k_max: int,
    min_in: int,
    keep_inliers: bool,
    conf: float,
    max_it: int,
    n_pre: int,
    rng: np.random.Generator,
    caller: str,
) -> PlaneRemovalResult:
    """remove_dominant_planes on validated arguments (``pts`` C-contiguous finite float64 (N, 3))."""
    remaining = _ALL  # empty: all the points (np.arange only when needed)
    planes: list[PlaneModel] = []
    reason = "max_planes reached"
    while len(planes) < k_max:
        try:
            subset = pts if remaining is _ALL else pts[remaining]
            plane = _fit(subset, thr, conf, max_it, n_pre, True, rng, caller)
        except SegmentationError as exc:
            if not planes:
                raise
            reason = f"{len(remaining)} points left, no further plane: {exc}"
            break
        if plane.n_inliers < min_in:
            reason = f"next plane has {plane.n_inliers} inliers < min_inliers={min_in}"
            break
        if keep_inliers:
            kept = plane.inlier_indices if remaining is _ALL else remaining[plane.inlier_indices]
        planes.append(replace(plane, inlier_indices=kept if keep_inliers else None))
        remaining = _k.complement(remaining, plane.inlier_indices, len(pts))
        if len(remaining) == 0:
            reason = "no points left"
            break
    if remaining is _ALL:
        remaining = np.arange(len(pts), dtype=np.int64)
    return PlaneRemovalResult(
        remaining_indices=remaining, planes=planes, n_points=len(pts), stop_reason=reason
    )


_ALL = np.zeros(0, np.int64)
