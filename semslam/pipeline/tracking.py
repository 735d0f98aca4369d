"""Border-cut clusters recognised by tracking (``PipelineConfig.track_border_cut_m``): from the scan before and after.

A cluster cut by the scan's border is often too little of its object to tell it from its neighbours in the catalogue
(a strip of a flange's rim, a tee without the arm that makes it a tee): alone it is rejected, or taken for the
neighbour it looks like (a cross cut to a tee fits the tee at fitness 1.000). But a line scanner
sweeps the scene a fraction of its swath per scan, so an object leaving the swath was usually recognised whole in the
scan before. Its pose there, carried into this scan by the vehicle's own motion between the two (attitude + DVL,
:mod:`semslam.pipeline.deskew`; never the filter's estimate, never ground truth), is a prior: the rejected cluster
that lies where the object is predicted is aligned to the class's model by ICP from the predicted pose (by the
class's pose search when that fails), and kept when the pose passes the same verification as any other (fitness,
floor, visibility) and moved no more than ``track_border_cut_m`` from the prediction. Its detection keeps the border's
flag (unreliable: by default it does not enter the filter), a position covariance widened by ``track_border_cut_m``
squared per axis (what the cut view does not fix, the prediction did, within that), and says whence it came
(``extras["tracked_from_scan"]``; the reason "tracked from scan k").
A border-cut cluster recognised alone as another class than the object predicted there is tried the same way: when
the predicted object's pose verifies too, the scan before's view (the whole object) decides what it is.

The priors come from the detections of the scan before (tracked ones included, so an object is followed out of the
swath), given to the scan's recognition, and from those of the scan after (an object entering the swath, recognised
whole one scan later), carried back: a runner holds each scan's result, with its context, until the scan after it is
recognised and then makes it final (:func:`~semslam.pipeline.dataset_detection.track_from_scan_after`), when that
scan ends within :data:`SPANS_TO_THE_SCAN_AFTER` of its spans (:func:`follows_closely`; after a gap in the scans it
is not waited for). Nothing here reads more than the scans either side and the navigation between them."""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..detection import Detection
from ..errors import RegistrationError
from ._scan_helpers import _input_indices
from .hypothesis import Hypothesis, pose_hypothesis, verification_failure
from .scan_records import ClusterOutcome, ScanContext
from .stages import describe, size_rejection

__all__ = ["MAX_TRACK_AGE_S", "SPANS_TO_THE_SCAN_AFTER", "TrackPrior", "follows_closely", "predicted_priors",
           "track_rejected", "tracks"]

_log = logging.getLogger("semslam.pipeline")

#: the oldest detection (s before the scan's stamp) that is carried into a scan as a prior
MAX_TRACK_AGE_S = 3.0
#: a scan is tracked from the scan after it when that one ends within this many of its spans from its first point
#: (the next scan back to back ends two spans after it: a runner's filters wait that long for it,
#: :meth:`semslam.run.scan_flow.ScanFlow.hold_s`)
SPANS_TO_THE_SCAN_AFTER = 3.0


def tracks(recognizer: Any) -> bool:
    """Does ``recognizer`` (a :class:`~semslam.pipeline.ScanRecognizer`, or any object with a ``config``) track
    border-cut clusters from the scan before (``PipelineConfig.track_border_cut_m``)?"""
    return getattr(getattr(recognizer, "config", None), "track_border_cut_m", None) is not None


def follows_closely(first_stamp_s: float, start_stamp_s: float, end_stamp_s: float, after_end_stamp_s: float) -> bool:
    """Is a scan (its first point's stamp, its start and end) tracked from the scan after it, ending at
    ``after_end_stamp_s``? When that one ends within :data:`SPANS_TO_THE_SCAN_AFTER` of its spans from its first
    point: a scan after a gap in the scans (a turn, a pause) is not waited for, by any runner alike."""
    span = max(0.0, float(end_stamp_s) - float(start_stamp_s))
    return float(after_end_stamp_s) - float(first_stamp_s) <= SPANS_TO_THE_SCAN_AFTER * span


@dataclass(frozen=True)
class TrackPrior:
    """An object recognised in an earlier scan, predicted in this scan's sensor frame.

    Attributes
    ----------
    label : str
    T_sensor_object : ndarray (4, 4)
        The predicted pose in the frame this scan is recognised in.
    scan_id : int
        The scan it was recognised in.
    """

    label: str
    T_sensor_object: np.ndarray
    scan_id: int


def predicted_priors(detections: Sequence[Detection], motion: Any, T_vehicle_sensor: Any, to_stamp_s: float,
                     max_age_s: float = MAX_TRACK_AGE_S) -> list[TrackPrior]:
    """The ``detections`` of another scan (each in the sensor frame at its own stamp; the scan before, or the scan
    after) carried to the sensor frame at ``to_stamp_s`` by the vehicle's ``motion``
    (:class:`~semslam.pipeline.deskew.ScanMotion` over a window holding both stamps; None: no navigation, no priors).
    Detections more than ``max_age_s`` from ``to_stamp_s``, outside the window or without a finite stamp are left
    out."""
    from .deskew import sensor_motion_between

    if motion is None:
        return []
    out = []
    for d in detections:
        age = float(to_stamp_s) - float(d.stamp_s)
        if not abs(age) <= max_age_s or not motion.stamps_s[0] <= d.stamp_s <= motion.stamps_s[-1]:
            continue
        T_now_then = sensor_motion_between(motion, T_vehicle_sensor, float(d.stamp_s), float(to_stamp_s))
        out.append(TrackPrior(str(d.label), T_now_then @ d.T_sensor_object.matrix, int(d.scan_id)))
    return out


def track_rejected(rec: Any, ctx: ScanContext, seg: Any, outcomes: list[ClusterOutcome], detections: list[Detection],
                   priors: Sequence[TrackPrior], timings: dict) -> tuple[list[ClusterOutcome], list[Detection]]:
    """The border-cut clusters of a recognised scan (its context, segmentation, outcomes and detections) rejected, or
    recognised alone as another class than a prior about them, tried at those priors: the outcomes and the
    detections with those that verify added or replaced (``timings["tracking"]``, ms)."""
    t0 = time.perf_counter()
    outcomes, detections = list(outcomes), list(detections)
    max_shift = rec.config.track_border_cut_m
    cut = priors and any(o.touches_border for o in outcomes)  # (else nothing to try)
    classes = set(rec.db.classes) if cut else set()
    known = [p for p in priors if p.label in classes]
    for k, o in enumerate(outcomes):
        if not o.touches_border or not known or not (o.detection is None or _alone(o, outcomes)):
            continue
        cluster = seg.clusters[o.cluster_index]
        centroid = cluster.points_xyz_m.mean(axis=0)
        others = [d for d in detections if d is not o.detection]
        desc = None  # the cluster's descriptors, once for all its priors
        for prior in _candidates(rec, known, centroid, others, np.asarray(o.extent_m)):
            if o.detection is not None and o.detection.label == prior.label:  # what it was: nothing to decide
                continue
            if desc is None:
                desc = describe(rec, cluster, ctx.cluster_seed + o.cluster_index)
            if isinstance(desc, str):  # no descriptor: nothing to score a pose of it with
                break
            det, why = _tracked(rec, ctx, seg, o, prior, desc, max_shift, timings)
            if det is None:
                _log.debug("scan %d cluster %d as the %s of scan %d: %s", ctx.scan_id, o.cluster_index, prior.label,
                           prior.scan_id, why)
                continue
            det.extras["tracked_from_scan"] = prior.scan_id
            alone = f"alone {o.reason}" if o.detection is None else f"alone as {o.label}"
            reason = (f"detected (unreliable pose), tracked from scan {prior.scan_id} "
                      f"(nearest {o.nearest_label or 'none'}; {alone})")
            outcomes[k] = dataclasses.replace(o, label=prior.label, detection=det, reason=reason)
            detections = others + [det]
            break
    timings["tracking"] = (time.perf_counter() - t0) * 1e3
    return outcomes, detections


def _alone(o: ClusterOutcome, outcomes: list[ClusterOutcome]) -> bool:
    """Is ``o``'s detection its own (not a union's, nor one it is a fragment of)?"""
    return sum(x.detection is o.detection for x in outcomes) == 1 and "fragments" not in o.detection.extras


def _candidates(rec: Any, priors: Sequence[TrackPrior], centroid: np.ndarray, detections: list[Detection],
                extent_m: np.ndarray) -> list[TrackPrior]:
    """The priors a cluster (its centroid, principal extents) may be: predicted within their class's radius (half its
    box's diagonal, plus ``track_border_cut_m``) of the centroid, of a class whose size test the cluster passes, not
    recognised in this scan already (a detection of the class within that radius of the prediction), nearest
    first."""
    found = []
    for p in priors:
        radius = 0.5 * float(np.linalg.norm(rec.db.class_info(p.label).size_xyz_m)) + rec.config.track_border_cut_m
        at = p.T_sensor_object[:3, 3]
        d = float(np.linalg.norm(at - centroid))
        if d > radius or size_rejection(rec, p.label, extent_m):
            continue
        if any(det.label == p.label and np.linalg.norm(det.T_sensor_object.translation_m - at) <= radius
               for det in detections):
            continue
        found.append((d, p))
    return [p for _, p in sorted(found, key=lambda x: x[0])]


def _tracked(rec: Any, ctx: ScanContext, seg: Any, o: ClusterOutcome, prior: TrackPrior, desc: Any,
             max_shift_m: float, timings: dict) -> tuple[Detection | None, str]:
    """The detection of cluster ``o`` (its descriptors ``desc``) as ``prior``'s object, or None and why not: ICP from
    the prediction first (``extras["track_pose"] = "prediction"``), then, when that pose fails, the class's pose
    search (``"search"``: ICP's basin on a cut view can be narrower than the navigation's error between two scans,
    a half socket's under 2 cm)."""
    why = ""
    for init in (prior.T_sensor_object, None):
        det, why = _tracked_from(rec, ctx, seg, o, prior, desc, max_shift_m, timings, init)
        if det is not None:
            det.extras["track_pose"] = "search" if init is None else "prediction"
            return det, ""
    return None, why


def _tracked_from(rec: Any, ctx: ScanContext, seg: Any, o: ClusterOutcome, prior: TrackPrior, desc: Any,
                  max_shift_m: float, timings: dict, init: np.ndarray | None) -> tuple[Detection | None, str]:
    """:func:`_tracked` from ``init`` (ICP from it; None: the pose search)."""
    cluster = seg.clusters[o.cluster_index]
    seed = ctx.cluster_seed + o.cluster_index
    match = rec.recognizer.class_match(desc, prior.label)
    hyp = Hypothesis(_input_indices(seg, o.cluster_index), cluster, prior.label, match.view_index, match,
                     touches_border=True, init_T_sensor_object=init)
    try:
        det = pose_hypothesis(rec, ctx, seg, hyp, seed=seed, timings=timings)
    except RegistrationError as exc:
        return None, str(exc)
    cfg = rec.config
    failed = verification_failure(det, cfg.verify_min_fitness, cfg.verify_max_visibility,
                                  cfg.verify_max_plane_penetration_m)
    if failed:
        return None, failed
    shift = float(np.linalg.norm(det.T_sensor_object.translation_m - prior.T_sensor_object[:3, 3]))
    if shift > max_shift_m:
        return None, f"moved {1e3 * shift:.1f} mm from the prediction (> {1e3 * max_shift_m:g} mm)"
    det.extras["track_shift_m"] = shift
    # where a cut view does not fix the position (along an anode's axis), the prediction did, within max_shift_m:
    # the position covariance says so (measured without it: a tracked anode 30 mm off along its axis, NEES6 850)
    cov = np.array(det.covariance_6x6, dtype=float)
    cov[:3, :3] += np.eye(3) * max_shift_m ** 2
    return dataclasses.replace(det, covariance_6x6=cov), ""
