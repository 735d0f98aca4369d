"""The one loop over a dataset's scans: every scan through a :class:`~semslam.pipeline.scan.ScanRecognizer`,
each detection stamped with its own points' acquisition time, the detections kept for SLAM as
``{scan_id: [Detection]}`` (the form :func:`semslam.run.run_slam` and ``detections.jsonl`` take).

Scoring against ground truth is a separate pass (``on_scan`` receives every scan's cloud and result).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .._progress import Progress, progress_steps
from ..dataset import Dataset, ScanRecord
from ..detection import Detection
from ..errors import InputError
from .scan import RecognitionResult, ScanRecognizer

#: seed of scan ``k`` from the run's seed (every scan its own stream, independent of the others)
SCAN_SEED_STRIDE = 100003


def scan_seed(seed: int, scan_id: int) -> int:
    return int(seed) * SCAN_SEED_STRIDE + int(scan_id)


@dataclass
class DatasetDetections:
    """Detections of a whole dataset and per-scan statistics (``scans``: one dict per scan with ``scan_id``,
    ``stamp_s``, ``n_points``, ``n_clusters``, ``n_detections``, ``n_kept`` and the stage timings in ms)."""

    detections_by_scan: dict[int, list[Detection]] = field(default_factory=dict)
    scans: list[dict] = field(default_factory=list)

    @property
    def n_detections(self) -> int:
        return sum(len(v) for v in self.detections_by_scan.values())

    def summary(self) -> dict:
        return detection_summary(self.scans, self.n_detections)


def detection_summary(scans: list[dict], n_kept: int) -> dict:
    """Counts and scan latencies of per-scan statistics (:func:`detect_scan`'s)."""
    total = np.array([s["timings_ms"].get("total", np.nan) for s in scans]) if scans else np.zeros(0)
    return {
        "n_scans": len(scans),
        "n_clusters": int(sum(s["n_clusters"] for s in scans)),
        "n_detections": int(sum(s["n_detections"] for s in scans)),
        "n_kept": int(n_kept),
        "n_tracked": int(sum(s.get("n_tracked", 0) for s in scans)),  # from the scan before (pipeline.tracking)
        "scan_latency_ms_median": float(np.median(total)) if total.size else float("nan"),
        "scan_latency_ms_p90": float(np.percentile(total, 90)) if total.size else float("nan"),
    }


#: an attitude sample farther than this from a scan's middle does not give that scan an up direction
MAX_ATTITUDE_GAP_S = 1.0


def up_in_scanner(dataset: Dataset, stamp_s: float) -> np.ndarray | None:
    """The world's up (NED: ``(0, 0, -1)``) in the scanner frame at ``stamp_s``, from the attitude log (roll and pitch
    interpolated; yaw does not move up) and the scanner's mounting: ``(R_world_vehicle R_vehicle_scanner)^T
    (0, 0, -1)``. None when no attitude sample lies within :data:`MAX_ATTITUDE_GAP_S` of ``stamp_s``."""
    return up_from_attitude_samples(dataset.attitude.stamp_s, dataset.attitude.rpy_rad,
                                    dataset.vehicle.scanner.T_vehicle_scanner, stamp_s)


def up_from_attitude_samples(stamps_s: np.ndarray, rpy_rad: np.ndarray, T_vehicle_scanner, stamp_s: float):
    """:func:`up_in_scanner` from attitude samples (a streaming runner's recent history)."""
    from ..geometry import rotation_from_rpy

    t = np.asarray(stamps_s, dtype=float)
    if not len(t) or np.min(np.abs(t - stamp_s)) > MAX_ATTITUDE_GAP_S:
        return None
    rpy = np.asarray(rpy_rad, dtype=float).reshape(-1, 3)
    roll = np.interp(stamp_s, t, np.unwrap(rpy[:, 0]))
    pitch = np.interp(stamp_s, t, np.unwrap(rpy[:, 1]))
    R_wv = rotation_from_rpy(float(roll), float(pitch), 0.0)
    R_vs = np.asarray(T_vehicle_scanner.matrix, dtype=float)[:3, :3]
    return (R_wv @ R_vs).T @ np.array([0.0, 0.0, -1.0])


def detect_scan(recognizer: ScanRecognizer, cloud, *, scan_id: int, start_stamp_s: float, end_stamp_s: float,
                point_stamps_s, seed: int = 0, keep_unreliable: bool = False, up_scanner=None, motion=None,
                T_vehicle_scanner=None, priors=None):
    """One scan through the recogniser (seed ``scan_seed(seed, scan_id)``): ``(kept detections, statistics,
    result)``. The one step every runner takes per scan (:func:`detect_dataset`, :mod:`semslam.run`).

    With the vehicle's ``motion`` over the scan (:class:`~semslam.pipeline.deskew.ScanMotion`), ``point_stamps_s``
    and ``PipelineConfig.deskew`` on, the scan is deskewed to ``end_stamp_s`` first (``T_vehicle_scanner`` its
    mounting); each detection is then carried into the sensor frame at its own stamp (the median stamp of its points,
    as without deskewing), so that the motion's error enters only over its own points' time span (measured: 0.9 mm
    median position error with the true motion, 4.8 mm with the navigation's when posed at the scan's end).
    ``stats["deskewed"]`` says whether it was. ``priors``: the scan before's objects in this scan's frame, or a
    callable giving them (:meth:`ScanRecognizer.recognize`; :func:`priors_from_scan_before`)."""
    from .deskew import deskew_scan, deskews
    from .tracking import tracks

    deskewed = motion is not None and deskews(recognizer, point_stamps_s)
    measured = cloud if deskewed else None
    if deskewed:
        cloud = deskew_scan(cloud, point_stamps_s, motion, T_vehicle_scanner, end_stamp_s)
    kw = {"measured": measured} if deskewed else {}  # (a duck-typed recogniser need not know the keywords)
    if priors is not None:
        kw["priors"] = priors
    if tracks(recognizer):  # the scan after may still track its border-cut clusters (track_from_scan_after)
        kw["keep_context"] = True
    result = recognizer.recognize(cloud, seed=scan_seed(seed, scan_id), stamp_s=end_stamp_s, scan_id=scan_id,
                                  point_stamps_s=point_stamps_s, up_scanner=up_scanner, **kw)
    if deskewed:  # each detection from the scan's end to its own points' median stamp: the motion between cancels
        result = _at_own_stamps(result, motion, T_vehicle_scanner, end_stamp_s)
    kept = [d for d in result.detections if d.reliable or keep_unreliable]
    stats = {"scan_id": scan_id, "stamp_s": end_stamp_s, "n_points": cloud.n_points,
             "n_clusters": len(result.clusters), "n_detections": len(result.detections),
             "n_kept": len(kept), "n_tracked": sum("tracked_from_scan" in d.extras for d in result.detections),
             "deskewed": deskewed, "timings_ms": dict(result.timings_ms)}
    return kept, stats, result


def detect_dataset(dataset: Dataset, recognizer: ScanRecognizer, *, seed: int = 0, keep_unreliable: bool = False,
                   progress: Progress = False, up_from_attitude: bool = False,
                   on_scan: Callable[[ScanRecord, object, RecognitionResult], None] | None = None) -> DatasetDetections:
    """Recognise the objects of every scan of ``dataset``.

    Parameters
    ----------
    dataset : Dataset
    recognizer : ScanRecognizer
        Prepared once for the database (see :meth:`ScanRecognizer.warm_up`).
    seed : int
        Scan ``k`` is recognised with seed ``seed * 100003 + k``: the same seed gives the same detections.
    keep_unreliable : bool
        Keep detections whose pose is flagged unreliable (default: only reliable ones go to SLAM).
    progress : bool or callable
        A bar, or ``progress(done, total)`` after every scan (:mod:`semslam._progress`).
    up_from_attitude : bool
        Give every scan its own up direction from the vehicle's attitude at the scan's middle
        (:func:`up_in_scanner`), so classes whose database records their up (``db build --fuse --up``) are posed
        upright however the vehicle rolls and pitches (``PipelineConfig.up_scanner`` is fixed). A scan without an
        attitude sample within :data:`MAX_ATTITUDE_GAP_S` uses the configuration's.
    on_scan : callable, optional
        ``on_scan(record, cloud, result)`` after each scan (e.g. scoring against ground truth, figures).
    """
    if not isinstance(dataset, Dataset):
        raise InputError(
            f"The 'dataset' argument of detect_dataset must be a Dataset. Got {type(dataset).__name__} instead."
        )
    if not isinstance(recognizer, ScanRecognizer):
        raise InputError(f"The 'recognizer' argument of detect_dataset must be a ScanRecognizer. Got "
                         f"{type(recognizer).__name__} instead.")
    from .deskew import deskew_lookahead_s
    from .tracking import follows_closely

    out = DatasetDetections()
    scans = dataset.scans
    before = None  # the scan before: its record, cloud, detect_scan output and first stamp (tracking)

    def final(scan):  # a scan's output made final: kept, counted, handed to on_scan
        rec, cloud, (kept, stats, result), _ = scan
        if kept:
            out.detections_by_scan[rec.scan_id] = kept
        out.scans.append(stats)
        if on_scan is not None:
            on_scan(rec, cloud, result)

    with progress_steps(progress, len(scans), "recognise", "scan") as step:
        for rec in scans:
            cloud = dataset.load_scan(rec.scan_id)
            stamps = dataset.point_stamps_s(rec, cloud)
            up = up_in_scanner(dataset, 0.5 * (rec.start_stamp_s + rec.end_stamp_s)) if up_from_attitude else None
            link = _motion_since(dataset, recognizer, before, rec)
            motion = _scan_motion(dataset, stamps, rec.end_stamp_s, deskew_lookahead_s(recognizer))
            T_vs = dataset.vehicle.scanner.T_vehicle_scanner
            scan_out = detect_scan(recognizer, cloud, scan_id=rec.scan_id, start_stamp_s=rec.start_stamp_s,
                                   end_stamp_s=rec.end_stamp_s, point_stamps_s=stamps, seed=seed,
                                   keep_unreliable=keep_unreliable, up_scanner=up,
                                   motion=motion, T_vehicle_scanner=T_vs,
                                   priors=None if link is None else priors_from_scan_before(
                                       before[2][2].detections, link, T_vs, rec.end_stamp_s))
            if before is not None:  # the scan before, tracked from this one when it follows closely, is final
                brec = before[0]
                after = scan_out[2].detections if follows_closely(before[3], brec.start_stamp_s, brec.end_stamp_s,
                                                                  rec.end_stamp_s) else None
                final(before[:2] + (track_from_scan_after(recognizer, before[2], after, link, T_vs, keep_unreliable),
                                    None))
                step()
            before = (rec, cloud, scan_out, first_stamp_s(stamps, rec.start_stamp_s))
        if before is not None:
            final(before[:2] + (final_scan(before[2]), None))
            step()
    return out


def priors_from_scan_before(detections_before, motion, T_vehicle_scanner, end_stamp_s: float):
    """A callable giving the scan before's objects in the frame of a scan ending at ``end_stamp_s``
    (:func:`~semslam.pipeline.tracking.predicted_priors`): ``detections_before`` its detections (each at its own
    stamp), or a callable giving them (a runner's scan still in recognition); ``motion`` the vehicle's over a window
    from the scan before's first point to ``end_stamp_s`` (None: no navigation, no priors)."""
    from .tracking import predicted_priors

    def priors():
        dets = detections_before() if callable(detections_before) else detections_before
        return predicted_priors(dets, motion, T_vehicle_scanner, end_stamp_s)

    return priors


def track_from_scan_after(recognizer, scan_out, detections_after, motion, T_vehicle_scanner,
                          keep_unreliable: bool = False):
    """A scan's :func:`detect_scan` output ``scan_out`` made final with the objects of the scan after
    (``detections_after``, each at its own stamp), carried back into its frame by the vehicle's ``motion`` over a
    window holding both scans: its border-cut clusters rejected alone (an object entering the swath) are tried as
    them (:func:`~semslam.pipeline.tracking.track_rejected`; ``PipelineConfig.track_border_cut_m``). The result
    returned no longer holds its context (:func:`final_scan`). ``detections_after`` None or ``motion`` None: only
    made final."""
    from .tracking import predicted_priors, track_rejected, tracks

    kept, stats, result = scan_out
    ctx = getattr(result, "context", None)  # (a duck-typed recogniser's result need not have one)
    if ctx is None or motion is None or not detections_after or not tracks(recognizer):
        return final_scan(scan_out)
    priors = predicted_priors(detections_after, motion, T_vehicle_scanner, ctx.stamp_s)
    timings = {"descriptors": 0.0, "matching": 0.0, "pose": 0.0}
    clusters, dets = track_rejected(recognizer, ctx, result.segmentation, result.clusters, result.detections, priors,
                                    timings)
    before = {id(d) for d in result.detections}
    new = {id(d) for d in dets if id(d) not in before}
    if not new:
        return final_scan(scan_out)
    spent = dict(result.timings_ms)  # its stages' time, and the total, grow by the time spent tracking it
    for key, ms in dict(timings, total=timings["tracking"]).items():
        spent[key] = spent.get(key, 0.0) + ms
    from dataclasses import replace

    result = replace(result, detections=dets, clusters=clusters, timings_ms=spent, context=None)
    if stats.get("deskewed"):  # the new ones from the scan's end to their own stamps, as detect_scan does
        result = _at_own_stamps(result, motion, T_vehicle_scanner, ctx.stamp_s, only=new)
    kept = [d for d in result.detections if d.reliable or keep_unreliable]
    stats = dict(stats, n_detections=len(result.detections), n_kept=len(kept), timings_ms=dict(spent),
                 n_tracked=sum("tracked_from_scan" in d.extras for d in result.detections))
    return kept, stats, result


def final_scan(scan_out):
    """A :func:`detect_scan` output without its result's context (nothing more will be tracked in it)."""
    from dataclasses import replace

    kept, stats, result = scan_out
    return scan_out if getattr(result, "context", None) is None else (kept, stats, replace(result, context=None))


def first_stamp_s(point_stamps_s, start_stamp_s: float) -> float:
    """The stamp of a scan's first point (its start without per-point stamps)."""
    st = None if point_stamps_s is None else np.asarray(point_stamps_s, dtype=float)
    finite = st[np.isfinite(st)] if st is not None else np.zeros(0)
    return min(float(start_stamp_s), float(finite.min())) if len(finite) else float(start_stamp_s)


def _motion_since(dataset: Dataset, recognizer: ScanRecognizer, before, rec: ScanRecord):
    """The vehicle's motion from the scan before's first point (``before[3]``) to the end of scan ``rec``, from the
    dataset's attitude and DVL logs: what tracking carries objects between the two scans with (None when tracking
    is off or there is no scan before)."""
    from .deskew import deskew_lookahead_s, scan_motion
    from .tracking import tracks

    if before is None or not tracks(recognizer):
        return None
    a, d = dataset.attitude, dataset.dvl
    return scan_motion(a.stamp_s, a.rpy_rad, d.stamp_s, d.velocity_body_mps, d.valid,
                       dataset.vehicle.dvl.T_vehicle_dvl.rotation, before[3], rec.end_stamp_s,
                       lookahead_s=deskew_lookahead_s(recognizer))


def _scan_motion(dataset: Dataset, point_stamps_s, end_stamp_s: float, lookahead_s: float):
    """The vehicle's motion over a scan from the dataset's attitude and DVL logs (None without stamps), with no
    sample later than ``lookahead_s`` after its end (what a stream's runner waits for)."""
    from .deskew import scan_motion, scan_span

    span = scan_span(point_stamps_s, end_stamp_s)
    if span is None:
        return None
    a, d = dataset.attitude, dataset.dvl
    return scan_motion(a.stamp_s, a.rpy_rad, d.stamp_s, d.velocity_body_mps, d.valid,
                       dataset.vehicle.dvl.T_vehicle_dvl.rotation, *span, lookahead_s=lookahead_s)


def _at_own_stamps(result: RecognitionResult, motion, T_vehicle_scanner, ref_stamp_s: float,
                   only: set | None = None) -> RecognitionResult:
    """``result`` with every detection (posed in the sensor frame at ``ref_stamp_s``) carried to its own stamp (only
    those whose ``id`` is in ``only`` when given)."""
    from dataclasses import replace

    from ..geometry import RigidTransform
    from .deskew import reexpressed, sensor_motion_between

    moved = {}
    for d in result.detections:
        if only is not None and id(d) not in only:
            continue
        A = sensor_motion_between(motion, T_vehicle_scanner, ref_stamp_s, float(d.stamp_s))
        T, cov = reexpressed(A, np.asarray(d.T_sensor_object.matrix), d.covariance_6x6)
        moved[id(d)] = replace(d, T_sensor_object=RigidTransform(T), covariance_6x6=cov)
    clusters = [replace(c, detection=moved.get(id(c.detection), c.detection)) if c.detection is not None else c
                for c in result.clusters]
    return replace(result, detections=[moved.get(id(d), d) for d in result.detections], clusters=clusters)
