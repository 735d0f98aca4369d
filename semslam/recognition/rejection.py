"""Rejection of objects that are not in the database (rocks, pipe offcuts, pieces of wall).

A nearest-neighbour matcher always answers with some class; here a query is accepted only if its
chi-square distance to the nearest stored view is not much larger than the distances *between the
database's own views*. Calibration uses the database alone:

1. for every stored view, its leave-one-out distance: the chi-square distance to the nearest **other** view
   of the **same** class (how far a new view of a known object typically lies from what is stored);
2. threshold = ``margin * quantile(distances, q)``, either over all views (``mode="global"``, the default
   and the more stable choice with few views per class) or class by class (``mode="per_class"``, which
   adapts to classes whose appearance changes more with the viewpoint; with fewer than
   ``min_class_views`` views in a class the global threshold is used for it).

**Leave one viewpoint out.** A database recorded by a user often holds several frames of one viewpoint
(two frames per rig setting in the shared RealSense valve views). The nearest other view of a frame is then
its twin, at a distance that says nothing about a *new* viewpoint, and the threshold comes out far too tight
(on those valves 83 % of held-out views accepted with ESF, 33 % with ESF+VFH). When the views' viewing
directions are known in the object frame (``view_directions``: from each view's centroid to its sensor
origin, :meth:`ViewDatabase.view_directions`), step 1 skips the same-class views seen from within
``min_view_separation_deg`` (10 degrees) of the left-out one; a view with no other viewpoint in its class
keeps its plain leave-one-out distance. Databases whose views all come from distinct viewpoints (the
simulated ones: 45 degrees apart) calibrate exactly as before.

Defaults ``q = 0.95``, ``margin = 1.0``, ``mode="global"``. No extra margin is needed because a
leave-one-out distance is already pessimistic: with views every 45 degrees, the left-out view is 45
degrees from its nearest neighbour, while a new view is at most 22.5 degrees from one. Measured on the
built-in database (8 Kinect views per object; ``benchmarks/database.py --only reject``: 32 new views from
the odd azimuths of a 16-view acquisition, and 80 clutter clouds -- the simulator's rocks and pipe
offcuts and synthetic rocks, pipes and wall pieces -- all moved to a random sensor frame):

* ESF: 96.9 % of new views accepted and correct, 3.1 % rejected, 5 % of clutter falsely accepted
  (simulator rocks 10 %); margin 1.5: 100 % accepted, 10 % false accepts.
* ESF+VFH: 100 % accepted and correct, 1.2 % false accepts.
* ``per_class`` with 8 views per class is too noisy (22-28 % of new ESF views rejected): prefer global.

Clusters from a different sensor (the laser scanner) sit farther from the Kinect views: on simulated
laser missions, with the survey-geometry database, known objects lie up to ~6x the ESF+VFH threshold
away, so :class:`~semslam.pipeline.PipelineConfig` uses ``reject_margin=6`` and rejects clutter mainly by
size (``benchmarks/recognition.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._validation import check_choice, check_int, check_positive
from ..errors import RecognitionError

UNKNOWN_LABEL = "unknown"

__all__ = ["UNKNOWN_LABEL", "RejectionThresholds", "calibrate_rejection", "loo_same_class_distances"]


@dataclass(frozen=True)
class RejectionThresholds:
    """Chi-square distance thresholds above which a match is rejected as ``"unknown"``.

    Attributes
    ----------
    global_threshold : float
        Threshold used for every class in ``mode="global"``, and for classes without their own.
    per_class : dict of str to float
        Thresholds of the classes calibrated on their own (``mode="per_class"``), else empty.
    mode : str
    quantile, margin : float
        The calibration parameters.
    """

    global_threshold: float
    per_class: dict = field(default_factory=dict)
    mode: str = "global"
    quantile: float = 0.95
    margin: float = 1.0

    def threshold_of(self, label: str) -> float:
        """The threshold applied to a match of class ``label``."""
        return float(self.per_class.get(str(label), self.global_threshold))

    def thresholds_for(self, labels: Any) -> np.ndarray:
        """Thresholds (n,) for an array of predicted labels (n,)."""
        return np.array([self.threshold_of(lab) for lab in np.asarray(labels).ravel()], dtype=float)

    def to_dict(self) -> dict:
        return {"mode": self.mode, "quantile": self.quantile, "margin": self.margin,
                "global_threshold": self.global_threshold, "per_class": dict(self.per_class)}


def same_viewpoint_pairs(view_directions: Any, min_view_separation_deg: float) -> np.ndarray:
    """(n, n) True where two views' directions are within ``min_view_separation_deg`` (diagonal included);
    rows with a NaN direction pair only with themselves."""
    V = np.asarray(view_directions, dtype=float)
    with np.errstate(invalid="ignore"):
        cos = V @ V.T
    close = cos >= np.cos(np.radians(min_view_separation_deg))
    close |= np.eye(len(V), dtype=bool)
    return close


def loo_same_class_distances(X: np.ndarray, y: np.ndarray, same_viewpoint: np.ndarray | None = None) -> np.ndarray:
    """Chi-square distance of every row of ``X`` (n, d) to the nearest other row with the same label.

    With ``same_viewpoint`` ((n, n) bool, see :func:`same_viewpoint_pairs`), rows seen from the same
    viewpoint are skipped, unless that leaves a row without any (then its plain nearest distance counts).
    Rows whose class has no other row get NaN (they carry no information about the spread).
    """
    from ._chi2_kernels import chi2_distance_matrix

    X = np.ascontiguousarray(X, dtype=float)
    y = np.asarray(y).astype(str)
    D = chi2_distance_matrix(X, X)
    same = (y[:, None] == y[None, :]) & ~np.eye(len(y), dtype=bool)
    nearest = np.where(same, D, np.inf).min(axis=1)
    if same_viewpoint is not None:
        other_view = np.where(same & ~same_viewpoint, D, np.inf).min(axis=1)
        nearest = np.where(np.isfinite(other_view), other_view, nearest)
    nearest[~np.isfinite(nearest)] = np.nan
    return nearest


def _cached_loo_distances(X: np.ndarray, y: np.ndarray, same_viewpoint: np.ndarray | None) -> np.ndarray:
    """:func:`loo_same_class_distances` through the on-disk cache (:mod:`semslam._cache`): the (n, n) distance
    matrix behind it is most of a cold start's work on a user's database (832 views: ~0.5 s), and it depends on
    the database alone."""
    from .._cache import cached_arrays

    key = [X, y.astype("U"), "all" if same_viewpoint is None else same_viewpoint]
    return cached_arrays("rejection_loo_v1", key,
                         lambda: {"nearest": loo_same_class_distances(X, y, same_viewpoint)})["nearest"]


def calibrate_rejection(X: Any, y: Any, *, quantile: float = 0.95, margin: float = 1.0,
                        mode: str = "global", min_class_views: int = 4, view_directions: Any = None,
                        min_view_separation_deg: float = 10.0) -> RejectionThresholds:
    """Calibrate unknown-object thresholds from a database's own descriptors (see module docstring).

    Parameters
    ----------
    X : array-like of shape (n_views, n_bins)
        Non-negative histograms of the stored views.
    y : array-like of str, shape (n_views,)
        Their class labels (``"unknown"`` is reserved).
    quantile : float in (0, 1]
    margin : float > 0
    mode : {"global", "per_class"}
    min_class_views : int
        Classes with fewer views fall back to the global threshold in ``per_class`` mode.
    view_directions : array-like of shape (n_views, 3), optional
        Unit viewing directions in the object frame (NaN rows: unknown); calibrate leaving one viewpoint
        out (module docstring). None: plain leave-one-out.
    min_view_separation_deg : float
        Views closer than this show the same viewpoint.

    Returns
    -------
    RejectionThresholds
    """
    caller = "calibrate_rejection"
    q = check_positive("quantile", quantile, caller=caller)
    if q > 1:
        raise RecognitionError(f"The 'quantile' argument of {caller} must be in (0, 1]. Got {quantile!r} instead.")
    m = check_positive("margin", margin, caller=caller)
    check_choice("mode", mode, ("global", "per_class"), caller=caller)
    check_int("min_class_views", min_class_views, caller=caller, minimum=2)
    X = np.ascontiguousarray(X, dtype=float)
    y = np.asarray(y).astype(str)
    if X.ndim != 2 or len(X) != len(y):
        raise RecognitionError(f"The 'X' and 'y' arguments of {caller} must have n_views rows each. "
                               f"Got shapes {X.shape} and {y.shape} instead.")
    if UNKNOWN_LABEL in set(y):
        raise RecognitionError(f"The label {UNKNOWN_LABEL!r} is reserved for rejected objects; "
                               f"a database class must not use it.")
    same_viewpoint = None
    if view_directions is not None:
        check_positive("min_view_separation_deg", min_view_separation_deg, caller=caller)
        V = np.asarray(view_directions, dtype=float)
        if V.shape != (len(y), 3):
            raise RecognitionError(f"The 'view_directions' argument of {caller} must have shape ({len(y)}, 3). "
                                   f"Got {V.shape} instead.")
        same_viewpoint = same_viewpoint_pairs(V, min_view_separation_deg)
    d = _cached_loo_distances(X, y, same_viewpoint)
    finite = d[np.isfinite(d)]
    if finite.size == 0:
        raise RecognitionError(
            f"{caller} needs at least one class with 2 or more views to calibrate a threshold. "
            f"Got {len(y)} view(s) in {len(set(y))} class(es), one view each."
        )
    global_t = m * float(np.quantile(finite, q))
    per_class: dict[str, float] = {}
    if mode == "per_class":
        for label in np.unique(y):
            dc = d[(y == label) & np.isfinite(d)]
            if np.count_nonzero(y == label) >= min_class_views and dc.size:
                per_class[str(label)] = m * float(np.quantile(dc, q))
    return RejectionThresholds(global_t, per_class, mode, q, m)
