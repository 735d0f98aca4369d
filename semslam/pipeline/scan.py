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
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from .._validation import as_float_array, as_rng, check_choice, check_positive
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
from ..registration.pose import PoseConfig, PoseModel, estimate_object_pose, prepare_pose_model
from ..segmentation.scene import SegmentationConfig, SegmentationResult, segment_scene
from .attached import AttachedConfig, find_attached
from .parts import PartsConfig, merge_parts
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

CLASSIFIERS = ("chi2", "svm")
BORDER_POLICIES = ("reject", "flag", "keep")
POSE_MODELS = ("fused", "view")


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of the whole scan-to-detections pipeline.

    Attributes
    ----------
    segmentation : SegmentationConfig
        Voxel grid, plane removal and clustering (see :class:`~semslam.segmentation.scene.SegmentationConfig`).
    descriptor : {"esf", "vfh", "esf+vfh"}
        Global descriptor used for matching. Default ``"esf+vfh"``: on simulated laser missions (built-in
        database, ``benchmarks/recognition.py``) it separates the fittings from clutter best (precision
        97.7 %, recall 97 % of un-cut object clusters, against 98.4 % / 95.5 % for ESF alone with margin 8).
    classifier : {"chi2", "svm"}
        Chi-square nearest view (the papers' matcher) or the RBF SVM; unknown rejection always uses the
        chi-square distance to the nearest view, calibrated on the database.
    rejection : {"global", "per_class", "none"}
    reject_quantile, reject_margin : float
        Calibration of the rejection threshold (see :mod:`semslam.recognition.rejection`): threshold =
        ``reject_margin * quantile(LOO distances between database views, reject_quantile)``. The database
        views come from another sensor (a Kinect) than the queries (laser clusters after a 5 mm grid,
        noisier, seen from other angles), so laser clusters of known objects lie several times farther
        from their nearest view than views from each other: the default margin 6 keeps 97 % of them,
        while clutter is mostly rejected by the size test below.
    size_tolerance : float or None
        Size plausibility: a cluster whose largest principal extent exceeds ``size_tolerance`` times the
        matched class's longest dimension (see ``size_reference``) plus ``size_slack_m`` is rejected (floor and slope
        remains, rocks bigger than any fitting). Default 1.15; None disables the test.
    size_slack_m : float
        Default 0.01 m (two voxels: noise and floor points left around the object).
    size_reference : {"box", "principal"}
        The class's longest dimension for the size test: its bounding box's longest side (default), or the larger
        of that and the largest principal extent of its fused pose-model views (``"principal"``): clusters are
        measured along their principal axes, and an L-shaped part seen whole is longer that way than its box's
        longest side (the catalogue's butterfly valve: 0.299 m against 0.232 m; the box rule rejected 3 of its 8
        clusters). Not the default: on the built-in fittings it also lets more clutter through when nothing else
        checks it (``benchmarks/recognition.py --only missions``: clutter false accepts 3 -> 9 of 55).
    border : {"reject", "flag", "keep"}
        Clusters within ``border_margin_rad`` of the scan footprint's edge are cut objects (their
        descriptor is unreliable: 85 % correct against 100 % for whole ones): ``"reject"`` (default) lists
        them as unknown, ``"flag"`` recognises them and sets ``extras["touches_border"]`` (pose marked
        unreliable), ``"keep"`` ignores the test. The next scans see these objects whole.
    border_margin_rad : float
        Default 0.5 degree (~3 laser lines of the default scanner).
    pose_model : {"fused", "view"}
        Align to the class's pose-model views fused in its canonical frame (default;
        :meth:`~semslam.recognition.ViewDatabase.pose_views`: the database's pose-model views when it stores
        some, as the built-in one does, else its recognition views), or to the matched view only (the papers).
    pose : PoseConfig
        Coarse alignment, ICP, covariance and reliability thresholds.
    estimate_pose : bool
        False stops after recognition (detections then carry an identity pose and an infinite-like covariance).
    ambiguous_rotation_variance_rad2 : float
        Added to the rotation variances of a pose that aligns well but whose orientation is ambiguous (another,
        non-equivalent orientation scores within ``pose.min_score_margin``): 0.25 rad^2 (~29 degrees). Such a
        detection stays usable for its position (``extras["orientation_ambiguous"]``).
    up_scanner : (3,) or None
        The up direction in the scanner frame (a level camera with y down: ``(0, -1, 0)``; a vehicle: from its
        attitude). For the classes whose database records their up direction (``db build --fuse --up``), the
        pose search then keeps the object upright (:func:`~semslam.registration.estimate_object_pose`'s
        ``up_scanner``/``up_object``), which resolves the half-turn flips of near-symmetric objects;
        ``extras["pose_upright"]`` says whether it did. None (default): the search spans all of SO(3).
    verify_min_fitness, verify_max_visibility : float or None
        Hypothesis verification: a recognised cluster whose estimated pose puts the class's surface where the
        scan is not -- ICP fitness below ``verify_min_fitness``, or visibility (free-space) cost above
        ``verify_max_visibility`` -- is rejected as unknown ("rejected: pose verification ..."): a rock or a
        pipe offcut can be near a tee's or an elbow's view in descriptor space but does not fit its surface.
        Off (None) by default, so the built-in demo is unchanged; the 13-class catalogue benchmark
        (``benchmarks/catalogue.py --config catalogue``) uses 0.95 / 0.15 with ``border="flag"``: clutter false
        accepts 35 % -> 0 %, precision 47 % -> 99 % on the missions it was tuned on (held out: 40 % -> 5 %,
        37 % -> 82 %). The visibility cost counts occluded parts of the object as contradictions, so partly
        hidden objects are rejected too (benchmarks/RESULTS.md). Needs ``estimate_pose``.
    verify_visibility_image : {"cluster", "scene", "border"}
        What verification's visibility cost compares the model with: the cluster alone (default: every model
        point the cluster did not see is a contradiction, so an object hidden in part or cut by the scan's edge
        fails), or the whole scan about the cluster (``"scene"``: a model point behind another object is hidden, one
        where the scanner did not look is unknown, one in front of what the scanner saw -- free space -- or behind a
        plane contradicts); ``"border"``: the scene for the clusters cut by the scan border, the cluster for the
        others.
    parts : PartsConfig or None
        Part-based hypotheses (:mod:`semslam.pipeline.parts`): unknown clusters close to each other are tried as
        one object (a valve's handwheel seen apart from its body) and kept when the union is recognised, passes
        verification and every part fits the pose. Off (None) by default; needs ``verify_min_fitness``.
    attached : AttachedConfig or None
        Objects attached to structure (:mod:`semslam.pipeline.attached`): in the clusters rejected as too big or
        cut by the border, the structure (a pipe, a post) is removed primitive by primitive and the rest is
        recognised. Off (None) by default.
    """

    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    descriptor: str = "esf+vfh"
    classifier: str = "chi2"
    rejection: str = "global"
    reject_quantile: float = 0.95
    reject_margin: float = 6.0
    size_tolerance: float | None = 1.15
    size_slack_m: float = 0.01
    size_reference: str = "box"
    border: str = "reject"
    border_margin_rad: float = float(np.radians(0.5))
    pose_model: str = "fused"
    pose: PoseConfig = field(default_factory=PoseConfig)
    estimate_pose: bool = True
    ambiguous_rotation_variance_rad2: float = 0.25
    up_scanner: tuple | None = None
    verify_min_fitness: float | None = None
    verify_max_visibility: float | None = None
    verify_visibility_image: str = "cluster"
    parts: PartsConfig | None = None
    attached: AttachedConfig | None = None

    def __post_init__(self) -> None:
        c = "PipelineConfig"
        if self.verify_min_fitness is not None:
            check_positive("verify_min_fitness", self.verify_min_fitness, caller=c, allow_zero=True)
            if self.verify_min_fitness > 1:
                raise InputError(f"The 'verify_min_fitness' argument of {c} must be in [0, 1]. "
                                 f"Got {self.verify_min_fitness!r} instead.")
        if self.verify_max_visibility is not None:
            check_positive("verify_max_visibility", self.verify_max_visibility, caller=c, allow_zero=True)
        if not self.estimate_pose and (self.verify_min_fitness is not None or self.verify_max_visibility is not None):
            raise InputError(f"The 'verify_min_fitness' / 'verify_max_visibility' arguments of {c} need "
                             f"estimate_pose=True (they test the estimated pose). Got estimate_pose=False instead.")
        if self.parts is not None and (not isinstance(self.parts, PartsConfig) or self.verify_min_fitness is None):
            raise InputError(f"The 'parts' argument of {c} must be a PartsConfig, with verify_min_fitness set (a union "
                             f"is kept only if its pose verifies). Got parts={self.parts!r}, "
                             f"verify_min_fitness={self.verify_min_fitness!r} instead.")
        if self.attached is not None and not isinstance(self.attached, AttachedConfig):
            raise InputError(f"The 'attached' argument of {c} must be an AttachedConfig or None. "
                             f"Got {type(self.attached).__name__} instead.")
        if self.up_scanner is not None:
            from .._validation import as_float_array

            up = as_float_array("up_scanner", self.up_scanner, (3,), caller=c)
            if not np.linalg.norm(up) > 1e-9:
                raise InputError(f"The 'up_scanner' argument of {c} must be a non-zero 3-vector. Got {up.tolist()} instead.")
            object.__setattr__(self, "up_scanner", tuple(float(v) for v in up))
        check_positive("ambiguous_rotation_variance_rad2", self.ambiguous_rotation_variance_rad2, caller=c)
        check_choice("descriptor", self.descriptor, ("esf", "vfh", "esf+vfh"), caller=c)
        check_choice("classifier", self.classifier, CLASSIFIERS, caller=c)
        check_choice("rejection", self.rejection, ("global", "per_class", "none"), caller=c)
        check_choice("pose_model", self.pose_model, POSE_MODELS, caller=c)
        check_choice("border", self.border, BORDER_POLICIES, caller=c)
        check_choice("size_reference", self.size_reference, ("box", "principal"), caller=c)
        check_choice("verify_visibility_image", self.verify_visibility_image, ("cluster", "scene", "border"), caller=c)
        check_positive("reject_margin", self.reject_margin, caller=c)
        if self.size_tolerance is not None:
            check_positive("size_tolerance", self.size_tolerance, caller=c)
        check_positive("size_slack_m", self.size_slack_m, caller=c, allow_zero=True)
        check_positive("border_margin_rad", self.border_margin_rad, caller=c, allow_zero=True)
        if not isinstance(self.segmentation, SegmentationConfig):
            raise InputError(f"The 'segmentation' argument of {c} must be a SegmentationConfig. "
                             f"Got {type(self.segmentation).__name__} instead.")
        if not isinstance(self.pose, PoseConfig):
            raise InputError(f"The 'pose' argument of {c} must be a PoseConfig. Got {type(self.pose).__name__} instead.")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["segmentation"] = self.segmentation.to_dict()
        d["pose"] = self.pose.to_dict()
        d["parts"] = None if self.parts is None else self.parts.to_dict()
        d["attached"] = None if self.attached is None else self.attached.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: Any, *, source: str = "a PipelineConfig record") -> "PipelineConfig":
        """Rebuild from :meth:`to_dict`'s form (every key optional; nested ``segmentation`` and ``pose``
        tables); unknown keys and wrong types raise :class:`~semslam.errors.ConfigError` naming ``source``."""
        from dataclasses import fields as dc_fields

        from ..errors import ConfigError

        def build(klass, table, where):
            if not isinstance(table, dict):
                raise ConfigError(f"{where} must be a table. Got {table!r} instead.")
            names = {f.name for f in dc_fields(klass)}
            unknown = sorted(set(table) - names)
            if unknown:
                raise ConfigError(f"Unknown key(s) {unknown} in {where}. Expected some of {sorted(names)}.")
            kw = {k: (tuple(v) if isinstance(v, list) else v) for k, v in table.items()}
            try:
                return klass(**kw)
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"{where} is invalid: {exc}") from None

        if not isinstance(d, dict):
            raise ConfigError(f"{source} must be a table. Got {type(d).__name__} instead.")
        d = dict(d)
        if "segmentation" in d:
            d["segmentation"] = build(SegmentationConfig, d["segmentation"], f"the 'segmentation' table of {source}")
        if "pose" in d:
            d["pose"] = build(PoseConfig, d["pose"], f"the 'pose' table of {source}")
        if d.get("parts") is not None:
            d["parts"] = build(PartsConfig, d["parts"], f"the 'parts' table of {source}")
        if d.get("attached") is not None:
            d["attached"] = build(AttachedConfig, d["attached"], f"the 'attached' table of {source}")
        return build(cls, d, source)


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
                  scan_id: int = -1, point_stamps_s: Any = None) -> RecognitionResult:
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
        """
        if not isinstance(scan, PointCloud):
            raise InputError(f"The 'scan' argument of ScanRecognizer.recognize must be a PointCloud. "
                             f"Got {type(scan).__name__} instead.")
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
