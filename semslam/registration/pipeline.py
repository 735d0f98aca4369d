"""Cloud-to-cloud registration as PCL's alignment tutorial: voxel grid, normals, FPFH, prerejective
RANSAC, then ICP (see ``design/pcl-algorithms.md`` section 4)."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .._validation import check_choice, check_int, check_positive
from ..cloud import PointCloud
from ..errors import InputError, RegistrationError
from .coarse import align_prerejective
from .icp import ICP_METHODS, align_icp
from .result import RegistrationResult


@dataclass(frozen=True)
class RegisterConfig:
    """Settings of :func:`register` (defaults = PCL's ``alignment_prerejective`` tutorial / ``pcl_ref register``).

    Lengths in metres; ``None`` lengths derive from ``voxel_m``: normals radius ``2 * voxel_m``, FPFH
    radius ``5 * voxel_m``, RANSAC inlier distance ``2.5 * voxel_m``, ICP correspondence distance
    ``2 * voxel_m``.
    """

    voxel_m: float = 0.005
    normal_radius_m: float | None = None
    feature_radius_m: float | None = None
    max_iterations: int = 50000
    n_samples: int = 3
    k_correspondences: int = 5
    similarity: float = 0.9
    max_correspondence_m: float | None = None
    inlier_fraction: float = 0.25
    #: ICP variant or ``"none"``. Default ``"pcl"``: PCL's point-to-point ICP (SVD steps on a scipy KD-tree), as
    #: ``pcl_ref register``; small_gicp's KD-tree is pathologically slow on dense Kinect scenes such as rs1.pcd
    #: (10-20 s for the chef ICP against 0.5-2 s), so the small_gicp variants (``"point"``, ``"plane"``,
    #: ``"gicp"``) are better with ``icp_full_resolution=False``.
    icp_method: str = "pcl"
    icp_max_correspondence_m: float | None = None
    icp_max_iterations: int = 50
    #: ICP on the full-resolution clouds (as ``pcl_ref``) rather than the voxelised ones. The target
    #: is cropped to the aligned source's bounding box grown by ``icp_crop_margin_m`` (default 5 x ICP distance).
    icp_full_resolution: bool = True
    icp_crop_margin_m: float | None = None

    def __post_init__(self) -> None:
        c = "RegisterConfig"
        check_positive("voxel_m", self.voxel_m, caller=c)
        for name in ("normal_radius_m", "feature_radius_m", "max_correspondence_m", "icp_max_correspondence_m",
                     "icp_crop_margin_m"):
            if getattr(self, name) is not None:
                check_positive(name, getattr(self, name), caller=c)
        check_int("max_iterations", self.max_iterations, caller=c, minimum=1)
        check_int("n_samples", self.n_samples, caller=c, minimum=3)
        check_int("k_correspondences", self.k_correspondences, caller=c, minimum=1)
        check_int("icp_max_iterations", self.icp_max_iterations, caller=c, minimum=1)
        check_choice("icp_method", self.icp_method, (*ICP_METHODS, "none"), caller=c)
        if not 0 < float(self.similarity) <= 1:
            raise InputError(f"The 'similarity' argument of {c} must be in (0, 1]. Got {self.similarity!r} instead.")
        if not 0 <= float(self.inlier_fraction) <= 1:
            raise InputError(f"The 'inlier_fraction' argument of {c} must be in [0, 1]. Got {self.inlier_fraction!r} instead.")

    def resolved(self, name: str) -> float:
        """A length setting, with its default derived from ``voxel_m``."""
        factors = {"normal_radius_m": 2.0, "feature_radius_m": 5.0, "max_correspondence_m": 2.5,
                   "icp_max_correspondence_m": 2.0}
        value = getattr(self, name)
        if value is not None:
            return float(value)
        if name == "icp_crop_margin_m":
            return 5.0 * self.resolved("icp_max_correspondence_m")
        return factors[name] * self.voxel_m

    def to_dict(self) -> dict:
        return asdict(self)


def register(source: Any, target: Any, config: RegisterConfig | None = None, *, seed: Any = 0) -> RegistrationResult:
    """Align ``source`` onto ``target``: features + prerejective RANSAC (coarse) then ICP (fine).

    Parameters
    ----------
    source, target : PointCloud or array-like of shape (N, 3)
        Clouds in metres, each in its own frame; their viewpoints orient the normals.
    config : RegisterConfig, optional
        Settings (PCL tutorial defaults).
    seed : int or numpy Generator
        Seed of the RANSAC.

    Returns
    -------
    RegistrationResult
        ``T_target_source`` after ICP; ``fitness`` and ``inlier_rmse_m`` are those of the final stage
        (ICP distance), ``converged`` is the coarse stage's; ``extras["coarse"]`` is the coarse result,
        ``timings_ms`` has ``downsample``, ``features``, ``coarse``, ``icp`` and ``total``.

    Raises
    ------
    RegistrationError
        When a cloud is too small after voxelisation.
    """
    from ..descriptors import compute_fpfh, estimate_normals
    from ..segmentation.voxel import voxel_downsample

    cfg = config or RegisterConfig()
    if not isinstance(cfg, RegisterConfig):
        raise InputError(f"The 'config' argument of register must be a RegisterConfig. Got {type(cfg).__name__} instead.")
    src_cloud, tgt_cloud = _as_cloud("source", source), _as_cloud("target", target)
    t0 = time.perf_counter()
    src = voxel_downsample(src_cloud.points_xyz_m, cfg.voxel_m)
    tgt = voxel_downsample(tgt_cloud.points_xyz_m, cfg.voxel_m)
    for name, pts in (("source", src), ("target", tgt)):
        if len(pts) < cfg.n_samples:
            raise RegistrationError(f"The {name} cloud has {len(pts)} points after a {cfg.voxel_m} m voxel grid; "
                                    f"register needs at least {cfg.n_samples}.")
    t1 = time.perf_counter()
    feats = []
    for pts, cloud in ((src, src_cloud), (tgt, tgt_cloud)):
        nrm = estimate_normals(pts, radius_m=cfg.resolved("normal_radius_m"),
                               viewpoint_xyz_m=cloud.viewpoint_xyz_m).normals_xyz
        feats.append(compute_fpfh(pts, nrm, radius_m=cfg.resolved("feature_radius_m")))
    t2 = time.perf_counter()
    coarse = align_prerejective(
        src, feats[0], tgt, feats[1], max_iterations=cfg.max_iterations, n_samples=cfg.n_samples,
        k_correspondences=cfg.k_correspondences, similarity=cfg.similarity,
        max_correspondence_m=cfg.resolved("max_correspondence_m"), inlier_fraction=cfg.inlier_fraction, seed=seed)
    t3 = time.perf_counter()
    timings = {"downsample": 1e3 * (t1 - t0), "features": 1e3 * (t2 - t1), "coarse": 1e3 * (t3 - t2)}
    if cfg.icp_method == "none" or not coarse.converged:
        timings["total"] = 1e3 * (time.perf_counter() - t0)
        return _replace(coarse, timings, coarse)
    if cfg.icp_full_resolution:
        src_icp, tgt_icp = src_cloud.points_xyz_m, tgt_cloud.points_xyz_m
    else:
        src_icp, tgt_icp = src, tgt
    T0 = coarse.T_target_source
    moved = T0.apply(src_icp)
    margin = cfg.resolved("icp_crop_margin_m")
    inside = ((tgt_icp >= moved.min(axis=0) - margin) & (tgt_icp <= moved.max(axis=0) + margin)).all(axis=1)
    if np.count_nonzero(inside) < 3:
        timings["total"] = 1e3 * (time.perf_counter() - t0)
        return _replace(coarse, timings, coarse)
    fine = align_icp(src_icp, tgt_icp[inside], init_T=T0, method=cfg.icp_method,
                     max_correspondence_m=cfg.resolved("icp_max_correspondence_m"),
                     max_iterations=cfg.icp_max_iterations)
    timings["icp"] = 1e3 * (time.perf_counter() - t3)
    timings["total"] = 1e3 * (time.perf_counter() - t0)
    return RegistrationResult(
        T_target_source=fine.T_target_source, fitness=fine.fitness, inlier_rmse_m=fine.inlier_rmse_m,
        n_iterations=fine.n_iterations, converged=coarse.converged, timings_ms=timings, n_inliers=fine.n_inliers,
        max_correspondence_m=fine.max_correspondence_m, method=f"prerejective+{fine.method}",
        extras={"coarse": coarse.to_dict(), "icp_converged": fine.converged,
                "n_source_voxels": len(src), "n_target_voxels": len(tgt)},
    )


def _as_cloud(name: str, value: Any) -> PointCloud:
    if isinstance(value, PointCloud):
        return value
    try:
        return PointCloud(np.asarray(value, dtype=np.float64))
    except InputError as exc:
        raise InputError(f"The {name!r} argument of register must be a PointCloud or an (N, 3) array: {exc}") from None
    except (TypeError, ValueError):
        raise InputError(f"The {name!r} argument of register must be a PointCloud or an (N, 3) array. "
                         f"Got {type(value).__name__} instead.") from None


def _replace(res: RegistrationResult, timings: dict, coarse: RegistrationResult) -> RegistrationResult:
    return RegistrationResult(res.T_target_source, res.fitness, res.inlier_rmse_m, res.n_iterations, res.converged,
                              timings, res.n_inliers, res.max_correspondence_m, res.method,
                              {**res.extras, "coarse": coarse.to_dict()})
