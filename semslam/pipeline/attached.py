"""Objects attached to structure: find a known object inside a larger cluster.

A valve is mounted on a pipe, a sensor on a post: Euclidean clustering returns the object and the structure it
touches as one cluster, which is too big for any class (or, when the structure is short, matches no view), and
the object is reported unknown. On the shared RealSense frames the ball valve's lever is always one cluster with
the rig's vertical pipe (15-17 cm against a 10 cm class).

:func:`find_attached` (``PipelineConfig(attached=AttachedConfig())``, ``semslam recognize --attached``; opt-in)
runs after the per-cluster pipeline of :meth:`~semslam.pipeline.ScanRecognizer.recognize`, on the clusters
rejected as too big (for any class or for their class) or as cut by the scan border -- and, with
``include_far``, on those whose descriptor is too far from every view. In each such cluster it removes the
structure one primitive at a time:

1. normals of the cluster's points; the cylinder (or plane, see ``kinds``) with the most inliers by RANSAC
   (:func:`~semslam.segmentation.primitives.fit_primitive`) that is structure: a cylinder must be elongated
   (``min_structure_elongation``; a wide one is fitted again with a smaller radius);
2. the structure is that primitive's cross-section extruded along its axis: every point whose projection across
   the axis lies within ``removal_margin`` of an inlier's projection, between the inliers' ends, is removed (the
   pipe's edges and seams, whose normals miss the cylinder, go with it; an object sticking out of the pipe
   stays);
3. the rest is clustered again (the scan's cluster tolerance); each piece goes through the size test for any
   class, the border test, the descriptor, matching with unknown rejection and the size test of its class; it
   must be at least ``min_extent_share`` of its class's longest dimension and ``min_area_share`` of its views'
   surface (fragments are not objects), and with the removed structure explain ``min_explained_share`` of the
   cluster (a piece cut out of a large surface is not an object on a pipe).

The first removal step that frees a recognised piece ends the search (removing more would eat the object: a flat
lever fits a wide cylinder); the piece nearest its view (distance over threshold) is posed like any cluster
(the pose from the piece's own points, hypothesis verification with ``PipelineConfig.verify_*`` when set) and
replaces the cluster's outcome, with ``extras["attached"]`` (the removed primitives, the piece's size, centroid
and explained share). Measured on the shared RealSense frames (held out): the ball valve 0/6 -> 6/6, clutter
unchanged with ``reject_margin=1`` (``benchmarks/real_valves_frames.py --attached``).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .._validation import as_float_array, check_choice, check_int, check_positive
from ..detection import Detection
from ..errors import DescriptorError, InputError
from ..recognition import UNKNOWN_LABEL
from ..recognition.plausibility import border_touched, principal_extent
from ..segmentation.clusters import extract_euclidean_clusters
from ..segmentation.primitives import Primitive, fit_primitive
from ._scan_helpers import _input_indices_of
from .class_measures import grid_area_m2
from .hypothesis import Hypothesis, pose_and_verify
from .scan_records import ClusterOutcome, ScanContext
from .stages import scan_footprint

__all__ = ["AttachedConfig", "find_attached", "remove_structure"]

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AttachedConfig:
    """Settings of :func:`find_attached` (``PipelineConfig.attached``). Lengths given as factors are relative to
    the segmentation's resolved cluster tolerance ``tol`` (6.4-7.1 mm on the RealSense frames at 30 cm, 20 mm on
    the laser's default), so that one setting serves both sensors.

    Attributes
    ----------
    max_structures : int
        Primitives removed from one cluster, one after the other, at most. Default 2.
    kinds : tuple of {"cylinder", "plane"}
        Primitives tried at each step (the one with the most inliers is removed). Default ("cylinder",): a flat
        part of the object (a lever) is a plane too, and a plane's removal would take it with the wall.
    inlier_distance_factor : float
        A point is on the primitive within this times ``tol``. Default 0.5.
    removal_margin_factor : float
        A point whose projection across the axis is within this times ``tol`` of an inlier's projection is
        structure. Default 0.9.
    normal_radius_factor : float
        Normals from the neighbours within this times ``tol``. Default 0.75 (3 voxels at the "auto" lengths).
    max_angle_deg : float
        Inlier normals within this of the surface's normal. Default 30.
    radius_range_m : (float, float)
        Cylinder radii tried. Default (0.005, 0.25).
    iterations : int
        RANSAC hypotheses per primitive. Default 1000.
    min_structure_points : int
        A primitive with fewer inliers is not structure (the search stops). Default 100.
    min_structure_elongation : float
        A cylinder is structure (a pipe, a post) only if its inliers are at least this times longer along its axis
        than wide across it; a wide, short one is a curved surface (a cloth backdrop fits r = 0.25 m over
        0.28 x 0.28 m): it is fitted again with a smaller radius (twice at most; then the search ends). Default 2
        (the rig's pipe: 15 cm long, 4-5 cm seen across).
    min_extent_share : float
        A piece must be at least this share of its class's longest dimension. Default 0.6.
    min_area_share : float
        A piece's surface (occupied cells of the segmentation's voxel grid) must be at least this share of the
        median surface of its class's views on the same grid: a fragment of the structure left by the removal
        is smaller than any view of a whole object. Default 0.4.
    min_explained_share : float
        The removed structure and the piece must together be at least this share of the cluster's points: an
        object on a pipe is the cluster minus the pipe (and a few fragments), while a piece cut out of a large
        surface (a backdrop with folds that fit thin cylinders) leaves most of that surface unexplained. Default
        0.8.
    include_far : bool
        Also search the clusters rejected by their descriptor distance (not too big). Default False.
    max_clusters : int
        Clusters searched per scan at most, largest first (a bound on the time). Default 8.
    """

    max_structures: int = 2
    kinds: tuple = ("cylinder",)
    inlier_distance_factor: float = 0.5
    removal_margin_factor: float = 0.9
    normal_radius_factor: float = 0.75
    max_angle_deg: float = 30.0
    radius_range_m: tuple = (0.005, 0.25)
    iterations: int = 1000
    min_structure_points: int = 100
    min_structure_elongation: float = 2.0
    min_extent_share: float = 0.6
    min_area_share: float = 0.4
    min_explained_share: float = 0.8
    include_far: bool = False
    max_clusters: int = 8

    def __post_init__(self) -> None:
        c = "AttachedConfig"
        check_int("max_structures", self.max_structures, caller=c, minimum=1, maximum=5)
        kinds = tuple(self.kinds) if isinstance(self.kinds, (list, tuple)) else (self.kinds,)
        if not kinds:
            raise InputError(f"The 'kinds' argument of {c} must name at least one of cylinder, plane. Got () instead.")
        for k in kinds:
            check_choice("kinds", k, ("cylinder", "plane"), caller=c)
        object.__setattr__(self, "kinds", kinds)
        for name in ("inlier_distance_factor", "removal_margin_factor", "normal_radius_factor", "max_angle_deg",
                     "min_extent_share", "min_area_share", "min_explained_share"):
            check_positive(name, getattr(self, name), caller=c)
        if not self.max_angle_deg < 90:
            raise InputError(
                f"The 'max_angle_deg' argument of {c} must be in (0, 90). Got {self.max_angle_deg!r} instead."
            )
        for name in ("min_extent_share", "min_explained_share"):
            if not getattr(self, name) <= 1:
                raise InputError(
                    f"The '{name}' argument of {c} must be in (0, 1]. Got {getattr(self, name)!r} instead."
                )
        try:
            lo, hi = (float(v) for v in self.radius_range_m)
        except (TypeError, ValueError):
            raise InputError(f"The 'radius_range_m' argument of {c} must be two lengths (low, high). "
                             f"Got {self.radius_range_m!r} instead.") from None
        if not 0 < lo < hi < np.inf:
            raise InputError(f"The 'radius_range_m' argument of {c} must be (low, high) with 0 < low < high. "
                             f"Got {self.radius_range_m!r} instead.")
        object.__setattr__(self, "radius_range_m", (lo, hi))
        check_int("iterations", self.iterations, caller=c, minimum=1)
        check_positive("min_structure_elongation", self.min_structure_elongation, caller=c, allow_zero=True)
        check_int("min_structure_points", self.min_structure_points, caller=c, minimum=3)
        check_int("max_clusters", self.max_clusters, caller=c, minimum=1)
        if not isinstance(self.include_far, bool):
            raise InputError(
                f"The 'include_far' argument of {c} must be True or False. Got {self.include_far!r} instead."
            )

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["kinds"], d["radius_range_m"] = list(self.kinds), list(self.radius_range_m)
        return d


def _elongation(q: np.ndarray, axis: np.ndarray) -> float:
    """Length of the points ``q`` along ``axis`` over their width across it (the largest spread of their
    projections on the plane normal to ``axis``). Unlike the radius, the width is well measured when a camera sees
    only a narrow arc of a pipe."""
    along = q @ axis
    across = q - np.outer(along, axis)
    across = across - across.mean(axis=0)
    width = float(np.ptp(across @ np.linalg.svd(across, full_matrices=False)[2][0])) if len(q) > 2 else 0.0
    return float(np.ptp(along)) / max(width, 1e-12)


def _extrusion_mask(points: np.ndarray, prim: Primitive, inliers: np.ndarray, margin_m: float) -> np.ndarray:
    """True for the ``points`` inside ``prim``'s cross-section (the projections of ``inliers`` across its axis,
    grown by ``margin_m``) extruded between the inliers' ends (a plane: along its longest in-plane direction)."""
    q = points[inliers]
    if prim.kind == "cylinder":
        axis = prim.direction
    else:  # a plane's extrusion direction: its inliers' longest in-plane direction
        centred = q - q.mean(axis=0)
        axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    across = np.column_stack([points @ e1, points @ e2])
    t = points @ axis
    d = cKDTree(across[inliers]).query(across, k=1, distance_upper_bound=margin_m)[0]
    lo, hi = float(t[inliers].min()) - margin_m, float(t[inliers].max()) + margin_m
    return (d <= margin_m) & (t >= lo) & (t <= hi)


def _structure(pts: np.ndarray, normals: np.ndarray, tolerance_m: float, cfg: AttachedConfig,
               seed: int) -> Primitive | None:
    """The primitive of ``cfg.kinds`` with the most inliers that is structure (at least ``min_structure_points``
    inliers; a cylinder elongated along its axis), or None. A cylinder that is not elongated (a wide one spanning
    a pipe and the flat lever in front of it, or a curved backdrop) is fitted again with its radius below half
    of that one's, twice at most."""
    best = None
    for j, kind in enumerate(cfg.kinds):
        lo, hi = cfg.radius_range_m
        for attempt in range(3 if kind == "cylinder" else 1):
            prim = fit_primitive(pts, normals, kind, distance_m=cfg.inlier_distance_factor * tolerance_m,
                                 max_angle_rad=float(np.radians(cfg.max_angle_deg)), radius_range_m=(lo, hi),
                                 iterations=cfg.iterations, seed=seed + 7 * j + attempt)
            if prim is None or len(prim.inliers) < cfg.min_structure_points:
                prim = None
                break
            if kind != "cylinder" or _elongation(pts[prim.inliers], prim.direction) >= cfg.min_structure_elongation:
                break
            hi = min(hi, prim.radius_m) / 2.0
            prim = None
            if hi <= lo:
                break
        if prim is not None and (best is None or len(prim.inliers) > len(best.inliers)):
            best = prim
    return best


def remove_structure(points_xyz_m: np.ndarray, normals_xyz: np.ndarray, *, tolerance_m: float,
                     config: AttachedConfig | None = None, min_piece_points: int = 50,
                     seed: int = 0) -> list[tuple[list[Primitive], list[np.ndarray], int]]:
    """The structure removal of :func:`find_attached` on one cluster, step by step, without recognition.

    Returns one ``(primitives removed so far, pieces, points left)`` per step: ``pieces`` are index arrays into
    ``points_xyz_m`` (the rest clustered at ``tolerance_m``, at least ``min_piece_points`` each, largest first),
    ``points left`` the number of points not removed (in the pieces or in smaller fragments).
    The steps stop after ``config.max_structures`` or when no primitive is structure (``min_structure_points``
    inliers, a cylinder ``min_structure_elongation`` times longer than wide)."""
    caller = "remove_structure"
    cfg = AttachedConfig() if config is None else config
    if not isinstance(cfg, AttachedConfig):
        raise InputError(f"The 'config' argument of {caller} must be an AttachedConfig or None. "
                         f"Got {type(config).__name__} instead.")
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller=caller)
    normals_xyz = as_float_array("normals_xyz", normals_xyz, (len(pts), 3), caller=caller, finite=False)
    check_positive("tolerance_m", tolerance_m, caller=caller)
    check_int("min_piece_points", min_piece_points, caller=caller, minimum=1)
    alive = np.arange(len(pts))
    removed: list[Primitive] = []
    steps = []
    for step in range(cfg.max_structures):
        if len(alive) < cfg.min_structure_points:
            break
        best = _structure(pts[alive], normals_xyz[alive], tolerance_m, cfg, seed + 101 * step)
        if best is None:
            break
        gone = _extrusion_mask(pts[alive], best, best.inliers, cfg.removal_margin_factor * tolerance_m)
        removed.append(best)
        alive = alive[~gone]
        pieces = [alive[p] for p in extract_euclidean_clusters(pts[alive], tolerance_m=tolerance_m,
                                                               min_size=min_piece_points)] if len(alive) else []
        steps.append((list(removed), pieces, len(alive)))
    return steps


def _eligible(outcome: ClusterOutcome, cfg: AttachedConfig) -> bool:
    if outcome.detection is not None:
        return False
    r = outcome.reason
    return (r.startswith("rejected: extent") or r.startswith("rejected: touches the scan border")
            or (cfg.include_far and r.startswith("rejected: distance")))


def _piece_candidate(rec: Any, seg: Any, pts: np.ndarray, cloud_idx: np.ndarray, piece: np.ndarray, seed: int, *,
                     leaf: float, scan_extent: Any, viewpoint: np.ndarray, max_plausible: float) -> tuple | str:
    """``(distance / threshold, cloud, match, label, view_index, border)`` of a piece recognised as an object, or
    why it is not one."""
    cfg = rec.config
    acfg: AttachedConfig = cfg.attached
    q = np.ascontiguousarray(pts[piece])
    extent = principal_extent(q)
    if extent[0] > max_plausible:
        return f"extent {extent[0]:.3f} m, too big for any class"
    border = scan_extent is not None and border_touched(q, scan_extent, viewpoint, float(cfg.border_margin_rad))
    if border and cfg.border == "reject":
        return "touches the scan border"
    cloud = seg.segmented_cloud.select(cloud_idx[piece])
    try:
        desc = rec.db.describe(cloud, seed=seed)
    except DescriptorError as exc:
        return f"no descriptor ({exc})"
    match, label, view_index = rec.classify(desc)
    if label == UNKNOWN_LABEL:
        return f"unknown (nearest {match.nearest_label}, distance {match.distance:.3g} > {match.threshold:.3g})"
    longest = float(np.max(rec.db.class_info(label).size_xyz_m))
    if cfg.size_tolerance is not None and extent[0] > rec.class_size_limit_m(label):
        return f"{label}, extent {extent[0]:.3f} m too big"
    if extent[0] < acfg.min_extent_share * longest:
        return f"{label}, extent {extent[0]:.3f} m < {acfg.min_extent_share:g} x {longest:.3f} m"
    area_share = grid_area_m2(q, leaf) / max(rec.class_view_area_m2(label, leaf), 1e-12)
    if area_share < acfg.min_area_share:
        return f"{label}, surface {area_share:.2f} of its views' < {acfg.min_area_share:g}"
    return (match.distance / match.threshold, cloud, match, label, view_index, border)


def _best_piece(rec: Any, seg: Any, k: int, pts: np.ndarray, steps: list, seed: int, **piece_kw: Any) -> tuple | None:
    """``(primitives removed, (score, j, piece, cloud, match, label, view_index, border, explained))``: the piece of
    the first removal step in ``steps`` that frees a recognised one, nearest its view (distance over threshold),
    or None. ``piece_kw``: the scan-wide arguments of :func:`_piece_candidate`."""
    cloud_idx = seg.cluster_indices[k]
    min_explained = rec.config.attached.min_explained_share
    for prims, pieces, n_left in steps:
        cands = []
        for j, piece in enumerate(pieces):
            explained = 1.0 - (n_left - len(piece)) / len(pts)
            if explained < min_explained:  # the cluster is not this piece and its structure
                cand = f"structure and piece explain {explained:.2f} of the cluster < {min_explained:g}"
            else:
                cand = _piece_candidate(rec, seg, pts, cloud_idx, piece, seed + j, **piece_kw)
            if isinstance(cand, str):
                _log.debug("cluster %d, step %d, piece %d (%d points): %s", k, len(prims), j, len(piece), cand)
            else:
                cands.append((cand[0], j, piece, *cand[1:], explained))
        if cands:
            return prims, min(cands, key=lambda c: (c[0], c[1]))
    return None


def _search_cluster(rec: Any, ctx: ScanContext, seg: Any, outcome: ClusterOutcome, seed: int, timings: dict,
                    **piece_kw: Any) -> ClusterOutcome | None:
    """The outcome of a rejected cluster in which an attached object was found (its structure removed, the piece
    recognised, posed and verified), or None."""
    from ..descriptors import estimate_normals

    cfg = rec.config
    acfg: AttachedConfig = cfg.attached
    k = outcome.cluster_index
    tol = float(seg.resolved.get("cluster_tolerance_m") or cfg.segmentation.cluster_tolerance_m)
    pts = np.ascontiguousarray(seg.clusters[k].points_xyz_m, dtype=np.float64)
    normals = estimate_normals(pts, radius_m=acfg.normal_radius_factor * tol,
                               viewpoint_xyz_m=piece_kw["viewpoint"]).normals_xyz
    steps = remove_structure(pts, normals, tolerance_m=tol, config=acfg,
                             min_piece_points=int(cfg.segmentation.min_cluster_size), seed=seed)
    found = _best_piece(rec, seg, k, pts, steps, seed, **piece_kw)
    if found is None:
        return None
    prims, (_, j, piece, cloud, match, label, view_index, border, explained) = found
    raw_idx = _input_indices_of(seg, seg.cluster_indices[k][piece])
    det = pose_and_verify(rec, ctx, seg, Hypothesis(raw_idx, cloud, label, view_index, match, border),
                          seed=seed + 500, timings=timings, what=f"cluster {k}: attached")
    if det is None:
        return None
    det.extras["attached"] = {"cluster": int(k), "piece_points": int(len(piece)),
                              "piece_centroid_m": [float(v) for v in pts[piece].mean(axis=0)],
                              "explained_share": float(explained),
                              "structures": [p.to_dict() for p in prims]}
    what = ", ".join(f"{p.kind}" + (f" r={1e3 * p.radius_m:.0f} mm" if p.kind == "cylinder" else "")
                     for p in prims)
    reason = (f"detected inside the cluster ({len(piece)} of {len(pts)} points) after removing its attachment "
              f"({what})" + ("" if det.reliable else " (unreliable pose)")
              + (", touches the scan border" if border else ""))
    return dataclasses.replace(outcome, label=label, nearest_label=match.nearest_label, distance=match.distance,
                               threshold=match.threshold, detection=det, reason=reason)


def find_attached(rec: Any, ctx: ScanContext, seg: Any, outcomes: list[ClusterOutcome], detections: list[Detection],
                  *, seed: int, timings: dict) -> tuple[list[ClusterOutcome], list[Detection]]:
    """The attached-objects stage of one scan (module docstring): ``outcomes`` and ``detections`` (those of the
    stages before) with the objects found in the rejected clusters (new lists). ``rec``: the
    :class:`~semslam.pipeline.scan.ScanRecognizer`; ``timings["attached"]`` gets the time (ms, the pose of a found
    object included; that pose also counts in ``timings["pose"]``)."""
    t0 = time.perf_counter()
    cfg = rec.config
    acfg: AttachedConfig = cfg.attached
    outcomes, detections = list(outcomes), list(detections)
    timings["attached"] = 0.0
    eligible = sorted((o for o in outcomes if _eligible(o, acfg)), key=lambda o: -o.n_points)[:acfg.max_clusters]
    if not eligible:
        return outcomes, detections
    tol = float(seg.resolved.get("cluster_tolerance_m") or cfg.segmentation.cluster_tolerance_m)
    piece_kw = {"leaf": float(seg.resolved.get("voxel_leaf_m") or tol / 4.0),
                "scan_extent": scan_footprint(ctx.border_scan, cfg),
                "viewpoint": np.ascontiguousarray(ctx.scan.viewpoint_xyz_m, dtype=np.float64),
                "max_plausible": rec.max_plausible_extent_m()}
    for n, outcome in enumerate(eligible):
        found = _search_cluster(rec, ctx, seg, outcome, seed + 1000 * n, timings, **piece_kw)
        if found is not None:
            detections.append(found.detection)
            outcomes[outcome.cluster_index] = found
    timings["attached"] = (time.perf_counter() - t0) * 1e3
    return outcomes, detections
