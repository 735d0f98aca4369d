"""Fragments: clusters left unknown that are pieces of an object recognised in the same scan.

Euclidean clustering cuts an object wherever the scanner does not see what joins its parts, and the part-based
stage (:mod:`.parts`) joins at most ``PartsConfig.max_parts`` clusters into one object; a small piece left over
(a funnel's rim behind its body, a plate's edge beyond a shadow) matches no view alone and was reported unknown,
beside the detection of the very object it belongs to.

:func:`absorb_fragments` (``PartsConfig(fragments=True)``, the default of the part-based stage) runs after it. A
cluster still unknown becomes a fragment of a detection of the scan when, under that detection's pose, at least
``PartsConfig.min_part_fitness`` of its points lie within ``PoseConfig.icp_max_correspondence_m`` of the class's
surface model (the test every part of a union passes; ``ScanRecognizer.surface_model``: the pose-model views and
the recognition views together, so the bottom of a deep bore that only the survey's steep views reach is on it):
the cluster gets the detection's class and its one
:class:`~semslam.detection.Detection`, whose ``extras["fragments"]`` lists such clusters (``extras["fragment_fitness"]``
their shares). The pose is not changed: the detection was posed and verified without them. A rock or an offcut
beside the object is off the model's surface (its points are not within millimetres of it) and stays unknown.
Clusters too big for every class stay unknown, and so do clusters cut by the scan border when the border policy is
``"reject"``.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from ..detection import Detection
from ._scan_helpers import _input_indices
from .parts import _part_fitness, min_part_share
from .scan_records import ClusterOutcome, ScanContext

__all__ = ["absorb_fragments"]


def _candidate(outcome: ClusterOutcome, border_policy: str) -> bool:
    """A cluster that may be a fragment: unknown, not too big for every class, not border-cut under ``"reject"``."""
    return (outcome.detection is None and "for any class" not in outcome.reason
            and not (border_policy == "reject" and outcome.touches_border))


def _best_fit(rec: Any, points: np.ndarray, detections: list[Detection], min_share: float) -> tuple | None:
    """``(share, detection)`` of the detection whose posed model holds the largest share of ``points`` (at least
    ``min_share``; the earlier detection on a tie), or None."""
    best = None
    for det in detections:
        share = _part_fitness(rec, det, det.label, int(det.extras["view_index"]), [points])[0]
        if share >= min_share and (best is None or share > best[0]):
            best = (share, det)
    return best


def absorb_fragments(rec: Any, ctx: ScanContext, seg: Any, outcomes: list[ClusterOutcome],
                     detections: list[Detection], *, timings: dict) -> list[ClusterOutcome]:
    """The fragment step of one scan (module docstring): ``outcomes`` (a new list) with every unknown cluster that
    lies on the surface of a detection's posed model given that detection. ``detections`` are unchanged but for
    their ``extras["fragments"]`` / ``extras["fragment_fitness"]``. ``timings["fragments"]`` gets the time (ms)."""
    t0 = time.perf_counter()
    cfg = rec.config
    min_share = min_part_share(cfg)
    outcomes = list(outcomes)
    posed = [d for d in detections if d.extras.get("view_index") is not None]  # the stage needs verified poses
    members = {id(d): [o.cluster_index for o in outcomes if o.detection is d] for d in posed}
    for o in list(outcomes):
        raw = _input_indices(seg, o.cluster_index) if posed and _candidate(o, cfg.border) else ()
        if not len(raw):
            continue
        found = _best_fit(rec, ctx.scan.points_xyz_m[raw], posed, min_share)
        if found is None:
            continue
        share, det = found
        det.extras.setdefault("fragments", []).append(int(o.cluster_index))
        det.extras.setdefault("fragment_fitness", []).append(float(share))
        reason = (f"detected as a fragment of the {det.label} of clusters {members[id(det)]}"
                  + ("" if det.reliable else " (unreliable pose)")
                  + (", touches the scan border" if o.touches_border else ""))
        outcomes[o.cluster_index] = dataclasses.replace(o, label=det.label, detection=det, reason=reason)
    timings["fragments"] = (time.perf_counter() - t0) * 1e3
    return outcomes

