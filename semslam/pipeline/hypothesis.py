"""The pose and verify stages of the recogniser, shared by every kind of hypothesis (a cluster, a union of parts, a
piece found inside a cluster): :func:`pose_hypothesis` turns a recognised :class:`Hypothesis` into a
:class:`~semslam.detection.Detection` (6-DoF pose, covariance, reliability), :func:`verification_failure` says why
a detection fails hypothesis verification, :func:`pose_and_verify` does both for the opt-in stages.

``rec`` is the :class:`~semslam.pipeline.scan.ScanRecognizer` (its ``config``, ``db`` and ``pose_model``)."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..cloud import PointCloud
from ..detection import Detection
from ..pose.estimate import estimate_object_pose
from ..pose.model import HULL_SLACK_M
from ..segmentation.scene import SegmentationResult
from .scan_records import ScanContext

__all__ = ["Hypothesis", "plane_penetration_m", "pose_and_verify", "pose_hypothesis", "scene_visibility",
           "verification_failure"]


@dataclass(frozen=True, eq=False)
class Hypothesis:
    """Points of a scan recognised as a class: what the pose stage aligns.

    Attributes
    ----------
    raw_idx : ndarray of int
        Indices into the scan of the hypothesis's points (the pose is estimated from them; empty: from ``cloud``).
    cloud : PointCloud
        Its points in the segmented cloud (the ones that were described and matched).
    label : str
    view_index : int
        The matched view (``PipelineConfig(pose_model="view")`` aligns to it).
    match : Match
        The nearest-view match (its distance is the detection's score).
    touches_border : bool
        The points are cut by the scan's border (the pose is then marked unreliable).
    union : bool
        The points are a union of clusters (:mod:`semslam.pipeline.parts`): a part of the object may be missing or
        elsewhere, so, like a border-cut cluster, the pose search also starts the translation on a grid across the
        object (``estimate_object_pose(partial=True)``, ``PoseConfig.partial_start_step_m``).
    init_T_sensor_object : ndarray (4, 4) or None
        A predicted pose (:mod:`semslam.pipeline.tracking`): the pose is refined by ICP from it, with no search.
    """

    raw_idx: np.ndarray
    cloud: PointCloud
    label: str
    view_index: int
    match: Any
    touches_border: bool = False
    union: bool = False
    init_T_sensor_object: np.ndarray | None = None


def verification_failure(det: Detection, min_fitness: float | None, max_visibility: float | None,
                         max_penetration_m: float | None = None) -> str:
    """Why a detection fails hypothesis verification (``PipelineConfig.verify_min_fitness`` /
    ``verify_max_visibility`` / ``verify_max_plane_penetration_m``), or ``""`` when it passes (or verification is
    off). The visibility cost is tested only when the pose search measured it (grid search; NaN otherwise), the
    penetration only when a removed plane lies under the cluster (``extras["plane_penetration_m"]``). The cluster's
    own visibility cost is the lower of one viewpoint's and the scanner camera's (``extras["pose_visibility_camera"]``,
    ``PipelineConfig.verify_camera_shadows``) when both were computed."""
    if min_fitness is not None and not det.fitness >= min_fitness:
        return f"pose verification: fitness {det.fitness:.3f} < {min_fitness:g}"
    depth = float(det.extras.get("plane_penetration_m", float("nan")))
    if max_penetration_m is not None and depth == depth and depth > max_penetration_m:
        return (f"pose verification: the posed object reaches {1e3 * depth:.1f} mm behind a removed plane "
                f"(> {1e3 * max_penetration_m:g} mm: inside the floor or the wall it lies on)")
    scene = "pose_visibility_scene" in det.extras
    vis = float(det.extras.get("pose_visibility_scene" if scene else "pose_visibility", float("nan")))
    camera = float(det.extras.get("pose_visibility_camera", float("nan")))
    if not scene and camera < vis:  # the camera's shadows explain what one viewpoint does not (NaN: not computed)
        vis = camera
    if max_visibility is not None and vis == vis and vis > max_visibility:
        return f"pose verification: {'scene ' if scene else ''}visibility cost {vis:.3f} > {max_visibility:g}"
    return ""


def _scene_of(seg: SegmentationResult | None, points: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``(scene, occluders)`` for the pose search of a border-cut cluster (``PipelineConfig.pose_border_scene``): the
    segmented scan (planes included) and its clusters with ``points``, as :func:`scene_visibility` uses them; None
    without a segmentation."""
    if seg is None:
        return None
    cloud = seg.segmented_cloud.points_xyz_m
    objects = cloud[np.concatenate(seg.cluster_indices)] if seg.cluster_indices else cloud[:0]
    return cloud, np.vstack([objects, points])


def scene_visibility(pose_config: Any, scan: PointCloud, seg: SegmentationResult | None, points: np.ndarray,
                     model: Any, T_scanner_object: Any) -> float:
    """The visibility cost of a pose against the whole scan about the cluster (``verify_visibility_image="scene"``,
    :meth:`~semslam.pose.search.RangeImage.build_scene`): the segmented scan (planes included) for the free
    space, its clusters as the only surfaces that may hide the object. NaN when the model has no visibility points."""
    from ..pose.search import RangeImage

    if model.visibility_points is None or not len(model.visibility_points):
        return float("nan")
    pc = pose_config
    if seg is None:  # no segmentation given: the raw scan, any surface may hide
        image = RangeImage.build_scene(scan.points_xyz_m, scan.viewpoint_xyz_m, points, cell_m=pc.image_cell_m)
    else:
        cloud, occluders = _scene_of(seg, points)
        image = RangeImage.build_scene(cloud, scan.viewpoint_xyz_m, points, cell_m=pc.image_cell_m,
                                       occluder_points=occluders)
    image = image.with_camera(pc.camera_offset_m)
    T_os = np.linalg.inv(T_scanner_object.matrix)  # a scene image: where the scanner saw nothing is unknown
    return float(image.visibility_cost(T_os[None, :3, :3], T_os[None, :3, 3], model.visibility_points,
                                       model.visibility_normals, pc.visibility_tol_m)[0])


def camera_visibility(pose_config: Any, points: np.ndarray, viewpoint_xyz_m: np.ndarray, model: Any,
                      T_scanner_object: Any, camera_xyz_m: Any) -> float:
    """The visibility cost of a pose against the cluster's own range image (``points``, on the pose search's voxel
    grid, as the search's verdict computes it) with the triangulation camera at ``camera_xyz_m`` (scanner frame):
    model points the camera cannot see are not expected in the scan (``PipelineConfig.verify_camera_shadows``).
    NaN when the model has no visibility points."""
    from ..pose.search import RangeImage
    from ..segmentation.voxel import voxel_downsample

    if model.visibility_points is None or not len(model.visibility_points):
        return float("nan")
    pc = pose_config
    grid = voxel_downsample(points, pc.search_voxel_m)
    image = RangeImage.build(grid if len(grid) >= 3 else points, np.asarray(viewpoint_xyz_m, dtype=np.float64),
                             cell_m=pc.image_cell_m).with_camera(camera_xyz_m)
    T_os = np.linalg.inv(T_scanner_object.matrix)
    return float(image.visibility_cost(T_os[None, :3, :3], T_os[None, :3, 3], model.visibility_points,
                                       model.visibility_normals, pc.visibility_tol_m)[0])


#: A removed plane is the one a cluster lies on when the cluster's nearest point is at most this far in front of it.
SUPPORT_PLANE_DISTANCE_M = 0.05
#: Behind a removed plane after the first (a slope, a wall: structure beside the objects), the depth the deepest
#: 2 % of the posed model's points reach, so that a corner touching the plane does not count: a fitted plane is not
#: the exact surface. Chosen when the simulator still placed parts across the slope's foot (the blind flange of
#: benchmarks/real_models.py seed 3 reached 12 mm past it, its right poses 10.6-13.4 mm behind the slope's plane at
#: their deepest point, 0.5 % of the points more than 5 mm deep; parts lie wholly on the flat floor since
#: 2026-12-06), while a class sunk into a plane puts its whole underside there (27-31 % of its points more than 10 mm
#: deep for the panel base taken for the blind flange).
PENETRATION_SHARE = 0.02


def _supporting_planes(seg: SegmentationResult, cluster_points: np.ndarray):
    """``(k, unit normal, d)`` of each removed plane (in removal order) the cluster lies on: its nearest point within
    :data:`SUPPORT_PLANE_DISTANCE_M` of it."""
    for k, plane in enumerate(seg.planes):
        n, d = plane.coefficients[:3], float(plane.coefficients[3])
        if -SUPPORT_PLANE_DISTANCE_M <= float(np.min(cluster_points @ n + d)) <= SUPPORT_PLANE_DISTANCE_M:
            yield k, n, d


def plane_penetration_m(seg: SegmentationResult | None, cluster_points: np.ndarray, model_points_object: np.ndarray,
                        T_scanner_object: np.ndarray) -> float:
    """How far the posed model reaches behind the removed planes the cluster lies on (metres, >= 0), NaN when no
    removed plane is within :data:`SUPPORT_PLANE_DISTANCE_M` of the cluster (or no segmentation). Behind the first
    removed plane (the largest: the seabed or floor the objects rest on), the deepest model point; behind a later
    one (a slope or wall beside them, whose infinite extension passes under objects in front of its foot), the depth
    its deepest :data:`PENETRATION_SHARE` of points reach, so that a corner clipping it does not count.

    A removed plane (the seabed, a wall; :attr:`SegmentationResult.planes`, ``n . p + d = 0`` with the scanner on
    the positive side) is solid where the scanner saw it: an object lying on it cannot reach behind it. A cluster
    taken for a class whose surface sits higher than the one seen (a 12 mm plate fitted as a 22 mm flange, top
    face on top face) puts that class's bottom inside the floor, by the difference. Frames: ``cluster_points``
    (N, 3) and the planes in the scan's frame, ``model_points_object`` (M, 3) in the object's,
    ``T_scanner_object`` (4, 4)."""
    if seg is None or not seg.planes or not len(cluster_points) or not len(model_points_object):
        return float("nan")
    T = np.asarray(T_scanner_object, dtype=np.float64)
    depth = float("nan")
    for k, n, d in _supporting_planes(seg, cluster_points):
        signed = _plane_values(model_points_object, T, n, d)
        behind = max(-float(np.min(signed) if k == 0 else np.quantile(signed, PENETRATION_SHARE)), 0.0)
        depth = behind if depth != depth else max(depth, behind)
    return depth


def _plane_values(points_object: np.ndarray, T_scanner_object: np.ndarray, n: np.ndarray, d: float) -> np.ndarray:
    """``n . (R p + t) + d`` of every object-frame point ``p`` posed by ``T_scanner_object``: the signed distances to
    the plane ``n . x + d = 0`` (scanner frame), from one matrix-vector product (``(R^T n) . p + (n . t + d)``, no
    transformed copy of the model)."""
    R, t = T_scanner_object[:3, :3], T_scanner_object[:3, 3]
    return points_object @ (R.T @ n) + (float(t @ n) + d)


#: Beyond the cluster's own extent, how far about it the scan's other objects count as its surroundings (m); the
#: reach is at least twice the model's radius (``PipelineConfig.pose_surroundings``).
SURROUNDINGS_MARGIN_M = 0.05


def surroundings(seg: SegmentationResult | None, points: np.ndarray, radius_m: float) -> np.ndarray | None:
    """The points of the scan's clusters (the segmented cloud's objects, not its planes) within reach of ``points``
    (a cluster, scanner frame): within ``max(cluster radius + SURROUNDINGS_MARGIN_M, 2 * radius_m)`` of its centroid
    (``radius_m``: the posed class's). The cluster's own points are among them. None without a segmentation."""
    if seg is None or not seg.cluster_indices or not len(points):
        return None
    cloud = seg.segmented_cloud.points_xyz_m
    objects = cloud[np.concatenate(seg.cluster_indices)]
    c = points.mean(axis=0)
    reach = max(float(np.sqrt(np.max(np.sum((points - c) ** 2, axis=1)))) + SURROUNDINGS_MARGIN_M, 2.0 * radius_m)
    return objects[np.sum((objects - c) ** 2, axis=1) <= reach * reach]


def _above_floor(cfg: Any, seg: SegmentationResult | None, points: np.ndarray, model: Any):
    """The pose search's admissibility test (``estimate_object_pose(admissible=...)``) under the floor check
    (``verify_max_plane_penetration_m``): a pose whose model reaches no deeper behind the removed planes the cluster
    lies on than the check allows. When the search's pose fails it, the search takes the best other refined
    hypothesis whose pose passes (a border-cut cluster's depth twin, another orientation) instead of handing over a
    pose the check will reject. None without the check or without a removed plane."""
    limit = cfg.verify_max_plane_penetration_m
    if limit is None or seg is None or not seg.planes:
        return None

    def admissible(T_scanner_object: np.ndarray) -> bool:
        return within_planes(seg, points, model.points_object, T_scanner_object, limit, hull_points=model.hull_points)

    return admissible


def _resting_floor(cfg: Any, seg: SegmentationResult | None, points: np.ndarray) -> tuple | None:
    """The floor the cluster rests on for the pose search's starts (``estimate_object_pose(floor_scanner=...)``): the
    first removed plane (the largest, the seabed) when the cluster lies on it and the floor check is on (its
    ``verify_max_plane_penetration_m`` says objects rest on the floor); None otherwise."""
    if cfg.verify_max_plane_penetration_m is None or seg is None or not seg.planes:
        return None
    return next(((n, d) for k, n, d in _supporting_planes(seg, points) if k == 0), None)


#: Rounding allowance of :func:`within_planes`'s bound (m): a pose whose deepest point comes this close to the limit
#: gets the exact depth.
BOUND_SLACK_M = 1e-9


def within_planes(seg: SegmentationResult | None, cluster_points: np.ndarray, model_points_object: np.ndarray,
                  T_scanner_object: np.ndarray, limit_m: float, *, hull_points: np.ndarray | None = None) -> bool:
    """``not plane_penetration_m(...) > limit_m`` (NaN passes), the floor check's verdict, computed fast. Behind each
    removed plane the cluster lies on, the posed model's depths come from one matrix-vector product (no transformed
    model, no sort): the floor's depth is the deepest point's, a later plane's the :data:`PENETRATION_SHARE` quantile,
    decided by counting the points deeper than the limit. Only a depth within :data:`BOUND_SLACK_M` of the limit
    (where the two products' rounding could differ) gets :func:`plane_penetration_m`. The pose search asks this of
    every refined hypothesis: ~20 ms each on a model of 300 000 points before, ~3 ms then. Given the model's
    ``hull_points`` (:attr:`~semslam.pose.model.PoseModel.hull_points`), the deepest point comes from the hull's
    vertices first (good to :data:`~semslam.pose.model.HULL_SLACK_M`): a plane the hull clears, or a floor it is
    clearly beyond, is decided without the model's points."""
    if seg is None or not seg.planes or not len(cluster_points) or not len(model_points_object):
        return True
    T = np.asarray(T_scanner_object, dtype=np.float64)
    exact = lambda: not plane_penetration_m(seg, cluster_points, model_points_object, T) > limit_m  # noqa: E731
    for k, n, d in _supporting_planes(seg, cluster_points):
        if hull_points is not None and len(hull_points):
            hull_deepest = -float(np.min(_plane_values(hull_points, T, n, d)))  # <= the deepest, to the slack
            if hull_deepest + HULL_SLACK_M <= limit_m - BOUND_SLACK_M:
                continue
            if k == 0 and hull_deepest - HULL_SLACK_M > limit_m + BOUND_SLACK_M:
                return False
        signed = _plane_values(model_points_object, T, n, d)
        deepest = -float(np.min(signed))
        if deepest <= limit_m - BOUND_SLACK_M:
            continue  # the deepest point bounds the depth behind this plane
        if k == 0:
            if deepest > limit_m + BOUND_SLACK_M:
                return False
            return exact()
        # np.quantile's linear interpolation lies between the sorted depths lo and lo + 1
        lo = int(np.floor(PENETRATION_SHARE * (len(signed) - 1)))
        if np.count_nonzero(signed < -(limit_m + BOUND_SLACK_M)) >= lo + 2:
            return False  # both beyond the limit
        if np.count_nonzero(signed < -(limit_m - BOUND_SLACK_M)) <= lo:
            continue  # the lower one within it
        return exact()
    return True


def pose_hypothesis(rec: Any, ctx: ScanContext, seg: SegmentationResult | None, hyp: Hypothesis, *, seed: int,
                    timings: dict) -> Detection:
    """The detection of ``hyp``: its pose (unless ``estimate_pose`` is off), covariance and reliability, stamped
    with :meth:`ScanContext.stamp_of` its points; ``timings["pose"]`` accumulates the pose time. ``seg``: the
    scan's segmentation, for the scene visibility cost (``verify_visibility_image="scene"``)."""
    from ..geometry import RigidTransform

    cfg, scan, raw_idx, label = rec.config, ctx.scan, hyp.raw_idx, hyp.label
    stamp_s = ctx.stamp_of(raw_idx)
    extras = {"view_index": int(hyp.view_index), "view_id": str(rec.db.view_ids[hyp.view_index]),
              "cluster_points": len(raw_idx), "touches_border": bool(hyp.touches_border)}
    if not cfg.estimate_pose:
        centroid = hyp.cloud.points_xyz_m.mean(axis=0)
        return Detection(label, hyp.match.distance, RigidTransform.from_rotation_translation(np.eye(3), centroid),
                         np.diag([1e-2] * 3 + [1e4] * 3), n_points=hyp.cloud.n_points, reliable=False,
                         stamp_s=stamp_s, scan_id=ctx.scan_id, extras=extras)
    t0 = time.perf_counter()
    info = rec.db.class_info(label)
    model = rec.pose_model(label, hyp.view_index)
    points = scan.points_xyz_m[raw_idx] if len(raw_idx) else hyp.cloud.points_xyz_m
    up_scanner = ctx.up_scanner
    up_object = rec.db.up_objects(label) if up_scanner is not None else None  # one up, or both ways of a tied rest
    extras["pose_upright"] = up_object is not None
    pose = estimate_object_pose(points, model, symmetry=info.symmetry, config=cfg.pose, seed=seed,
                                viewpoint_xyz_m=scan.viewpoint_xyz_m, up_scanner=up_scanner if up_object
                                is not None else None, up_object=up_object,
                                partial=bool(hyp.touches_border or hyp.union),
                                surroundings_scanner=surroundings(seg, points, model.radius_m)
                                if cfg.pose_surroundings else None, admissible=_above_floor(cfg, seg, points, model),
                                scene_scanner=_scene_of(seg, points) if cfg.pose_border_scene and hyp.touches_border
                                else None, init_T_scanner_object=hyp.init_T_sensor_object,
                                floor_scanner=_resting_floor(cfg, seg, points) if up_object is not None else None)
    timings["pose"] += (time.perf_counter() - t0) * 1e3
    cov = pose.covariance_6x6
    ambiguous = pose.ambiguous  # the rule lives in registration.pose.pose_verdict
    extras["pose_visibility"] = float(pose.visibility)
    camera = rec.db.scanner_camera_xyz_m if cfg.verify_camera_shadows else None
    if camera is not None and np.isfinite(pose.visibility):
        extras["pose_visibility_camera"] = camera_visibility(cfg.pose, points, scan.viewpoint_xyz_m, model,
                                                             pose.T_scanner_object, camera)
    mode = cfg.verify_visibility_image
    if cfg.verify_max_visibility is not None and (mode == "scene" or (mode == "border" and hyp.touches_border)):
        extras["pose_visibility_scene"] = scene_visibility(cfg.pose, scan, seg, points, model, pose.T_scanner_object)
    extras["pose_score_margin"] = float(pose.score_margin)
    if cfg.verify_max_plane_penetration_m is not None:
        extras["plane_penetration_m"] = plane_penetration_m(seg, points, model.points_object,
                                                            pose.T_scanner_object.matrix)
    if ambiguous:
        # The cluster is well aligned but another, non-equivalent orientation fits almost as well (a
        # near-symmetric view): the position is trustworthy, the orientation is not. Say so in the
        # covariance instead of dropping the detection; the filter's cascade then uses the position.
        cov = cov.copy()
        cov[3:, 3:] += np.eye(3) * cfg.ambiguous_rotation_variance_rad2
        extras["orientation_ambiguous"] = True
    if hyp.touches_border and cfg.border_rotation_variance_rad2 > 0:
        # fitted to the part of the object the scan saw: the orientation is unknown (PipelineConfig's docstring)
        cov = cov.copy()
        cov[3:, 3:] += np.eye(3) * cfg.border_rotation_variance_rad2
        extras["orientation_unknown_border"] = True
    return Detection(label, hyp.match.distance, pose.T_scanner_object, cov, score_kind="chi2",
                     fitness=pose.fitness, rmse_m=pose.rmse_m, n_points=len(points),
                     reliable=bool((pose.reliable or ambiguous) and not hyp.touches_border),
                     stamp_s=stamp_s, scan_id=ctx.scan_id, extras=extras)


def pose_and_verify(rec: Any, ctx: ScanContext, seg: SegmentationResult | None, hyp: Hypothesis, *, seed: int,
                    timings: dict, what: str, scene_visibility_cost: bool = False) -> Detection | None:
    """Pose and verify a hypothesis of an opt-in stage (a union of parts, a piece found inside a cluster): the
    detection, or None when the pose fails or verification rejects it (logged with ``what``).
    ``scene_visibility_cost``: verify the visibility cost against the whole scan (:func:`scene_visibility`) whatever
    ``verify_visibility_image`` says (``PartsConfig.scene_visibility``)."""
    from ..errors import RegistrationError

    cfg = rec.config
    try:
        det = pose_hypothesis(rec, ctx, seg, hyp, seed=seed, timings=timings)
    except RegistrationError:
        return None
    if scene_visibility_cost and cfg.verify_max_visibility is not None and "pose_visibility_scene" not in det.extras:
        points = ctx.scan.points_xyz_m[hyp.raw_idx] if len(hyp.raw_idx) else hyp.cloud.points_xyz_m
        model = rec.pose_model(hyp.label, hyp.view_index)
        det.extras["pose_visibility_scene"] = scene_visibility(cfg.pose, ctx.scan, seg, points, model,
                                                               det.T_sensor_object)
    failed = verification_failure(det, cfg.verify_min_fitness, cfg.verify_max_visibility,
                                  cfg.verify_max_plane_penetration_m)
    if failed:
        logging.getLogger("semslam.pipeline").debug("%s: %s %s", what, hyp.label, failed)
        return None
    return det
