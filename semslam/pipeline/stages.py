"""The per-cluster stages of :meth:`~semslam.pipeline.scan.ScanRecognizer.recognize`, in the order they run:
:func:`segment` (planes removed, clusters), then for every cluster (:func:`recognize_clusters`)
:func:`plausibility_rejection` (too big for any class, cut by the scan border), :func:`describe` (global
descriptors), :func:`match` (nearest view, unknown rejection), :func:`size_rejection` (the size test of the
class), the pose (:func:`~semslam.pipeline.hypothesis.pose_hypothesis`) and its verification
(:func:`~semslam.pipeline.hypothesis.verification_failure`); a class that fails verification may give way to the
next-nearest ones (:func:`next_classes`, ``verify_next_classes``).

Each stage takes what it reads as arguments and returns what it makes; ``rec`` is the
:class:`~semslam.pipeline.scan.ScanRecognizer` (its ``config``, ``db``, ``classify``, ``class_size_limit_m`` and
``max_plausible_extent_m``); ``timings`` (ms per stage) is the one accumulator they share."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..cloud import PointCloud
from ..detection import Detection
from ..errors import DescriptorError
from ..recognition import UNKNOWN_LABEL
from ..recognition.plausibility import border_touched, principal_extent
from ..segmentation.scene import SegmentationResult, segment_scene
from ._scan_helpers import _input_indices, _scan_angular_extent, _valid_points
from .hypothesis import Hypothesis, pose_hypothesis, verification_failure
from .scan_records import ClusterOutcome, ScanContext

__all__ = ["describe", "match", "next_classes", "plausibility_rejection", "recognize_clusters", "scan_footprint",
           "segment", "size_rejection"]


def segment(ctx: ScanContext, config: Any) -> SegmentationResult:
    """Plane removal and clustering of the scan (``config``: the pipeline's :class:`PipelineConfig`)."""
    return segment_scene(ctx.scan, config.segmentation, seed=ctx.segmentation_seed)


def scan_footprint(scan: PointCloud, config: Any) -> np.ndarray | None:
    """The scan's angular extent (4,) for the border test, or None when ``config.border`` is ``"keep"``."""
    if config.border == "keep":
        return None
    return _scan_angular_extent(_valid_points(scan, config.segmentation.drop_origin), scan.viewpoint_xyz_m)


def plausibility_rejection(extent_m: np.ndarray, touches_border: bool, max_plausible_m: float, config: Any) -> str:
    """Why a cluster of principal extents ``extent_m`` is rejected before matching, or ``""``."""
    if extent_m[0] > max_plausible_m:
        return f"rejected: extent {extent_m[0]:.3f} m > {max_plausible_m:.3f} m, too big for any class"
    if touches_border and config.border == "reject":
        return "rejected: touches the scan border (partial object)"
    return ""


def describe(rec: Any, cluster: PointCloud, seed: int) -> Any:
    """The cluster's global descriptors, or why there are none (a ``str``: a sparse cluster, points farther apart
    than the normal radius)."""
    try:
        return rec.db.describe(cluster, seed=seed)
    except DescriptorError as exc:
        return f"rejected: no descriptor ({exc})"


def match(rec: Any, desc: Any) -> tuple[Any, str, int, str]:
    """``(match, label, view_index, why)``: the nearest-view match of the descriptors, the class chosen (the SVM's,
    when it is used) and its view, and ``why`` the cluster is unknown (``""``: recognised)."""
    found, label, view_index = rec.classify(desc)
    if label == UNKNOWN_LABEL:
        return found, label, view_index, f"rejected: distance {found.distance:.4g} > threshold {found.threshold:.4g}"
    return found, label, view_index, ""


def size_rejection(rec: Any, label: str, extent_m: np.ndarray) -> str:
    """Why a cluster of principal extents ``extent_m`` is too big for class ``label``, or ``""``."""
    if rec.config.size_tolerance is not None:
        limit = rec.class_size_limit_m(label)
        if extent_m[0] > limit:
            return f"rejected: extent {extent_m[0]:.3f} m > {limit:.3f} m, too big for {label}"
    return ""


def _recognize_cluster(rec: Any, ctx: ScanContext, seg: SegmentationResult, k: int, footprint: np.ndarray | None,
                       max_plausible_m: float, timings: dict) -> ClusterOutcome:
    """Cluster ``k`` through the stages: its outcome (with the detection when it is recognised)."""
    cfg = rec.config
    cluster = seg.clusters[k]
    cluster_seed = ctx.cluster_seed + k
    # The clusters' points are checked PointCloud arrays: the kernels take them as they are.
    extent = principal_extent(cluster.points_xyz_m)
    border_pts = cluster.points_xyz_m if ctx.measured is None else \
        np.ascontiguousarray(ctx.measured.points_xyz_m[_input_indices(seg, k)])
    border = footprint is not None and border_touched(
        border_pts, footprint, np.ascontiguousarray(ctx.border_scan.viewpoint_xyz_m, dtype=np.float64),
        float(cfg.border_margin_rad))
    common = {"touches_border": bool(border), "extent_m": tuple(float(e) for e in extent)}
    nan = float("nan")
    why = plausibility_rejection(extent, border, max_plausible_m, cfg)
    if why:
        return ClusterOutcome(k, cluster.n_points, UNKNOWN_LABEL, "", nan, nan, None, why, **common)
    t0 = time.perf_counter()
    desc = describe(rec, cluster, cluster_seed)
    if isinstance(desc, str):
        return ClusterOutcome(k, cluster.n_points, UNKNOWN_LABEL, "", nan, nan, None, desc, **common)
    t1 = time.perf_counter()
    found, label, view_index, why = match(rec, desc)
    t2 = time.perf_counter()
    timings["descriptors"] += (t1 - t0) * 1e3
    timings["matching"] += (t2 - t1) * 1e3
    too_big = "" if why else size_rejection(rec, label, extent)
    if why or (too_big and not cfg.verify_next_classes):
        return ClusterOutcome(k, cluster.n_points, UNKNOWN_LABEL, found.nearest_label, found.distance,
                              found.threshold, None, why or too_big, **common)
    hyp = Hypothesis(_input_indices(seg, k), cluster, label, view_index, found, bool(border))
    # too big for the nearest class: the next classes are tried as after a failed verification
    det, failed = (None, too_big.removeprefix("rejected: ")) if too_big else \
        _pose_and_verify(rec, ctx, seg, hyp, cluster_seed, timings)
    tried = []
    if failed and cfg.verify_next_classes:
        for alt in next_classes(rec, found, label, extent):
            tried.append(f"{hyp.label}: {failed}")
            hyp = Hypothesis(hyp.raw_idx, cluster, alt.label, alt.view_index, alt, bool(border))
            det, failed = _pose_and_verify(rec, ctx, seg, hyp, cluster_seed, timings)
            if not failed:
                break
    if failed:
        others = "".join(f"; then as {t}" for t in tried[1:] + [f"{hyp.label}: {failed}"]) if tried else ""
        first = tried[0].split(": ", 1)[1] if tried else failed
        return ClusterOutcome(k, cluster.n_points, UNKNOWN_LABEL, found.nearest_label, found.distance, found.threshold,
                              None, f"rejected: {first}{others}", **common)
    reason = "detected" if det.reliable else "detected (unreliable pose)"
    if tried:
        reason += f", as the next class ({'; '.join(tried)})"
    if border:
        reason += ", touches the scan border"
    return ClusterOutcome(k, cluster.n_points, hyp.label, found.nearest_label, hyp.match.distance,
                          hyp.match.threshold, det, reason, **common)


def _pose_and_verify(rec: Any, ctx: ScanContext, seg: SegmentationResult, hyp: Hypothesis, seed: int,
                     timings: dict) -> tuple[Detection, str]:
    """The detection of ``hyp`` and why it fails verification (``""``: it passes)."""
    cfg = rec.config
    det = pose_hypothesis(rec, ctx, seg, hyp, seed=seed, timings=timings)
    return det, verification_failure(det, cfg.verify_min_fitness, cfg.verify_max_visibility,
                                     cfg.verify_max_plane_penetration_m)


def next_classes(rec: Any, found: Any, label: str, extent_m: np.ndarray) -> list[Any]:
    """The classes a cluster is tried as when class ``label``'s pose fails verification
    (``PipelineConfig.verify_next_classes``): the nearest views of the other classes the rejection accepts and
    whose size test the cluster passes, nearest first, at most ``verify_next_classes`` of them."""
    alts = [m for m in rec.recognizer.other_classes(found.descriptors, label)
            if not size_rejection(rec, m.label, extent_m)]
    return alts[:rec.config.verify_next_classes]


def recognize_clusters(rec: Any, ctx: ScanContext, seg: SegmentationResult,
                       timings: dict) -> tuple[list[ClusterOutcome], list[Detection]]:
    """Every cluster of ``seg`` through the stages: their outcomes (in cluster order) and the detections."""
    footprint = scan_footprint(ctx.border_scan, rec.config)
    max_plausible = rec.max_plausible_extent_m()
    outcomes = [_recognize_cluster(rec, ctx, seg, k, footprint, max_plausible, timings)
                for k in range(len(seg.clusters))]
    return outcomes, [o.detection for o in outcomes if o.detection is not None]
