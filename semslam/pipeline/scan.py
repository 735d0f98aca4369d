"""The scan-to-detections pipeline (both papers): plane removal and clustering, a global descriptor per
cluster, matching against the view database with unknown rejection, and the 6-DoF pose of every recognised
object with its covariance.

>>> from semslam.pipeline import ScanRecognizer
>>> from semslam.recognition import load_database
>>> recognizer = ScanRecognizer(load_database("objects.npz"))          # doctest: +SKIP
>>> result = recognizer.recognize(scan)                                # doctest: +SKIP
>>> [(d.label, d.T_sensor_object.translation_m) for d in result.detections]  # doctest: +SKIP

Everything expensive that does not depend on the scan (classifier fitting, rejection thresholds, the pose
models of each class) is prepared once, in the constructor or lazily on first use, and reused for every scan.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validation import as_float_array, as_rng
from ..cloud import PointCloud
from ..detection import Detection
from ..errors import DescriptorError, InputError, RecognitionError
from ..recognition import (
    UNKNOWN_LABEL,
    Recognizer,
    SvmClassifier,
    ViewDatabase,
    chi2_distances,
    combine_descriptors,
)
from ..recognition.plausibility import border_touched, principal_extent
from ..pose.estimate import PoseModel, estimate_object_pose, prepare_pose_model
from ..segmentation.scene import SegmentationResult, segment_scene
from .attached import find_attached
from .config import PipelineConfig
from .parts import merge_parts
from ._scan_helpers import (
    ClusterOutcome,
    _class_size_limit_m,
    _detect_cluster,
    _input_indices,
    _scan_angular_extent,
    _valid_points,
    _verification_failure,
)

__all__ = ["ClusterOutcome", "PipelineConfig", "RecognitionResult", "ScanRecognizer", "recognize_scan"]

@dataclass(frozen=True, eq=False)
class RecognitionResult:
    """Output of :meth:`ScanRecognizer.recognize`.

    Attributes
    ----------
    detections : list of Detection
        Recognised objects with ``T_sensor_object`` in the scan's frame, covariance, fitness, RMSE.
    clusters : list of ClusterOutcome
        Every cluster, recognised or not, and why.
    segmentation : SegmentationResult
    timings_ms : dict
        Wall time per stage summed over clusters: ``segmentation``, ``descriptors``, ``matching``, ``pose``,
        ``total`` (milliseconds); ``parts`` with ``PipelineConfig.parts`` (its unions' poses count in ``pose`` too).
    """

    detections: list[Detection]
    clusters: list[ClusterOutcome]
    segmentation: SegmentationResult
    timings_ms: dict[str, float]

    def to_dict(self) -> dict:
        return {"detections": [d.to_dict() for d in self.detections],
                "clusters": [c.to_dict() for c in self.clusters],
                "segmentation": self.segmentation.to_dict(),
                "timings_ms": dict(self.timings_ms)}


class ScanRecognizer:
    """Recognise and localise database objects in scans, one scan at a time.

    Parameters
    ----------
    db : ViewDatabase
        Partial views of the known objects in their canonical frames, with ESF and VFH.
    config : PipelineConfig, optional
    seed : int, optional
        Seeds the SVM's cross-validation when ``classifier="svm"``.
    """

    def __init__(self, db: ViewDatabase, config: PipelineConfig | None = None, *, seed: int = 0) -> None:
        if not isinstance(db, ViewDatabase):
            raise RecognitionError(f"The 'db' argument of ScanRecognizer must be a ViewDatabase. Got {type(db).__name__} instead.")
        self.db = db
        self.config = PipelineConfig() if config is None else config
        if not isinstance(self.config, PipelineConfig):
            raise InputError(f"The 'config' argument of ScanRecognizer must be a PipelineConfig. "
                             f"Got {type(config).__name__} instead.")
        cfg = self.config
        # the up of the scan being recognised (recognize's up_scanner): per call, so one recognizer must not
        # recognise two scans at once in threads (processes, as the batch engine uses, are fine)
        self._up_scanner = cfg.up_scanner
        self.recognizer = Recognizer(db, descriptor=cfg.descriptor, rejection=cfg.rejection,
                                     reject_quantile=cfg.reject_quantile, reject_margin=cfg.reject_margin)
        self.svm: SvmClassifier | None = None
        if cfg.classifier == "svm":
            self.svm = SvmClassifier(seed=seed).fit(db.features(cfg.descriptor), db.labels)
        self._features = db.features(cfg.descriptor)
        self._pose_models: dict[Any, PoseModel] = {}
        self._size_limits: dict[str, float] = {}

    # -- pose models, prepared once -----------------------------------------------------------------
    def pose_model(self, label: str, view_index: int) -> PoseModel:
        """The prepared model that clusters of ``label`` are aligned to (cached)."""
        if self.config.pose_model == "fused":
            key: Any = label
            if key not in self._pose_models:
                self._pose_models[key] = prepare_pose_model(self.db.pose_views(label), self.config.pose)
        else:
            key = int(view_index)
            if key not in self._pose_models:
                self._pose_models[key] = prepare_pose_model(self.db.view_cloud(key), self.config.pose)
        return self._pose_models[key]

    def _max_plausible_extent_m(self) -> float:
        """Largest cluster extent any class may have (size test off: infinity)."""
        cfg = self.config
        if cfg.size_tolerance is None:
            return float("inf")
        return max(_class_size_limit_m(self, c) for c in self.db.classes)

    def warm_up(self) -> None:
        """Prepare every class's pose model now, recognise one database view and estimate the pose of one
        view of every class (it loads the segmentation, descriptor, search and ICP kernels: ~50 ms), so that
        the first scans are not slower than the others (benchmarks/latency.py). No result changes."""
        from ..errors import SemslamError

        for label in self.db.classes:
            first = int(self.db.views_of(label)[0])
            self.pose_model(label, first)
        if not self.config.estimate_pose:
            return
        for i, label in enumerate(self.db.classes):  # every class: the symmetry kinds take different paths
            first = int(self.db.views_of(label)[0])
            view = self.db.view_cloud(first)
            try:  # a view is a valid cluster; any failure only means the kernels load on the first scan
                if i == 0:
                    self.recognize(view, seed=0)  # segmentation, border and plausibility kernels
                    self.recognizer.match_descriptors(self.db.describe(view, seed=0))
                estimate_object_pose(view.points_xyz_m, self.pose_model(label, first),
                                     symmetry=self.db.class_info(label).symmetry, config=self.config.pose, seed=0,
                                     viewpoint_xyz_m=view.viewpoint_xyz_m)
            except SemslamError:
                pass

    def _nearest_view_of(self, label: str, x: np.ndarray) -> int:
        """The view of class ``label`` nearest (chi-square) to the descriptor row ``x``."""
        views = self.db.views_of(label)
        d = chi2_distances(x, self._features[views])[0]
        return int(views[int(np.argmin(d))])

    # -- one scan ---------------------------------------------------------------------------------
    def recognize(self, scan: PointCloud, *, seed: int | np.random.Generator = 0, stamp_s: float = float("nan"),
                  scan_id: int = -1, point_stamps_s: Any = None, up_scanner: Any = None) -> RecognitionResult:
        """Segment ``scan``, recognise each cluster and estimate the pose of the recognised ones.

        Parameters
        ----------
        scan : PointCloud
            The scan in the sensor (scanner) frame; ``viewpoint_xyz_m`` is the sensor origin.
        seed : int or Generator
            Randomness of RMSAC, ESF sampling and coarse alignment: the same seed gives the same result.
        stamp_s : float
            Stamp given to every detection (e.g. the scan's end), unless ``point_stamps_s`` is given.
        scan_id : int
            Copied into every detection.
        point_stamps_s : array of shape (N,), optional
            Acquisition time of every scan point (a line scanner takes each line at its own time); a
            detection is then stamped with the median time of its cluster's points.
        up_scanner : (3,), optional
            The up direction in this scan's frame (a vehicle's attitude at the scan:
            :func:`semslam.pipeline.mission.up_in_scanner`), instead of ``PipelineConfig.up_scanner``.
        """
        if not isinstance(scan, PointCloud):
            raise InputError(f"The 'scan' argument of ScanRecognizer.recognize must be a PointCloud. "
                             f"Got {type(scan).__name__} instead.")
        self._up_scanner = self.config.up_scanner
        if up_scanner is not None:
            up = as_float_array("up_scanner", up_scanner, (3,), caller="ScanRecognizer.recognize")
            if not np.abs(up).max() > 0:
                raise InputError(f"The 'up_scanner' argument of ScanRecognizer.recognize must be a non-zero 3-vector. "
                                 f"Got {up.tolist()} instead.")
            self._up_scanner = tuple(float(v) for v in up / np.abs(up).max())
        stamps = None
        if point_stamps_s is not None:
            stamps = as_float_array("point_stamps_s", point_stamps_s, (scan.n_points,), caller="ScanRecognizer.recognize")
        rng = as_rng(seed, caller="ScanRecognizer.recognize")
        seeds = rng.integers(0, 2**31 - 1, size=2)
        cfg = self.config
        t_start = time.perf_counter()
        seg = segment_scene(scan, cfg.segmentation, seed=int(seeds[0]))
        timings = {"segmentation": (time.perf_counter() - t_start) * 1e3, "descriptors": 0.0, "matching": 0.0,
                   "pose": 0.0}
        outcomes: list[ClusterOutcome] = []
        detections: list[Detection] = []
        scan_extent = (_scan_angular_extent(_valid_points(scan, cfg.segmentation.drop_origin), scan.viewpoint_xyz_m)
                       if cfg.border != "keep" else None)
        max_plausible = self._max_plausible_extent_m()
        viewpoint = np.ascontiguousarray(scan.viewpoint_xyz_m, dtype=np.float64)
        for k, cluster in enumerate(seg.clusters):
            cluster_seed = int(seeds[1]) + k
            # The clusters' points are checked PointCloud arrays: the kernels take them as they are.
            extent = principal_extent(cluster.points_xyz_m)
            border = scan_extent is not None and border_touched(
                cluster.points_xyz_m, scan_extent, viewpoint, float(cfg.border_margin_rad))
            common = {"touches_border": bool(border), "extent_m": tuple(float(e) for e in extent)}
            if extent[0] > max_plausible:
                outcomes.append(ClusterOutcome(k, cluster.n_points, UNKNOWN_LABEL, "", float("nan"), float("nan"), None,
                                               f"rejected: extent {extent[0]:.3f} m > {max_plausible:.3f} m, too big "
                                               f"for any class", **common))
                continue
            if border and cfg.border == "reject":
                outcomes.append(ClusterOutcome(k, cluster.n_points, UNKNOWN_LABEL, "", float("nan"), float("nan"), None,
                                               "rejected: touches the scan border (partial object)", **common))
                continue
            t0 = time.perf_counter()
            try:
                desc = self.db.describe(cluster, seed=cluster_seed)
            except DescriptorError as exc:  # a sparse cluster (points farther apart than the normal radius)
                outcomes.append(ClusterOutcome(k, cluster.n_points, UNKNOWN_LABEL, "", float("nan"), float("nan"), None,
                                               f"rejected: no descriptor ({exc})", **common))
                continue
            t1 = time.perf_counter()
            match, label, view_index = self._classify(desc)
            t2 = time.perf_counter()
            timings["descriptors"] += (t1 - t0) * 1e3
            timings["matching"] += (t2 - t1) * 1e3
            if label == UNKNOWN_LABEL:
                outcomes.append(ClusterOutcome(k, cluster.n_points, label, match.nearest_label, match.distance,
                                               match.threshold, None,
                                               f"rejected: distance {match.distance:.4g} > threshold {match.threshold:.4g}",
                                               **common))
                continue
            if cfg.size_tolerance is not None:
                limit = _class_size_limit_m(self, label)
                if extent[0] > limit:
                    outcomes.append(ClusterOutcome(k, cluster.n_points, UNKNOWN_LABEL, match.nearest_label,
                                                   match.distance, match.threshold, None,
                                                   f"rejected: extent {extent[0]:.3f} m > {limit:.3f} m, too big for "
                                                   f"{label}", **common))
                    continue
            raw_idx = _input_indices(seg, k)
            det_stamp = float(np.median(stamps[raw_idx])) if stamps is not None and len(raw_idx) else stamp_s
            det = self._detect(scan, raw_idx, cluster, label, view_index, match, det_stamp, scan_id, cluster_seed,
                               timings, border, seg=seg)
            failed = _verification_failure(det, cfg.verify_min_fitness, cfg.verify_max_visibility)
            if failed:
                outcomes.append(ClusterOutcome(k, cluster.n_points, UNKNOWN_LABEL, match.nearest_label, match.distance,
                                               match.threshold, None, f"rejected: {failed}", **common))
                continue
            detections.append(det)
            reason = "detected" if det.reliable else "detected (unreliable pose)"
            if border:
                reason += ", touches the scan border"
            outcomes.append(ClusterOutcome(k, cluster.n_points, label, match.nearest_label, match.distance,
                                           match.threshold, det, reason, **common))
        if cfg.attached is not None:  # objects inside clusters too big for them (attached to structure)
            find_attached(self, scan, seg, outcomes, detections, seed=int(seeds[1]) + 7919, stamps=stamps,
                          stamp_s=stamp_s, scan_id=scan_id, timings=timings)
        if cfg.parts is not None:  # unknown clusters near each other tried as one object
            merge_parts(self, scan, seg, outcomes, detections, seed=int(seeds[1]) + len(seg.clusters), stamps=stamps,
                        stamp_s=stamp_s, scan_id=scan_id, timings=timings)
        timings["total"] = (time.perf_counter() - t_start) * 1e3
        return RecognitionResult(detections, outcomes, seg, timings)

    def _classify(self, desc: Any) -> tuple[Any, str, int]:
        """The nearest-view match of a cluster's descriptors, and its label and view (the SVM's, when it is used)."""
        match = self.recognizer.match_descriptors(desc)
        label, view_index = match.label, match.view_index
        if self.svm is not None and match.accepted:
            x = combine_descriptors(self.config.descriptor, desc.esf, desc.vfh)
            label = str(self.svm.predict(x)[0])
            view_index = self._nearest_view_of(label, x)
        return match, label, view_index

    def _detect(self, scan: PointCloud, raw_idx: np.ndarray, cluster: PointCloud, label: str, view_index: int,
                match: Any, stamp_s: float, scan_id: int, seed: int, timings: dict,
                touches_border: bool = False, seg: SegmentationResult | None = None) -> Detection:
        return _detect_cluster(self, scan, raw_idx, cluster, label, view_index, match, stamp_s, scan_id, seed, timings,
                               touches_border, seg=seg)


def recognize_scan(scan: PointCloud, db: ViewDatabase, config: PipelineConfig | None = None, *,
                   seed: int | np.random.Generator = 0, **kwargs: Any) -> RecognitionResult:
    """One-shot convenience: build a :class:`ScanRecognizer` and run it on one scan.

    For many scans, build the recognizer once and call :meth:`ScanRecognizer.recognize` per scan.
    """
    return ScanRecognizer(db, config).recognize(scan, seed=seed, **kwargs)
