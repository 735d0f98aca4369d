"""Pose of a recognised object (:func:`estimate_object_pose`): by default a global search over a deterministic
SO(3) grid scored with the model's distance field and a visibility (free-space) term (:mod:`.search`; ranked
coarse to fine: 512 then the children of the best 64 in the 4096 grid), point-to-plane ICP of the best distinct
hypotheses (numba, on the distance field's nearest-point candidates:
:func:`semslam.registration._icp_kernels.icp_plane_field`, see :mod:`.icp_refine`), selection by the same score
after ICP, then the orientation canonicalised under the object's symmetry and a 6x6 covariance (order x y z roll
pitch yaw, see :mod:`.covariance`). The papers' FPFH + prerejective RANSAC remains available
(``PoseConfig(coarse_method="ransac")``); a prior pose (``init_T_scanner_object``) skips the search.

The model is prepared once per class (:func:`.model.prepare_pose_model`): either the matched database view, or
all views of the class fused in the object frame (better: see ``benchmarks/pose_accuracy.py``). The cluster is
the SOURCE and the model the TARGET, so every cluster point has a model point to match and the ICP uses the
model's clean normals; the result is inverted into ``T_scanner_object``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import small_gicp

from .._validation import as_float_array
from ..cloud import PointCloud
from ..errors import InputError, RegistrationError
from ..geometry import RigidTransform
from ..symmetry import Symmetry
from ..registration._icp_kernels import icp_plane_field_batch
from ..registration.ambiguity import half_turns
from ..registration.coarse import align_prerejective
from ..registration.result import RegistrationResult
from ..registration.upright import upright_rotations
from ._search_inputs import checked_search_inputs
from .covariance import calibration_of, pose_covariance, widen_untrusted
from .icp_refine import (  # noqa: F401 (_final_score, _icp_field_nearest: tests use them here)
    _final_score, _final_scores, _icp_field_nearest, _icp_small_gicp, _refine, _small_gicp_T, back_facing_shares)
from .model import PoseConfig, PoseModel, _nearest, prepare_pose_model
from .search import resting_height_bands, search_hypotheses
from .selection import admissible_alternative, choose_hypothesis, margin_and_alternatives

__all__ = ["PoseConfig", "PoseEstimate", "PoseModel", "estimate_object_pose", "pose_verdict", "prepare_pose_model",
           "back_facing_shares"]

_CALLER = "estimate_object_pose"

@dataclass(frozen=True, eq=False)
class PoseEstimate:
    """The pose of a recognised object in the scanner frame.

    Parameters
    ----------
    T_scanner_object : RigidTransform
        Maps object-frame points into the scanner frame; orientation canonicalised under the symmetry.
    covariance_6x6 : ndarray (6, 6)
        Covariance of x y z (m) roll pitch yaw (rad) of ``T_scanner_object``. A rotation about a continuous
        symmetry axis has ``PoseConfig.unobservable_variance_rad2`` (1e4 rad^2) along it.
    fitness : float
        Share of the cluster points within ``icp_max_correspondence_m`` of the model after ICP.
    rmse_m : float
        RMS point-to-point distance of those inliers.
    reliable : bool
        Fitness >= ``min_fitness``, rmse <= ``max_rmse_m``, visibility cost <= ``max_visibility`` and score
        margin >= ``min_score_margin`` (grid search), or the RANSAC converged (``coarse_method="ransac"``).
    visibility : float
        Share of the model points predicted visible that contradict the scan (grid search; NaN otherwise).
    score_margin : float
        Final score of the best hypothesis not equivalent to the chosen one (> 10 degrees modulo the symmetry
        or > 1 cm away) minus the chosen one's (inf when every refined hypothesis converged to it).
    """

    T_scanner_object: RigidTransform
    covariance_6x6: np.ndarray
    fitness: float
    rmse_m: float
    reliable: bool
    timings_ms: dict = field(default_factory=dict)
    n_points: int = 0
    coarse_fitness: float = float("nan")
    icp_converged: bool = False
    residual_sigma_m: float = float("nan")
    extras: dict = field(default_factory=dict)
    visibility: float = float("nan")
    score_margin: float = float("nan")
    #: well aligned (fitness, rmse, visibility) but another, non-equivalent orientation scores within
    #: ``min_score_margin``: the position is trustworthy, the orientation is not (see :func:`pose_verdict`)
    ambiguous: bool = False

    def to_dict(self) -> dict:
        return {
            "T_scanner_object": self.T_scanner_object.to_dict(), "covariance_6x6": self.covariance_6x6.tolist(),
            "covariance_order": ["x", "y", "z", "roll", "pitch", "yaw"], "fitness": float(self.fitness),
            "rmse_m": float(self.rmse_m), "reliable": bool(self.reliable), "n_points": int(self.n_points),
            "coarse_fitness": float(self.coarse_fitness), "icp_converged": bool(self.icp_converged),
            "residual_sigma_m": float(self.residual_sigma_m), "visibility": float(self.visibility),
            "score_margin": float(self.score_margin), "ambiguous": bool(self.ambiguous),
            "timings_ms": {k: float(v) for k, v in self.timings_ms.items()},
        }


def pose_verdict(coarse_ok: bool, fitness: float, rmse_m: float, visibility: float, score_margin: float,
                 cfg: "PoseConfig") -> tuple[bool, bool]:
    """``(reliable, ambiguous)``: the one rule for trusting a pose.

    *Aligned*: fitness >= ``min_fitness``, rmse <= ``max_rmse_m`` and (when measured) visibility cost <=
    ``max_visibility``. *Reliable*: aligned, the coarse search converged and (when the visibility is measured,
    i.e. the grid search) the score margin >= ``min_score_margin``. *Ambiguous*: aligned but not reliable because
    another, non-equivalent orientation scores within the margin."""
    seen = bool(np.isfinite(visibility))
    aligned = bool(
        fitness >= cfg.min_fitness and rmse_m <= cfg.max_rmse_m and not (seen and visibility > cfg.max_visibility)
    )
    reliable = bool(coarse_ok and aligned and (not seen or score_margin >= cfg.min_score_margin))
    ambiguous = bool(not reliable and aligned and np.isfinite(score_margin) and score_margin < cfg.min_score_margin)
    return reliable, ambiguous


def estimate_object_pose(
    cluster_points_scanner: Any,
    model_points_object: Any,
    *,
    symmetry: Symmetry | None = None,
    config: PoseConfig | None = None,
    seed: Any = 0,
    viewpoint_xyz_m: Any = (0.0, 0.0, 0.0),
    canonical_reference: Any = None,
    init_T_scanner_object: Any = None,
    up_scanner: Any = None,
    up_object: Any = None,
    partial: bool = False,
    surroundings_scanner: Any = None,
    admissible: Any = None,
    scene_scanner: Any = None,
    floor_scanner: Any = None,
) -> PoseEstimate:
    """Estimate ``T_scanner_object`` of a recognised object and its covariance.

    By default a grid search over SO(3) then ICP of its best hypotheses; FPFH + prerejective RANSAC then ICP with
    ``PoseConfig(coarse_method="ransac")``; ICP alone from ``init_T_scanner_object`` when given.

    Parameters
    ----------
    cluster_points_scanner : PointCloud or array-like (N, 3)
        The segmented cluster in the scanner frame (metres). A PointCloud's viewpoint is the scanner origin.
    model_points_object : PoseModel, PointCloud, sequence of PointCloud or array-like (M, 3)
        The class model in the object frame; pass a :class:`PoseModel` to reuse its preparation.
    symmetry : Symmetry, optional
        The class symmetry (``none`` by default): the orientation is canonicalised and a rotation about a
        continuous axis gets ``config.unobservable_variance_rad2``.
    config : PoseConfig, optional
        Ignored when a PoseModel is given (the model's config is used).
    seed : int or numpy Generator
        RANSAC seed (``coarse_method="ransac"``; the grid search is deterministic).
    viewpoint_xyz_m : array-like (3,)
        Scanner origin in the scanner frame when the cluster is an array.
    canonical_reference : optional
        Passed to :meth:`Symmetry.canonicalize` (rotation for discrete, direction for continuous; scanner frame).
    init_T_scanner_object : array-like (4, 4) or RigidTransform, optional
        A prior pose (e.g. predicted from the map by the SLAM): the global search is skipped, ICP starts from it.
    up_scanner, up_object : array-like (3,), optional
        The up direction in the scanner frame (the vehicle's attitude, a level camera) and in the object frame
        (``db build --fuse --up``). Given both, the grid search scans only orientations that keep them within a few
        degrees of each other (:func:`~semslam.registration.upright.upright_rotations`), not all of SO(3).
        ``up_object`` may be several directions (k, 3) (a part resting on either face): a near-equal fit of another
        one makes the pose ambiguous.
    partial : bool
        Only part of the object (border-cut, a union of clusters): the grid search also starts the translation on a
        grid across the object (``PoseConfig.partial_start_step_m``; off at 0); so does a whole cluster whose search
        ends unaligned, in a second search.
    surroundings_scanner : array-like (K, 3), optional
        The scan's other objects about the cluster: seen surfaces for the search's visibility term (not the
        verdict's), ``PipelineConfig.pose_surroundings``.
    admissible : callable, optional
        A test of ``T_scanner_object`` (4, 4) -> bool (the floor check): see :func:`.selection.admissible_alternative`.
    scene_scanner : pair of array-likes (S, 3), (K, 3), optional
        The whole scan and its objects, for a border-cut cluster: the search's visibility term (not the verdict's)
        uses the scene's image, where the model beyond the border is unknown (``PipelineConfig.pose_border_scene``).
    floor_scanner : pair (normal (3,), d), optional
        The floor ``n . x + d = 0`` (scanner on its positive side) it rests on: see :data:`.search.MAX_FREE_STARTS`.

    Returns a :class:`PoseEstimate`. Raises a RegistrationError when the cluster has fewer than
    ``config.min_points`` points, an InputError on a bad ``symmetry``, cluster, viewpoint or search input, one up
    direction only or a model unprepared.
    """
    t0 = time.perf_counter()
    model = model_points_object if isinstance(model_points_object, PoseModel) else \
        prepare_pose_model(model_points_object, config)
    cfg = model.config
    sym = _checked_symmetry(symmetry)
    cluster, vp = _checked_cluster(cluster_points_scanner, viewpoint_xyz_m, cfg)
    t1 = time.perf_counter()
    alignment = _align_cluster(cluster, vp, model, cfg, sym, seed, init_T_scanner_object, up_scanner, up_object,
                               *checked_search_inputs(partial, surroundings_scanner, admissible, scene_scanner,
                                                      floor_scanner))
    return _estimate_of(cluster, model, cfg, sym, alignment, canonical_reference, t0, t1)


@dataclass
class _Alignment:
    """The cluster aligned onto the model (before the covariance): the final ICP result, whether the coarse
    step converged and its fitness, the visibility cost and score margin (grid search; NaN otherwise), extras,
    the nearest model points of the final ICP (or None) and the end times of the coarse step and the ICP."""

    fine: RegistrationResult
    coarse_ok: bool
    coarse_fitness: float
    visibility: float
    margin: float
    extras: dict
    nearest: Any
    t2: float
    t3: float


def _checked_symmetry(symmetry: Any) -> Symmetry:
    sym = symmetry if symmetry is not None else Symmetry()
    if not isinstance(sym, Symmetry):
        raise InputError(f"The 'symmetry' argument of {_CALLER} must be a Symmetry. Got {type(sym).__name__} instead.")
    return sym


def _checked_cluster(
    cluster_points_scanner: Any, viewpoint_xyz_m: Any, cfg: PoseConfig
) -> tuple[np.ndarray, np.ndarray]:
    """The cluster points (N, 3) and the scanner origin (3,), both in the scanner frame; a RegistrationError
    when the cluster has fewer than ``cfg.min_points`` points."""
    if isinstance(cluster_points_scanner, PointCloud):
        cluster, vp = cluster_points_scanner.points_xyz_m, cluster_points_scanner.viewpoint_xyz_m
    else:
        cluster = as_float_array("cluster_points_scanner", cluster_points_scanner, (None, 3), caller=_CALLER)
        vp = as_float_array("viewpoint_xyz_m", viewpoint_xyz_m, (3,), caller=_CALLER)
    vp = np.asarray(vp, dtype=np.float64)
    if len(cluster) < cfg.min_points:
        raise RegistrationError(f"The cluster given to {_CALLER} has {len(cluster)} points; at least "
                                f"{cfg.min_points} are needed (PoseConfig.min_points).")
    return cluster, vp


def _align_cluster(cluster: np.ndarray, vp: np.ndarray, model: PoseModel, cfg: PoseConfig, sym: Symmetry, seed: Any,
                   init_T_scanner_object: Any, up_scanner: Any, up_object: Any, partial: bool = False,
                   surroundings: np.ndarray | None = None, admissible: Any = None, scene: Any = None,
                   floor: Any = None) -> _Alignment:
    """ICP from the prior pose when one is given, else FPFH RANSAC then ICP (``coarse_method="ransac"``), else
    the grid search with ICP of its best hypotheses (the default)."""
    nan = float("nan")
    if init_T_scanner_object is not None:
        T_prior = init_T_scanner_object if isinstance(init_T_scanner_object, RigidTransform) else \
            RigidTransform(init_T_scanner_object)
        fine = _refine(cluster, model, cfg, T_prior.inverse().matrix)
        t2 = time.perf_counter()
        return _Alignment(fine, True, nan, nan, nan, {}, None, t2, t2)
    if cfg.coarse_method == "ransac":
        coarse, n_voxels, t2, _ = _coarse_ransac(cluster, vp, model, cfg, seed)
        fine = _refine(cluster, model, cfg, coarse.T_target_source.matrix)
        extras = {"coarse": coarse.to_dict(), "n_voxels": n_voxels}
        return _Alignment(fine, coarse.converged, coarse.fitness, nan, nan, extras, None, t2, time.perf_counter())
    upright, ups = None, None
    if up_scanner is not None or up_object is not None:
        if up_scanner is None or up_object is None:
            raise InputError(f"{_CALLER} needs both 'up_scanner' and 'up_object' (or neither). "
                             f"Got up_scanner={up_scanner!r}, up_object={up_object!r}.")
        ups = np.asarray(up_object, dtype=float)
        ups = ups.reshape(1, -1) if ups.ndim == 1 else ups
        if ups.ndim != 2 or ups.shape[1] != 3 or not len(ups):
            raise InputError(f"The 'up_object' argument of {_CALLER} must be a 3-vector or a list of them. "
                             f"Got shape {np.shape(up_object)} instead.")
        # several possible ups (a part that rests on either face): the orientations keeping any of them up
        upright = np.concatenate([upright_rotations(up_scanner, u, caller=_CALLER) for u in ups])
    def search(part: bool):
        heights = (floor, resting_height_bands(model.hull_points, ups, cfg.partial_start_step_m)) if part and \
            floor is not None and ups is not None else None
        return _grid_search(cluster, vp, model, cfg, sym, upright, part, surroundings, admissible, scene, heights)

    found = search(partial)
    if not partial and cfg.partial_start_step_m > 0 and found[0].fitness < cfg.min_fitness:
        # a whole cluster whose centroid starts all lie beyond the steps' 3 cm pull-in (a tilted hard hat's seen
        # centroid 4-5 cm from every start) ends unaligned: searched again from the grid of a partial one
        again = search(True)
        if again[3]["score"] < found[3]["score"]:
            found = again
        found[3]["searched_again"] = True
    fine, vis, margin, extras, t2, nearest = found
    return _Alignment(fine, True, extras["coarse_fitness"], vis, margin, extras, nearest, t2, time.perf_counter())


def _estimate_of(cluster: np.ndarray, model: PoseModel, cfg: PoseConfig, sym: Symmetry, a: _Alignment,
                 canonical_reference: Any, t0: float, t1: float) -> PoseEstimate:
    """The PoseEstimate of an alignment: canonical pose, covariance (widened when untrusted) and verdict."""
    T_os = a.fine.T_target_source.matrix  # T_object_scanner
    alternatives = a.extras.pop("_alternatives", ())
    (cov, T_so_can), sigma2 = _covariance(cluster, model, cfg, sym, T_os, canonical_reference, a.nearest,
                                          alternatives=alternatives)
    t4 = time.perf_counter()
    fine, vis, margin = a.fine, a.visibility, a.margin
    reliable, ambiguous = pose_verdict(a.coarse_ok, fine.fitness, fine.inlier_rmse_m, vis, margin, cfg)
    aligned = bool(fine.fitness >= cfg.min_fitness and fine.inlier_rmse_m <= cfg.max_rmse_m
                   and not (np.isfinite(vis) and vis > cfg.max_visibility))
    cov = widen_untrusted(cov, aligned=aligned, ambiguous=ambiguous, radius_m=model.radius_m)
    return PoseEstimate(
        T_scanner_object=RigidTransform(T_so_can), covariance_6x6=cov, fitness=fine.fitness,
        rmse_m=fine.inlier_rmse_m, reliable=reliable, n_points=len(cluster), coarse_fitness=a.coarse_fitness,
        icp_converged=fine.converged, residual_sigma_m=float(np.sqrt(sigma2)), visibility=vis, score_margin=margin,
        ambiguous=ambiguous,
        timings_ms={"coarse": 1e3 * (a.t2 - t1), "icp": 1e3 * (a.t3 - a.t2), "covariance": 1e3 * (t4 - a.t3),
                    "total": 1e3 * (t4 - t0)},
        extras=a.extras,
    )


def _grid_search(cluster, vp, model: PoseModel, cfg: PoseConfig, sym: Symmetry, upright: np.ndarray | None = None,
                 partial: bool = False, surroundings: np.ndarray | None = None, admissible=None, scene=None,
                 start_heights=None):
    """SO(3) grid search, ICP of the best distinct hypotheses, selection by the final score. Returns the final
    RegistrationResult, its visibility cost, the score margin, extras, the search's end time and the nearest
    model points of the final alignment (``(p, d, j)`` of :func:`_icp_field_nearest`, or None)."""
    from ..segmentation.voxel import voxel_downsample

    if model.distance_field is None:
        raise InputError(f"The model given to {_CALLER} was prepared without a distance field; prepare it with "
                         "coarse_method='grid'.")
    pts = voxel_downsample(cluster, cfg.search_voxel_m)
    if len(pts) < 3:
        pts = cluster
    rotations, hierarchy = (model.rotations, model.rotation_hierarchy) if upright is None else (upright, None)
    hyps, image = search_hypotheses(
        pts, vp, model.distance_field, rotations, model.visibility_points, model.visibility_normals,
        object_radius_m=model.radius_m, symmetry=sym, image_cell_m=cfg.image_cell_m, tau_m=cfg.fit_tau_m,
        visibility_weight=cfg.visibility_weight, visibility_tol_m=cfg.visibility_tol_m,
        truncations_m=cfg.translation_steps_m, n_keep=cfg.n_refine,
        n_candidates=cfg.n_candidates, n_coarse_points=cfg.n_coarse_points, hierarchy=hierarchy,
        n_coarse_keep=cfg.n_coarse_keep, view_centroids=model.view_centroids,
        local_steps_rad=tuple(np.radians(cfg.local_refine_steps_deg)) if model.radius_m >= cfg.local_refine_min_radius_m
        else (), camera_offset_m=cfg.camera_offset_m, partial_step_m=cfg.partial_start_step_m if partial else 0.0,
        surroundings=surroundings, scene=scene, start_heights=start_heights)
    t2 = time.perf_counter()
    field_icp = cfg.icp_backend == "field" and cfg.icp_method == "plane" and model.distance_field.index is not None
    wide = cfg.icp_wide_correspondence_m or cfg.icp_max_correspondence_m
    sg_pts = None
    Ts = []
    # the half-turns of the search's best hypothesis are refined and scored with the others: a near-equal flip the
    # search did not keep still makes the pose ambiguous (a wide covariance) instead of confidently wrong
    inits = [h.T_object_scanner for h in hyps] + (half_turns(hyps[0].T_object_scanner, pts) if hyps and upright is None
                                                  else [])
    hyps = list(hyps) + [hyps[0]] * (len(inits) - len(hyps))
    if field_icp and hyps:  # ICP of the search points (fast), the hypotheses on both cores
        f = model.distance_field
        Ts = list(icp_plane_field_batch(
            np.ascontiguousarray(pts, dtype=np.float64), np.stack(inits), f.params,
            f.index, model.icp_target.points_xyz_m, model.normals_object, float(wide), int(cfg.icp_max_iterations),
            1e-4, 1e-5)[0])
    for T0 in inits if not field_icp else ():
        if model.icp_target.method in ("plane", "point"):  # small_gicp directly: one source cloud, no statistics
            sg_pts = small_gicp.PointCloud(np.ascontiguousarray(pts, dtype=np.float64)) if sg_pts is None else sg_pts
            Ts.append(_small_gicp_T(sg_pts, model, cfg, T0, wide))
        else:
            Ts.append(_icp_small_gicp(pts, model, cfg, T0, wide).T_target_source.matrix)
    # scored on the whole cluster
    back = back_facing_shares(cluster, vp, model, Ts) if cfg.back_facing_weight > 0 else np.zeros(len(Ts))
    refined = [(fit + cfg.visibility_weight * vis + cfg.back_facing_weight * b, fit, vis, T, h)
               for (fit, vis), T, h, b in zip(_final_scores(cluster, image, model, cfg, Ts), Ts, hyps, back)]
    refined.sort(key=lambda x: x[0])
    # a depth twin (search._depth_twin) widens the covariance only, unless the pose is inadmissible (selection.py)
    best, judged = choose_hypothesis(refined), refined
    final, nearest = _final_icp(cluster, model, cfg, best[3], field_icp)
    if admissible is not None and not admissible(np.linalg.inv(final.T_target_source.matrix)):
        alt = admissible_alternative(refined, best, admissible)
        other = _final_icp(cluster, model, cfg, alt[0][3], field_icp) if alt is not None else None
        if other is not None and admissible(np.linalg.inv(other[0].T_target_source.matrix)):
            (best, judged), (final, nearest) = alt, other
    margin, distinct = margin_and_alternatives(judged, best, sym)
    extras = {"coarse_fitness": 1.0 - best[4].fit, "score": best[0], "fit_cost": best[1],
              "n_hypotheses": len(rotations), "search_points": len(pts), "upright": upright is not None,
              "hypotheses": [(float(s), float(f), float(v)) for s, f, v, _, _ in refined],
              "inadmissible_hypotheses": len(refined) - len(judged),
              # for the covariance's hypothesis spread (popped by estimate_object_pose)
              "_alternatives": distinct}
    # the verdict's visibility is the cluster's own: the surroundings choose between the hypotheses, they do not make
    # a pose more trustworthy (a wrong pose overlapping the rest of the object would otherwise look clean)
    own = scene is None and (surroundings is None or not len(surroundings))
    vis = best[2] if own else _cluster_visibility(pts, vp, model, cfg, best[3], cluster)
    return final, vis, margin, extras, t2, nearest


def _final_icp(cluster: np.ndarray, model: PoseModel, cfg: PoseConfig, T_os: np.ndarray, field_icp: bool):
    """The final ICP of the whole cluster from ``T_os`` (``T_object_scanner``): the RegistrationResult and the
    nearest model points of :func:`_icp_field_nearest` (None with small_gicp)."""
    if field_icp:
        return _icp_field_nearest(cluster, model, cfg, T_os, cfg.icp_max_correspondence_m)
    return _icp_small_gicp(cluster, model, cfg, T_os, cfg.icp_max_correspondence_m), None


def _cluster_visibility(pts: np.ndarray, vp: np.ndarray, model: PoseModel, cfg: PoseConfig, T_os: np.ndarray,
                        cluster: np.ndarray) -> float:
    """The visibility cost of ``T_os`` (``T_object_scanner``) against the range image of the search points ``pts``
    alone (the cluster, without its surroundings), as :func:`_final_scores` computes it."""
    from .search_index import RangeImage

    image = RangeImage.build(pts, vp, cell_m=cfg.image_cell_m).with_camera(cfg.camera_offset_m)
    return _final_scores(cluster, image, model, cfg, [T_os])[0][1]


def _covariance(cluster, model: PoseModel, cfg: PoseConfig, sym: Symmetry, T_os: np.ndarray, canonical_reference,
                nearest=None, *, alternatives=()):
    """Canonicalised ``T_scanner_object`` and its xyz-rpy covariance (:func:`.covariance.pose_covariance`: the
    point-to-plane information at the residual scale over the effectively independent points, floors, and the
    spread of the search's ``alternatives``). ``nearest``: ``(p, d, j)`` of :func:`_icp_field_nearest` under
    ``T_os`` (computed here when None)."""
    if nearest is None:
        p = cluster @ T_os[:3, :3].T + T_os[:3, 3]
        d, j = _nearest(model, p, cfg.icp_max_correspondence_m)
    else:
        p, d, j = nearest
    cal = calibration_of(cfg)
    cov, T_so_can, diag = pose_covariance(p, d, j, model.icp_target.points_xyz_m, model.normals_object, T_os, sym,
                                          canonical_reference=canonical_reference, alternatives=alternatives,
                                          calibration=cal, unobservable_variance_rad2=cfg.unobservable_variance_rad2,
                                          distances_at=lambda q: _nearest(model, q, cfg.icp_max_correspondence_m)[0],
                                          extent_m=model.radius_m)
    return (cov, T_so_can), diag["sigma2_m2"]


def _coarse_ransac(cluster, vp, model: PoseModel, cfg: PoseConfig, seed):
    """FPFH of the voxelised cluster and prerejective RANSAC onto the model (from the centroid guess)."""
    from ..descriptors.fpfh import compute_fpfh
    from ..descriptors import estimate_normals
    from ..segmentation.voxel import voxel_downsample

    if model.coarse_features is None:
        raise InputError(f"The model given to {_CALLER} was prepared without FPFH features; prepare it with "
                         "coarse_method='ransac'.")
    down = voxel_downsample(cluster, cfg.voxel_m)
    if len(down) < 3:
        raise RegistrationError(
            f"The cluster given to {_CALLER} has {len(down)} voxels of {cfg.voxel_m} m; at least 3 are needed."
        )
    nrm = estimate_normals(down, radius_m=cfg.normal_radius_m, viewpoint_xyz_m=vp).normals_xyz
    feats = compute_fpfh(down, nrm, radius_m=cfg.feature_radius_m)
    t2 = time.perf_counter()
    coarse = align_prerejective(
        down, feats, model.coarse_points, model.coarse_features, max_iterations=cfg.coarse_max_iterations,
        k_correspondences=cfg.k_correspondences, similarity=cfg.similarity,
        max_correspondence_m=cfg.coarse_max_correspondence_m, inlier_fraction=cfg.inlier_fraction, seed=seed,
        init_T="centroid", target_tree=model.coarse_tree, target_feature_tree=model.feature_tree,
        selection=cfg.coarse_selection)
    return coarse, len(down), t2, time.perf_counter()
