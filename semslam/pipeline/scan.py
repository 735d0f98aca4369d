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

:meth:`ScanRecognizer.recognize` is a sequence of stages, each a function of what it reads:

1. :func:`~.scan_records.scan_context`: the arguments checked, the scan's seeds drawn (a ``ScanContext``);
2. :func:`~.stages.segment`: planes removed, clusters;
3. :func:`~.stages.recognize_clusters`, per cluster: plausibility (too big for any class, cut by the border)
   -> describe -> match (nearest view, unknown rejection, size of the class) -> pose
   (:func:`~.hypothesis.pose_hypothesis`) -> verify (:func:`~.hypothesis.verification_failure`);
4. the opt-in stages on what is left unknown: :func:`~.attached.find_attached` (objects attached to structure),
   :func:`~.parts.merge_parts` (objects in several clusters), then :func:`~.fragments.absorb_fragments` (pieces
   of an object recognised in the scan, ``PartsConfig.fragments``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..cloud import PointCloud
from ..detection import Detection
from ..errors import InputError, RecognitionError
from ..recognition import Recognizer, SvmClassifier, ViewDatabase, chi2_distances, combine_descriptors
from ..pose.estimate import PoseModel, estimate_object_pose, prepare_pose_model
from ..pose.model import SurfacePoints
from ..segmentation.scene import SegmentationResult
from .attached import find_attached
from .class_measures import class_size_limit_m, median_view_area_m2
from .config import PipelineConfig
from .fragments import absorb_fragments
from .parts import merge_parts
from .scan_records import ClusterOutcome, scan_context
from .stages import recognize_clusters, segment

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
    context : ScanContext or None
        The scan's inputs as recognised (the frame its clusters are in), kept (``recognize(keep_context=True)``)
        while a runner may still track its border-cut clusters from the scan after
        (:func:`~semslam.pipeline.dataset_detection.track_from_scan_after`); None once its result is final, or not
        kept. Not part of :meth:`to_dict`.
    """

    detections: list[Detection]
    clusters: list[ClusterOutcome]
    segmentation: SegmentationResult
    timings_ms: dict[str, float]
    context: Any = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict:
        return {"detections": [d.to_dict() for d in self.detections],
                "clusters": [c.to_dict() for c in self.clusters],
                "segmentation": self.segmentation.to_dict(),
                "timings_ms": dict(self.timings_ms)}


class ScanRecognizer:
    """Recognise and localise database objects in scans, one scan at a time.

    One recognizer may recognise several scans at once in threads: what belongs to one scan (its up direction,
    stamps, seeds) is passed from stage to stage (:class:`~semslam.pipeline.scan_records.ScanContext`), and the
    recognizer keeps only what does not depend on the scan (the classifier, and caches of the pose models and the
    per-class measures, filled on first use).

    The stages (:mod:`semslam.pipeline.stages`, :mod:`.hypothesis`, :mod:`.parts`, :mod:`.attached`) use its
    ``config``, ``db`` and the methods :meth:`pose_model`, :meth:`classify`, :meth:`class_size_limit_m`,
    :meth:`max_plausible_extent_m` and :meth:`class_view_area_m2`.

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
            raise RecognitionError(f"The 'db' argument of ScanRecognizer must be a ViewDatabase. "
                                   f"Got {type(db).__name__} instead.")
        self.db = db
        self.config = PipelineConfig() if config is None else config
        if not isinstance(self.config, PipelineConfig):
            raise InputError(f"The 'config' argument of ScanRecognizer must be a PipelineConfig. "
                             f"Got {type(config).__name__} instead.")
        cfg = self.config
        self.recognizer = Recognizer(db, descriptor=cfg.descriptor, rejection=cfg.rejection,
                                     reject_quantile=cfg.reject_quantile, reject_margin=cfg.reject_margin)
        self.svm: SvmClassifier | None = None
        if cfg.classifier == "svm":
            self.svm = SvmClassifier(seed=seed).fit(db.features(cfg.descriptor), db.labels)
        self._features = db.features(cfg.descriptor)
        # caches filled on first use; a value computed twice by two threads is the same, the first one stays
        self._pose_models: dict[Any, PoseModel | SurfacePoints] = {}
        self._size_limits: dict[str, float] = {}
        self._view_areas: dict[tuple[str, float], float] = {}

    # -- what the stages use: prepared once, cached --------------------------------------------------
    def pose_model(self, label: str, view_index: int) -> PoseModel:
        """The prepared model that clusters of ``label`` are aligned to (cached)."""
        if self.config.pose_model == "fused":
            key: Any = label
            model = self._pose_models.get(key)
            if model is None:
                model = self._pose_models.setdefault(key, prepare_pose_model(self.db.pose_views(label),
                                                                             self.config.pose))
        else:
            key = int(view_index)
            model = self._pose_models.get(key)
            if model is None:
                model = self._pose_models.setdefault(key, prepare_pose_model(self.db.view_cloud(key),
                                                                             self.config.pose))
        return model

    def surface_model(self, label: str, view_index: int) -> SurfacePoints:
        """The surface the part and fragment tests look for a cluster's points on (cached): with the fused pose model,
        the class's pose-model views and its recognition views together, so a surface only the recognition views
        reach (the bottom of a deep bore, seen by the survey's steep looks) is on it; else :meth:`pose_model`'s."""
        fused = self.config.pose_model == "fused"
        key = ("surface", label, None if fused else int(view_index))
        model = self._pose_models.get(key)
        if model is None:
            if fused and np.any(self.db.model_labels == label):
                views = self.db.pose_views(label) + [self.db.view_cloud(int(i)) for i in self.db.views_of(label)]
                model = SurfacePoints.of_views(views, self.config.pose)
            else:
                model = SurfacePoints.of_pose_model(self.pose_model(label, view_index))
            model = self._pose_models.setdefault(key, model)
        return model

    def classify(self, desc: Any) -> tuple[Any, str, int]:
        """The nearest-view match of a cluster's descriptors, and its label and view (the SVM's, when it is used)."""
        match = self.recognizer.match_descriptors(desc)
        label, view_index = match.label, match.view_index
        if self.svm is not None and match.accepted:
            x = combine_descriptors(self.config.descriptor, desc.esf, desc.vfh)
            label = str(self.svm.predict(x)[0])
            view_index = self._nearest_view_of(label, x)
        return match, label, view_index

    def class_size_limit_m(self, label: str) -> float:
        """The size test's limit for class ``label`` (:func:`~semslam.pipeline.class_measures.class_size_limit_m`,
        cached)."""
        limit = self._size_limits.get(label)
        if limit is None:
            limit = self._size_limits.setdefault(label, class_size_limit_m(self.db, self.config, label))
        return limit

    def max_plausible_extent_m(self) -> float:
        """Largest cluster extent any class may have (size test off: infinity)."""
        if self.config.size_tolerance is None:
            return float("inf")
        return max(self.class_size_limit_m(c) for c in self.db.classes)

    def class_view_area_m2(self, label: str, leaf_m: float) -> float:
        """Median surface of the views of class ``label`` on a ``leaf_m`` grid
        (:func:`~semslam.pipeline.class_measures.median_view_area_m2`, cached)."""
        key = (label, round(leaf_m, 12))
        area = self._view_areas.get(key)
        if area is None:
            area = self._view_areas.setdefault(key, median_view_area_m2(self.db, label, leaf_m))
        return area

    def _nearest_view_of(self, label: str, x: np.ndarray) -> int:
        """The view of class ``label`` nearest (chi-square) to the descriptor row ``x``."""
        views = self.db.views_of(label)
        d = chi2_distances(x, self._features[views])[0]
        return int(views[int(np.argmin(d))])

    def warm_up(self) -> None:
        """Prepare every class's pose model now, recognise one database view and estimate the pose of one
        view of every class (it loads the segmentation, descriptor, search and ICP kernels: ~50 ms), so that
        the first scans are not slower than the others (benchmarks/latency.py). No result changes."""
        from .._signals import critical

        with critical():  # numba loads its cached kernels here: a Ctrl-C waits for the end (semslam._signals)
            self._warm_up()

    def _warm_up(self) -> None:
        from ..errors import SemslamError

        parts, tolerance = self.config.parts, self.config.segmentation.cluster_tolerance_m
        for label in self.db.classes:
            first = int(self.db.views_of(label)[0])
            model = self.pose_model(label, first)
            if self.config.verify_max_plane_penetration_m is not None and self.config.estimate_pose:
                model.hull_points  # noqa: B018 (the floor check's hull, built once: 0.1-0.3 s on a large model)
            if parts is not None:  # the part and fragment tests' model
                self.surface_model(label, first)
        if parts is not None and parts.view_gaps and not isinstance(tolerance, str):  # gaps learnt from the views
            from .parts import _gap_limits

            _gap_limits(self, float(tolerance))
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

    # -- one scan ---------------------------------------------------------------------------------
    def recognize(self, scan: PointCloud, *, seed: int | np.random.Generator = 0, stamp_s: float = float("nan"),
                  scan_id: int = -1, point_stamps_s: Any = None, up_scanner: Any = None,
                  measured: PointCloud | None = None, priors: Any = None,
                  keep_context: bool = False) -> RecognitionResult:
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
            :func:`semslam.pipeline.dataset_detection.up_in_scanner`), instead of ``PipelineConfig.up_scanner``.
        measured : PointCloud, optional
            The scan as measured when ``scan`` is its deskewed copy (:mod:`semslam.pipeline.deskew`): the border
            test reads the directions the scanner measured.
        priors : sequence of TrackPrior, or a callable returning one, optional
            The objects of the scan before, predicted in this scan's frame
            (:func:`~semslam.pipeline.tracking.predicted_priors`): with ``PipelineConfig.track_border_cut_m`` the
            border-cut clusters rejected alone, or recognised alone as another class, are tried as them
            (:mod:`semslam.pipeline.tracking`). A callable is
            called once this scan's own stages are done (a runner recognising scans at once waits there for the
            scan before).
        keep_context : bool
            Keep the scan's context in the result (``RecognitionResult.context``: the scan's clouds) for tracking
            from the scan after (a runner's; it drops it once the result is final).
        """
        cfg = self.config
        ctx = scan_context(scan, default_up_scanner=cfg.up_scanner, seed=seed, stamp_s=stamp_s, scan_id=scan_id,
                           point_stamps_s=point_stamps_s, up_scanner=up_scanner, measured=measured)
        t_start = time.perf_counter()
        seg = segment(ctx, cfg)
        timings = {"segmentation": (time.perf_counter() - t_start) * 1e3, "descriptors": 0.0, "matching": 0.0,
                   "pose": 0.0}
        outcomes, detections = recognize_clusters(self, ctx, seg, timings)
        if cfg.attached is not None:  # objects inside clusters too big for them (attached to structure)
            outcomes, detections = find_attached(self, ctx, seg, outcomes, detections, seed=ctx.cluster_seed + 7919,
                                                 timings=timings)
        if cfg.parts is not None:  # unknown clusters near each other tried as one object
            outcomes, detections = merge_parts(self, ctx, seg, outcomes, detections,
                                               seed=ctx.cluster_seed + len(seg.clusters), timings=timings)
            if cfg.parts.fragments:  # pieces of an object recognised in this scan
                outcomes = absorb_fragments(self, ctx, seg, outcomes, detections, timings=timings)
        if cfg.track_border_cut_m is not None and priors is not None:
            from .tracking import track_rejected

            t_wait = time.perf_counter()
            given = priors() if callable(priors) else priors
            t_start += time.perf_counter() - t_wait  # the wait for the scan before is not this scan's time
            outcomes, detections = track_rejected(self, ctx, seg, outcomes, detections, given, timings)
        timings["total"] = (time.perf_counter() - t_start) * 1e3
        return RecognitionResult(detections, outcomes, seg, timings, context=ctx if keep_context else None)


def recognize_scan(scan: PointCloud, db: ViewDatabase, config: PipelineConfig | None = None, *,
                   seed: int | np.random.Generator = 0, **kwargs: Any) -> RecognitionResult:
    """One-shot convenience: build a :class:`ScanRecognizer` and run it on one scan.

    For many scans, build the recognizer once and call :meth:`ScanRecognizer.recognize` per scan.
    """
    return ScanRecognizer(db, config).recognize(scan, seed=seed, **kwargs)
