"""Object models for :func:`.estimate.estimate_object_pose`: the settings (:class:`PoseConfig`) and the per-class
preparation (:func:`prepare_pose_model`: distance field, visibility samples, SO(3) grid and translation starts
for the grid search, or voxelised points + FPFH for the papers' RANSAC; the ICP target with normals).

A model is prepared once per class and reused for every cluster of that class; the expensive parts (distance
field, view centroids) are cached on disk (:meth:`.search.DistanceField.build_cached`).
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass, field
from typing import Any, Sequence

import numpy as np
import small_gicp
from scipy.spatial import cKDTree

from .._validation import as_float_array, check_choice, check_int, check_positive
from ..cloud import PointCloud
from ..errors import InputError, RegistrationError
from ..registration.icp import ICP_METHODS, IcpTarget, prepare_icp_target
from .search import TRANSLATION_STEPS_M, DistanceField, RadiusGrid, RotationHierarchy, ViewCentroids, so3_grid


@dataclass(frozen=True)
class PoseConfig:
    """Settings of :func:`estimate_object_pose` (lengths in metres, angles in radians)."""

    #: ``"grid"`` (SO(3) grid + distance field + visibility, default) or ``"ransac"`` (FPFH + prerejective RANSAC).
    coarse_method: str = "grid"
    #: Orientations of the SO(3) grid (super-Fibonacci; 4096 ~ 10 degrees apart).
    n_rotations: int = 4096
    #: Voxel leaf of the cluster for the grid search.
    search_voxel_m: float = 0.008
    #: Cell of the model's distance field.
    field_cell_m: float = 0.0025
    #: Truncation of the fit cost ``mean min(d, tau)^2 / tau^2``.
    fit_tau_m: float = 0.006
    #: Voxel leaf of the model points used by the visibility term.
    visibility_voxel_m: float = 0.006
    #: Weight of the visibility cost (share of predicted-visible model points contradicting the scan).
    visibility_weight: float = 1.0
    #: Weight of the back-facing share in the final score of the refined hypotheses: the share of cluster points
    #: whose nearest model point faces away from the sensor. It rejects an object turned around (seen from
    #: behind it would show its other side; the visibility term cannot, since no model point is then predicted
    #: visible): on the real RealSense globe valve, the handwheel fits from behind as well as from the front.
    back_facing_weight: float = 1.0
    #: A predicted model point this much in front of the observed surface is in free space.
    visibility_tol_m: float = 0.01
    #: Angular cell of the cluster's range image, as a length at the cluster's range.
    image_cell_m: float = 0.008
    #: The camera of a triangulation laser scanner, from the laser (the scan's viewpoint), in the scan's frame
    #: (``ScannerSpec.camera_xyz_m`` of the vehicle file): the visibility term then expects no return where the
    #: camera cannot see the laser's spot (its shadows). None (default): one viewpoint. Measured on the shared real
    #: models (benchmarks/history/real-models.md, session 15): recall +0.9 points held out, but the pose NEES
    #: 6.3 -> 21: the shadows explain the misses of the large wheel valve, and leave its half-turn undecided.
    camera_offset_m: tuple | None = None
    #: Translation starts of a partial cluster (cut by the scan's border, or a union of clusters:
    #: ``estimate_object_pose(partial=True)``):
    #: besides the centroid rules, a grid of this spacing across the object's radius, across the view (twice it
    #: along the view: :func:`.search._partial_offsets`). A strip of a flange's rim has its centroid ~10 cm from
    #: where the whole view's centroid would be, beyond the 3 cm that the translation steps pull in. 0 (default):
    #: the centroid rules only. 0.04 m found the shared slip-on flange's border strips (fitness 0.62-0.88 -> 1.0,
    #: within 4 mm) and, along the view, the valve panel front's (a ring on its rim, its lower arc ~10 cm behind
    #: the first start; benchmarks/history/real-models.md). A whole cluster whose search ends unaligned (fitness
    #: below ``min_fitness``) is searched again from the grid (DAVE's tilted hard hat, session 38).
    partial_start_step_m: float = 0.0
    #: Coarse-to-fine ranking: a grid of ``n_coarse_rotations`` is ranked first, and only the fine-grid
    #: children of its ``n_coarse_keep`` best orientations are ranked next (0 = rank the whole fine grid).
    #: 512 / 64 (was 1024 / 128: the same ~512 fine orientations ranked, half the coarse pass) with
    #: ``n_candidates`` 96 (was 128): benchmarks/pose_accuracy.py --models pipeline unchanged (2.20 deg /
    #: 1.83 mm / 95.1 % / NEES 6.23 against 2.21 / 1.83 / 95.1 / 6.27; the same wrong and flagged counts;
    #: seeds 3 4 5: 2.91 / 1.79 / 95.1 / 6.19 against 2.91 / 1.72 / 95.1 / 6.07), ~15 % less pose CPU time.
    n_coarse_rotations: int = 512
    n_coarse_keep: int = 64
    #: Cluster points used to rank every grid orientation (the first, coarse pass of the search).
    n_coarse_points: int = 32
    #: Best orientations of the coarse pass fitted again with every search point and given the visibility term.
    #: 128 (was 256) with ``n_refine`` 3 (was 4): benchmarks/pose_accuracy.py --models pipeline unchanged within
    #: noise (2.21 deg / 1.83 mm / 95.1 % / NEES 6.27 against 2.20 / 1.90 / 95.1 / 6.30), ~20 % less pose time;
    #: then 96 (see ``n_coarse_rotations``; 64 leaves one more wrong pose unflagged).
    n_candidates: int = 96
    #: Distinct grid hypotheses refined by ICP and compared by their final score.
    n_refine: int = 3
    #: Local rotation refinement of each of those hypotheses before the ICP, for models of RMS radius
    #: (``PoseModel.radius_m``) at least ``local_refine_min_radius_m``: per step (degrees), the best of the
    #: hypothesis and its 26 neighbours on a 3 x 3 x 3 grid of rotations +-step about each axis, translation-aligned
    #: and scored as in the search (:func:`.search._local_refine`; () = none); the original and the refined
    #: hypothesis both go to the ICP. The SO(3) grid is ~10 degrees apart: for a large object a start that far off
    #: moves its far points by more than the wide ICP pass's 2 cm, and the ICP stops in a wrong minimum. On the
    #: 13-class catalogue's gate valve (RMS radius 11.7 cm; the handwheel 14 cm from its centre) an orientation
    #: near the truth is among the search's best three by score in every union measured, but it is 10-13 degrees
    #: off and its ICP ends at fitness 0.84-0.90 where the true pose fits at 0.99 (issue #15;
    #: ``tests/pose/test_pose_local_refine.py``). The built-in fittings (RMS radius <= 5.2 cm) are below the radius
    #: and unchanged.
    local_refine_steps_deg: tuple = (8.0, 4.0, 2.0)
    local_refine_min_radius_m: float = 0.09
    #: The truncations (m) of the search's translation-only steps, one step each (:func:`.search.search_hypotheses`:
    #: all but the last two align every start on ``n_coarse_points`` points, the last two the candidates on all;
    #: the local refinement takes all but the first). A step moves a start by the mean offset of the points to the
    #: model, so along a plate only the points off it (a tube, a post) pull: a border-cut torque-tool receptacle
    #: (a 28 cm plate and a tube) seen mostly as plate ended 26 mm off at its true orientation with one step per
    #: truncation (fit cost 0.37, the true pose's 0.08), 2.7 mm off with two at 3 and 1.5 cm:
    #: ``(0.03, 0.03, 0.015, 0.015, 0.008, 0.008, 0.006)``. In ``seabed`` it raised recall on
    #: benchmarks/unseen_parts.py (seeds 0-2 pooled) from 81.6 to 84.7 %, but held out it cost precision on border-cut
    #: clusters for no recall (the catalogue's seed 2: 95.3 -> 94.4 %, below the goal; the shared models' seeds 1
    #: and 2: 99.1 / 99.0 -> 98.2 / 98.0 %), so it is not a default (benchmarks/history/real-models.md, session 28).
    translation_steps_m: tuple = TRANSLATION_STEPS_M
    #: Voxel leaf of the cluster and model for the features and the RANSAC (``coarse_method="ransac"``).
    voxel_m: float = 0.004
    normal_radius_m: float = 0.01
    feature_radius_m: float = 0.02
    coarse_max_iterations: int = 2000
    k_correspondences: int = 3
    similarity: float = 0.9
    coarse_max_correspondence_m: float = 0.006
    inlier_fraction: float = 0.25
    #: ``"msac"`` (most inliers, truncated cost) or ``"error"`` (PCL's rule).
    coarse_selection: str = "msac"
    icp_method: str = "plane"
    #: ICP of the grid search (its hypotheses, then the final alignment of the whole cluster): ``"field"``
    #: (default) runs small_gicp's point-to-plane optimiser in numba with the nearest neighbour taken among
    #: the 8 model points nearest to its 2.5 mm cell of the distance field (exact but in rare cases): no
    #: per-call overhead, ~10x faster on these small clusters, same accuracy and reliability flags
    #: (``benchmarks/pose_accuracy.py``); ``"small_gicp"`` calls small_gicp (KD-tree), as do ``icp_method``
    #: other than ``"plane"`` and the RANSAC path.
    icp_backend: str = "field"
    icp_max_correspondence_m: float = 0.006
    #: A first, wider ICP pass (0 = none) that pulls the coarse estimate into the fine pass's basin.
    icp_wide_correspondence_m: float = 0.02
    icp_max_iterations: int = 30
    #: Neighbours for the model normals (ICP and covariance).
    model_normals_k: int = 15
    #: Voxel leaf of the model used by ICP (0 = every model point).
    model_icp_voxel_m: float = 0.0015
    #: Multiplies the Gauss-Newton covariance, itself counted over the effectively independent residuals
    #: (:class:`~semslam.pose.covariance.CovarianceCalibration`, issue 29: ``benchmarks/real_models.py``).
    covariance_inflation: float = 1.0
    #: Floors added to the variances (per axis, in the object frame): no direction is more certain than this
    #: (the scans are distorted by the vehicle's motion within a scan; the database views are noisy).
    min_sigma_translation_m: float = 0.001
    min_sigma_rotation_rad: float = 0.03
    #: Variance given to a rotation the symmetry makes unobservable (rad^2): effectively no information.
    unobservable_variance_rad2: float = 1e4
    #: Reliability thresholds: fitness (inlier fraction within ``icp_max_correspondence_m``), RMSE,
    #: visibility cost of the chosen pose, and score margin to the best non-equivalent hypothesis.
    min_fitness: float = 0.7
    max_rmse_m: float = 0.003
    max_visibility: float = 0.3
    #: Calibrated on the simulator's scans: most wrong poses (flips) have a margin < 0.03.
    min_score_margin: float = 0.03
    min_points: int = 30

    def __post_init__(self) -> None:
        c = "PoseConfig"
        for name in ("voxel_m", "normal_radius_m", "feature_radius_m", "similarity", "coarse_max_correspondence_m",
                     "icp_max_correspondence_m", "covariance_inflation", "unobservable_variance_rad2", "max_rmse_m",
                     "search_voxel_m", "field_cell_m", "fit_tau_m", "visibility_voxel_m", "visibility_tol_m",
                     "image_cell_m", "max_visibility"):
            check_positive(name, getattr(self, name), caller=c)
        for name in ("n_coarse_rotations", "n_coarse_keep"):
            check_int(name, getattr(self, name), caller=c, minimum=0)
        for name in ("model_icp_voxel_m", "icp_wide_correspondence_m", "visibility_weight", "back_facing_weight",
                     "local_refine_min_radius_m", "partial_start_step_m",
                     "min_score_margin",
                     "min_sigma_translation_m", "min_sigma_rotation_rad"):
            check_positive(name, getattr(self, name), caller=c, allow_zero=True)
        for name in ("coarse_max_iterations", "k_correspondences", "icp_max_iterations", "min_points",
                     "n_rotations", "n_refine", "n_candidates", "n_coarse_points"):
            check_int(name, getattr(self, name), caller=c, minimum=1)
        check_int("model_normals_k", self.model_normals_k, caller=c, minimum=5)
        steps = self.local_refine_steps_deg
        if not isinstance(steps, (tuple, list)) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) and v > 0 for v in steps):
            raise InputError(f"The 'local_refine_steps_deg' argument of {c} must be a tuple of positive angles "
                             f"(degrees). Got {steps!r} instead.")
        object.__setattr__(self, "local_refine_steps_deg", tuple(float(v) for v in steps))
        tr = self.translation_steps_m
        if not isinstance(tr, (tuple, list)) or len(tr) < 3 or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) and v > 0 for v in tr) \
                or any(b > a for a, b in zip(tr, tr[1:])):
            raise InputError(f"The 'translation_steps_m' argument of {c} must be a tuple of at least 3 positive, "
                             f"non-increasing distances (metres). Got {tr!r} instead.")
        object.__setattr__(self, "translation_steps_m", tuple(float(v) for v in tr))
        if self.camera_offset_m is not None:
            cam = as_float_array("camera_offset_m", self.camera_offset_m, (3,), caller=c)
            object.__setattr__(self, "camera_offset_m", tuple(float(v) for v in cam))
        check_choice("icp_method", self.icp_method, tuple(ICP_METHODS), caller=c)
        check_choice("coarse_selection", self.coarse_selection, ("msac", "error"), caller=c)
        check_choice("coarse_method", self.coarse_method, ("grid", "ransac"), caller=c)
        check_choice("icp_backend", self.icp_backend, ("field", "small_gicp"), caller=c)
        for name in ("inlier_fraction", "min_fitness"):
            if not 0 <= float(getattr(self, name)) <= 1:
                raise InputError(
                    f"The {name!r} argument of {c} must be in [0, 1]. Got {getattr(self, name)!r} instead."
                )

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True, eq=False)
class PoseModel:
    """An object model prepared for :func:`estimate_object_pose` (build with :func:`prepare_pose_model`).

    Attributes
    ----------
    points_object : ndarray (M, 3)
        Model points in the object's canonical frame (metres), before voxelisation.
    coarse_points, coarse_features : ndarray (Mc, 3), (Mc, 33)
        Voxelised points and their FPFH, for the RANSAC (``coarse_features`` is None with the grid search).
    icp_target : IcpTarget
        The ICP target (model points, normals estimated from ``model_normals_k`` neighbours).
    normals_object : ndarray (Mi, 3)
        Unit normals of the ICP target points (for the covariance).
    distance_field : DistanceField
        Nearest model point per 2 mm cell (grid search).
    visibility_points, visibility_normals : ndarray (Mv, 3)
        Voxelised model points with outward normals (object frame) for the visibility term.
    rotations : ndarray (n_rotations, 3, 3)
        The SO(3) grid.
    rotation_hierarchy : RotationHierarchy or None
        A coarser grid over ``rotations`` for the coarse-to-fine ranking (None: rank every rotation).
    radius_m : float
        RMS distance of the model points to the object origin.
    radius_grid : RadiusGrid or None
        The ICP target points bucketed for exact nearest-neighbour queries within ``fit_tau_m`` and
        ``icp_max_correspondence_m`` (same results as ``icp_target.tree``, faster; None: the tree is used).
    view_centroids : ViewCentroids or None
        Centroid of the model surface facing each viewing direction: where the grid search starts the
        translation (None: ``radius_m / 2`` from the origin towards the sensor).
    """

    points_object: np.ndarray
    coarse_points: np.ndarray
    coarse_features: np.ndarray | None
    coarse_tree: cKDTree
    feature_tree: cKDTree | None
    icp_target: IcpTarget
    normals_object: np.ndarray
    config: PoseConfig = field(repr=False)
    distance_field: DistanceField | None = field(default=None, repr=False)
    visibility_points: np.ndarray | None = field(default=None, repr=False)
    visibility_normals: np.ndarray | None = field(default=None, repr=False)
    rotations: np.ndarray | None = field(default=None, repr=False)
    radius_m: float = 0.05
    rotation_hierarchy: RotationHierarchy | None = field(default=None, repr=False)
    radius_grid: RadiusGrid | None = field(default=None, repr=False)
    view_centroids: ViewCentroids | None = field(default=None, repr=False)

    @functools.cached_property
    def visibility_tree(self) -> cKDTree:
        """KD-tree of ``visibility_points``, built on first use and kept (the back-facing test of every pose)."""
        return cKDTree(self.visibility_points)

    @functools.cached_property
    def hull_points(self) -> np.ndarray:
        """The vertices (K, 3) of the convex hull of ``points_object`` (object frame), built on first use and kept:
        the deepest model point along any direction is one of them (the floor check of every pose asks for it:
        :func:`semslam.pipeline.hypothesis.within_planes`). Every point when the hull is degenerate (a flat
        model). Qhull leaves out points within its rounding of the hull, so a bound from these is good to
        :data:`HULL_SLACK_M`."""
        from scipy.spatial import ConvexHull, QhullError

        pts = self.points_object
        try:
            return np.ascontiguousarray(pts[ConvexHull(pts).vertices])
        except (QhullError, ValueError):
            return pts


#: How far inside the hull of :attr:`PoseModel.hull_points` a left-out model point can lie at most (m): Qhull's
#: rounding on coordinates of metres is ~1e-15 m; this allowance is a million times that.
HULL_SLACK_M = 1e-9


def prepare_pose_model(model: Any, config: PoseConfig | None = None) -> PoseModel:
    """Prepare an object model: distance field, visibility samples and SO(3) grid for the grid search
    (or voxelised points + FPFH for the RANSAC), ICP target with normals.

    Parameters
    ----------
    model : PointCloud, sequence of PointCloud, or array-like (M, 3)
        Model points in the object frame. A PointCloud with finite normals (e.g. mesh surface samples with
        outward face normals) uses them; otherwise it is one view whose ``viewpoint_xyz_m`` orients the
        normals. A sequence of views is fused (each view's normals oriented towards its own viewpoint,
        then the views are concatenated). A bare array has normals oriented away from its centroid.
    config : PoseConfig, optional
    """
    from ..segmentation.voxel import voxel_downsample

    cfg = config or PoseConfig()
    if not isinstance(cfg, PoseConfig):
        raise InputError(
            f"The 'config' argument of prepare_pose_model must be a PoseConfig. Got {type(cfg).__name__} instead."
        )
    views = _as_views(model)
    pts = np.vstack([v[0] for v in views])
    digest = _views_digest(views)
    down, nrm = _oriented_samples(views, cfg.voxel_m, cfg.normal_radius_m, digest)
    feats = ftree = None
    if cfg.coarse_method == "ransac":
        from ..descriptors.fpfh import compute_fpfh

        feats = compute_fpfh(down, nrm, radius_m=cfg.feature_radius_m)
        ftree = cKDTree(feats)
    icp_pts = voxel_downsample(pts, cfg.model_icp_voxel_m) if cfg.model_icp_voxel_m > 0 else pts
    if len(icp_pts) < 10 or len(down) < 3:
        raise RegistrationError(f"The object model has too few points ({len(icp_pts)}) for pose estimation.")
    target = prepare_icp_target(icp_pts, method=cfg.icp_method, normals_k=cfg.model_normals_k)
    normals = target.normals_xyz
    if normals is None:
        cloud = small_gicp.PointCloud(icp_pts)
        small_gicp.estimate_normals(cloud, num_neighbors=cfg.model_normals_k)
        normals = np.ascontiguousarray(cloud.normals()[:, :3])
    vis_pts, vis_nrm = _oriented_samples(
        views, cfg.visibility_voxel_m, max(cfg.normal_radius_m, 1.5 * cfg.visibility_voxel_m), digest
    )
    ok = np.isfinite(vis_nrm).all(axis=1)
    vis_pts, vis_nrm = vis_pts[ok], vis_nrm[ok]
    if len(views) > 1:  # fused views overlap: one sample per voxel (normal of the nearest view sample)
        merged = voxel_downsample(vis_pts, cfg.visibility_voxel_m)
        vis_pts, vis_nrm = merged, vis_nrm[cKDTree(vis_pts).query(merged)[1]]
    rotations = so3_grid(cfg.n_rotations)
    hierarchy = None
    if 0 < cfg.n_coarse_rotations < cfg.n_rotations and cfg.n_coarse_keep > 0:
        hierarchy = _rotation_hierarchy(cfg.n_rotations, cfg.n_coarse_rotations)
    return PoseModel(
        pts,
        down,
        feats,
        cKDTree(down),
        ftree,
        target,
        normals,
        cfg,
        distance_field=DistanceField.build_cached(icp_pts, cell_m=cfg.field_cell_m),
        visibility_points=np.ascontiguousarray(vis_pts),
        visibility_normals=np.ascontiguousarray(vis_nrm),
        rotations=rotations,
        radius_m=float(np.sqrt(np.mean(np.sum(pts**2, axis=1)))),
        rotation_hierarchy=hierarchy,
        radius_grid=RadiusGrid.build(target.points_xyz_m, max(cfg.fit_tau_m, cfg.icp_max_correspondence_m)),
        view_centroids=ViewCentroids.build_cached(vis_pts, vis_nrm) if len(vis_pts) else None,
    )


@dataclass(frozen=True)
class SurfacePoints:
    """An object's surface as points in its frame, for how many of a cluster's points lie on it (the pipeline's
    part and fragment tests): the points the pose model's ICP aligns to, without its search structures.
    :meth:`distances` gives what :func:`_nearest` gives on a pose model of the same views."""

    points_xyz_m: np.ndarray
    grid: RadiusGrid | None

    @functools.cached_property
    def tree(self) -> cKDTree:
        """For bounds beyond the grid's cell (built on first use)."""
        return cKDTree(self.points_xyz_m)

    @classmethod
    def of_views(cls, model: Any, config: PoseConfig) -> "SurfacePoints":
        """The points of ``model`` (as :func:`prepare_pose_model` takes it) voxelised as its ICP target is."""
        from ..segmentation.voxel import voxel_downsample

        pts = np.vstack([v[0] for v in _as_views(model)])
        pts = voxel_downsample(pts, config.model_icp_voxel_m) if config.model_icp_voxel_m > 0 else pts
        pts = np.ascontiguousarray(pts, dtype=np.float64)
        return cls(pts, RadiusGrid.build(pts, max(config.fit_tau_m, config.icp_max_correspondence_m)))

    @classmethod
    def of_pose_model(cls, model: PoseModel) -> "SurfacePoints":
        """The pose model's own ICP target and radius grid."""
        return cls(model.icp_target.points_xyz_m, model.radius_grid)

    def distances(self, points: np.ndarray, bound_m: float) -> np.ndarray:
        """Distance (N,) from each of ``points`` (N, 3) to the nearest surface point, inf beyond ``bound_m``."""
        q = np.ascontiguousarray(points, dtype=np.float64)
        if self.grid is not None and bound_m <= self.grid.cell_m:
            return self.grid.query(q, bound_m)[0]
        return self.tree.query(q, k=1, distance_upper_bound=bound_m)[0]


def _nearest(model: PoseModel, points: np.ndarray, bound_m: float) -> tuple[np.ndarray, np.ndarray]:
    """``icp_target.tree.query(points, k=1, distance_upper_bound=bound_m)``, by the radius grid when it applies."""
    g = model.radius_grid
    if g is not None and bound_m <= g.cell_m:
        return g.query(points, bound_m)
    return model.icp_target.tree.query(points, k=1, distance_upper_bound=bound_m)


@functools.lru_cache(maxsize=4)
def _rotation_hierarchy(n_fine: int, n_coarse: int) -> RotationHierarchy:
    """The same for every class: built once per process."""
    return RotationHierarchy.build(so3_grid(n_fine), n_coarse)


def _oriented_samples(views, leaf_m: float, radius_m: float, digest: str) -> tuple[np.ndarray, np.ndarray]:
    """Voxelised points of every view with normals oriented outwards (towards the view's viewpoint), through the
    on-disk cache (:mod:`semslam._cache`) under the views' ``digest`` (:func:`_views_digest`): on a database of 16
    laser views per class (~380 000 points) they are ~0.1 s of every class's first pose in a fresh process."""
    from .._cache import cached_arrays

    out = cached_arrays("oriented_samples_v1", [digest, float(leaf_m), float(radius_m)],
                        lambda: dict(zip(("points", "normals"), _build_oriented_samples(views, leaf_m, radius_m))))
    return out["points"], out["normals"]


def _views_digest(views) -> str:
    """SHA-256 of the model's views (points, viewpoints, given normals): hashed once for both sample sets."""
    from .._cache import key_digest

    return key_digest([len(views), *(part if part is None else np.asarray(part, dtype=np.float64)
                                      for view in views for part in view)])


def _build_oriented_samples(views, leaf_m: float, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_oriented_samples` computed."""
    from ..descriptors import estimate_normals
    from ..segmentation.voxel import voxel_downsample

    out_p, out_n = [], []
    for pts, vp, given in views:
        down = voxel_downsample(pts, leaf_m)
        if given is not None:  # normals given (e.g. mesh samples): those of the nearest original points
            nr = given[cKDTree(pts).query(down)[1]]
        elif vp is None:
            nr = estimate_normals(down, radius_m=radius_m).normals_xyz
            nr[np.einsum("ij,ij->i", nr, down - down.mean(axis=0)) < 0] *= -1.0
        else:
            nr = estimate_normals(down, radius_m=radius_m, viewpoint_xyz_m=vp).normals_xyz
        out_p.append(down)
        out_n.append(nr)
    return np.vstack(out_p), np.vstack(out_n)


def _as_views(model: Any) -> list[tuple[np.ndarray, np.ndarray | None, np.ndarray | None]]:
    if isinstance(model, PointCloud):
        model = [model]
    if isinstance(model, Sequence) and model and all(isinstance(v, PointCloud) for v in model):
        return [(v.points_xyz_m, v.viewpoint_xyz_m, v.normals_xyz if v.has_normals and np.isfinite(v.normals_xyz).all()
                 else None) for v in model]
    pts = as_float_array("model_points_object", model, (None, 3), caller="prepare_pose_model")
    return [(pts, None, None)]
