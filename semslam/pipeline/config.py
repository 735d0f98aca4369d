"""Settings of the scan-to-detections pipeline (:class:`PipelineConfig`): segmentation, descriptor, classifier and
rejection, plausibility tests, pose estimation and verification, and the opt-in stages (part-based unions,
objects attached to structure). Plain data with checks; :mod:`.scan` runs it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from .._validation import check_choice, check_int, check_positive
from ..errors import InputError
from ..pose.model import PoseConfig
from ..segmentation.scene import SegmentationConfig
from .attached import AttachedConfig
from .parts import PartsConfig

__all__ = ["BORDER_POLICIES", "CLASSIFIERS", "POSE_MODELS", "PipelineConfig"]

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
    border_rotation_variance_rad2 : float
        Added to the rotation variances of a pose fitted to a cluster cut by the border (``border="flag"``): part of
        the object was not seen, so its orientation may be any that fits the part (the built-in elbow fitted turned
        over, the hand wheel flipped): by default pi^2 / 3 rad^2, the variance of an angle uniform on a half-turn
        either way -- the orientation is reported as unknown, the position as estimated. Such poses are also
        flagged unreliable (the filter skips them unless ``keep_unreliable``).
    pose_model : {"fused", "view"}
        Align to the class's pose-model views fused in its canonical frame (default;
        :meth:`~semslam.recognition.ViewDatabase.pose_views`: the database's pose-model views when it stores
        some, as the built-in one does, else its recognition views), or to the matched view only (the papers).
    pose : PoseConfig
        Coarse alignment, ICP, covariance and reliability thresholds.
    pose_surroundings : bool
        The pose search's visibility term also takes the scan's other clusters about the cluster as seen surfaces
        (``estimate_object_pose(surroundings_scanner=...)``): an object the segmentation split in two is not
        penalised for its part in the other cluster. A handwheel lying on the seabed, its rim broken at the spokes,
        was seen as half a wheel and posed half-turned with a confident covariance (``benchmarks/real_models.py``
        seeds 0 and 3: the wheel valve's mean 6-DoF NEES 154 and 123, with this 4.1 and 4.7). Off by default; on in
        the ``seabed`` preset.
    pose_border_scene : bool
        For a cluster cut by the scan's border, the pose search's visibility term uses the whole scan about the
        cluster (``estimate_object_pose(scene_scanner=...)``, as ``verify_visibility_image="scene"`` verifies): the
        part of the object beyond the border, which the scanner never looked at, is unknown there, where the
        cluster's own image counts it as a contradiction and favours a pose that tucks the model into the swath.
        Off by default.
    estimate_pose : bool
        False stops after recognition (detections then carry an identity pose and an infinite-like covariance).
    ambiguous_rotation_variance_rad2 : float
        Added to the rotation variances of a pose that aligns well but whose orientation is ambiguous (another,
        non-equivalent orientation scores within ``pose.min_score_margin``): 0.25 rad^2 (~29 degrees). Such a
        detection stays usable for its position (``extras["orientation_ambiguous"]``).
    up_scanner : (3,) or None
        The up direction in the scanner frame (a level camera with y down: ``(0, -1, 0)``; a vehicle: from its
        attitude). For the classes whose database records their up direction (``db build --fuse --up``), the
        pose search then keeps the object upright (:func:`~semslam.pose.estimate_object_pose`'s
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
    verify_max_plane_penetration_m : float or None
        Hypothesis verification against the planes the segmentation removed (the seabed, a wall): a recognised
        cluster lying on one (its nearest point within 5 cm of it) whose posed class reaches more than this behind
        it (behind a second plane, a slope or wall beside it, the depth its deepest 2 % of points reach: a corner
        clipping that plane's infinite extension does not count) is rejected (``extras["plane_penetration_m"]``):
        the object would be inside the floor. A flat plate taken for a thicker flange, top face on top face, sinks
        the flange by the difference (11-12.5 mm on ``benchmarks/real_models.py`` seed 0, every right pose within
        2.1 mm). The pose search is told too: when its pose fails the check, it takes the best other refined
        hypothesis whose pose passes (``estimate_object_pose(admissible=...)``), so a border-cut cluster posed too
        deep, where its depth twin along the view lies on the floor, is posed there instead of rejected. Off (None)
        by default; the ``seabed`` preset uses 10 mm (objects resting on the seabed, not buried in it). Needs
        ``estimate_pose``.
    verify_next_classes : int
        A cluster whose class fails hypothesis verification, or whose size test (``size_tolerance``) it fails, is
        tried as the next-nearest classes (the nearest view of each other class the rejection accepts and whose size
        test it passes, nearest first), up to this many;
        the first whose pose verifies is the detection (its reason says which class failed first and why). A strip
        of a 12 mm plate cut by the swath's border is nearer a thicker flange's face than the plate's: the
        flange's pose, 15 mm inside the floor, fails, the plate's verifies. A union of clusters
        (:class:`~semslam.pipeline.parts.PartsConfig`) is tried the same way, unless one of its clusters was
        recognised alone (that detection gives way only to the union's nearest class). 0 (default): the nearest
        class only. Needs a verification check (``verify_min_fitness``, ``verify_max_visibility`` or
        ``verify_max_plane_penetration_m``).
    verify_visibility_image : {"cluster", "scene", "border"}
        What verification's visibility cost compares the model with: the cluster alone (default: every model
        point the cluster did not see is a contradiction, so an object hidden in part or cut by the scan's edge
        fails), or the whole scan about the cluster (``"scene"``: a model point behind another object is hidden, one
        where the scanner did not look is unknown, one in front of what the scanner saw -- free space -- or behind a
        plane contradicts); ``"border"``: the scene for the clusters cut by the scan border, the cluster for the
        others.
    verify_camera_shadows : bool
        A triangulation laser scanner measures a point only where its camera also sees the laser's spot: where the
        object hides the spot from the camera, the scan has nothing although the laser saw the surface. With this on
        and a database that records its scanner's camera (:attr:`~semslam.recognition.ViewDatabase.
        scanner_camera_xyz_m`: a laser database), a cluster's own visibility cost is also computed with the camera's
        shadows (``PoseConfig.camera_offset_m``'s model) and the lower of the two is verified: a pose passes when
        one viewpoint or the camera explains what the scan misses. The pose search itself is unchanged (with the
        camera in the search the wheel valve's half-turns tie, NEES x3). Off by default; the ``seabed`` preset turns
        it on: ``benchmarks/real_models.py`` seed 0 recall 89.4 -> 91.3 % (the wheel valve standing on its rim,
        only its top seen: visibility cost 0.25-0.33 alone), seed 3 unchanged (the camera alone would lose a
        wheel valve at 0.158).
    parts : PartsConfig or None
        Part-based hypotheses (:mod:`semslam.pipeline.parts`): unknown clusters close to each other are tried as
        one object (a valve's handwheel seen apart from its body) and kept when the union is recognised, passes
        verification and every part fits the pose. Off (None) by default; needs ``verify_min_fitness``.
    attached : AttachedConfig or None
        Objects attached to structure (:mod:`semslam.pipeline.attached`): in the clusters rejected as too big or
        cut by the border, the structure (a pipe, a post) is removed primitive by primitive and the rest is
        recognised. Off (None) by default.
    track_border_cut_m : float or None
        Border-cut clusters rejected alone, or recognised alone as another class, are tried as the objects
        recognised in the scan before, carried into this scan by the vehicle's motion between the two
        (:mod:`semslam.pipeline.tracking`; a stream's runner, a dataset's or the live node's, gives the scan before;
        :meth:`ScanRecognizer.recognize` alone tracks nothing): ICP from the predicted pose, the same verification,
        and at most this far (m) from the prediction. The detection keeps the border's flag (unreliable). Off (None)
        by default; needs ``verify_min_fitness``.
    deskew : bool
        Carry every point of a scan with per-point stamps into the scanner frame at the scan's end with the
        vehicle's own motion over the scan (attitude + DVL, :mod:`semslam.pipeline.deskew`) before segmenting it;
        its detections are then stamped at the scan's end. On by default; a scan without stamps or navigation
        over its span is used as it is.
    deskew_lookahead_s : float
        How much navigation after a scan's end smooths its motion (s, 0-1; default 0.5, the smoothing window's
        half). A stream's runner and the live node wait for it before they recognise the scan, so a live scan's
        detections come that much later (plus the scan's own span). 0: no wait, a window ending at the scan's end,
        measured ~3x less accurate (deskewing error median 11.5 mm against 3.4 mm, docs/configuration.md).
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
    border_rotation_variance_rad2: float = float(np.pi**2 / 3)
    pose_model: str = "fused"
    pose: PoseConfig = field(default_factory=PoseConfig)
    estimate_pose: bool = True
    pose_surroundings: bool = False
    pose_border_scene: bool = False
    ambiguous_rotation_variance_rad2: float = 0.25
    up_scanner: tuple | None = None
    verify_min_fitness: float | None = None
    verify_max_visibility: float | None = None
    verify_max_plane_penetration_m: float | None = None
    verify_next_classes: int = 0
    verify_visibility_image: str = "cluster"
    verify_camera_shadows: bool = False
    parts: PartsConfig | None = None
    attached: AttachedConfig | None = None
    track_border_cut_m: float | None = None
    deskew: bool = True
    deskew_lookahead_s: float = 0.5

    def __post_init__(self) -> None:
        c = "PipelineConfig"
        for name in ("pose_surroundings", "pose_border_scene"):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"The {name!r} argument of {c} must be true or false. "
                                 f"Got {getattr(self, name)!r} instead.")
        if not isinstance(self.verify_camera_shadows, bool):
            raise InputError(f"The 'verify_camera_shadows' argument of {c} must be true or false. "
                             f"Got {self.verify_camera_shadows!r} instead.")
        if not isinstance(self.deskew, bool):
            raise InputError(f"The 'deskew' argument of {c} must be true or false. Got {self.deskew!r} instead.")
        la = self.deskew_lookahead_s
        if isinstance(la, bool) or not isinstance(la, (int, float)) or not 0.0 <= la <= 1.0:
            raise InputError(f"The 'deskew_lookahead_s' argument of {c} must be a number of seconds in [0, 1]. "
                             f"Got {la!r} instead.")
        if self.verify_min_fitness is not None:
            check_positive("verify_min_fitness", self.verify_min_fitness, caller=c, allow_zero=True)
            if self.verify_min_fitness > 1:
                raise InputError(f"The 'verify_min_fitness' argument of {c} must be in [0, 1]. "
                                 f"Got {self.verify_min_fitness!r} instead.")
        if self.verify_max_visibility is not None:
            check_positive("verify_max_visibility", self.verify_max_visibility, caller=c, allow_zero=True)
        if self.verify_max_plane_penetration_m is not None:
            check_positive("verify_max_plane_penetration_m", self.verify_max_plane_penetration_m, caller=c,
                           allow_zero=True)
        if not self.estimate_pose and any(v is not None for v in (self.verify_min_fitness, self.verify_max_visibility,
                                                                   self.verify_max_plane_penetration_m)):
            raise InputError(f"The 'verify_min_fitness' / 'verify_max_visibility' / 'verify_max_plane_penetration_m' "
                             f"arguments of {c} need "
                             f"estimate_pose=True (they test the estimated pose). Got estimate_pose=False instead.")
        check_int("verify_next_classes", self.verify_next_classes, caller=c, minimum=0)
        if self.track_border_cut_m is not None:
            check_positive("track_border_cut_m", self.track_border_cut_m, caller=c)
            if self.verify_min_fitness is None:
                raise InputError(f"The 'track_border_cut_m' argument of {c} needs verify_min_fitness (a tracked "
                                 f"cluster's pose is verified like any other). Got verify_min_fitness=None.")
        if self.verify_next_classes and all(v is None for v in (self.verify_min_fitness, self.verify_max_visibility,
                                                                 self.verify_max_plane_penetration_m)):
            raise InputError(f"The 'verify_next_classes' argument of {c} needs a verification check "
                             f"(verify_min_fitness, verify_max_visibility or verify_max_plane_penetration_m): it "
                             f"tries the next classes when one fails. Got {self.verify_next_classes!r} with none.")
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
                raise InputError(
                    f"The 'up_scanner' argument of {c} must be a non-zero 3-vector. Got {up.tolist()} instead."
                )
            object.__setattr__(self, "up_scanner", tuple(float(v) for v in up))
        check_positive("ambiguous_rotation_variance_rad2", self.ambiguous_rotation_variance_rad2, caller=c)
        check_positive("border_rotation_variance_rad2", self.border_rotation_variance_rad2, caller=c, allow_zero=True)
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
            raise InputError(
                f"The 'pose' argument of {c} must be a PoseConfig. Got {type(self.pose).__name__} instead."
            )

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
