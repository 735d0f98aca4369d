"""Cloud-to-cloud registration as PCL's alignment tutorial: voxel grid, normals, FPFH, prerejective
RANSAC, then ICP (see ``design/pcl-algorithms.md`` section 4), within a time budget.

Bounded on any input: far outliers are cropped (robust 1-99 % box), the voxel leaf is chosen from the
clouds' spacing and extent (``voxel_m="auto"``) so that at most ``max_voxels`` voxels enter the features
and the RANSAC, FPFH neighbourhoods are capped, the RANSAC and PCL's ICP stop at the deadline, and a
plane or a line (unobservable registration) raises :class:`~semslam.errors.RegistrationError` up front.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .._progress import progress_steps
from .._validation import check_choice, check_int, check_positive
from ..cloud import PointCloud
from ..errors import InputError
from ._stages import RANSAC_SHARE
from ._stages import Clock as _Clock
from ._stages import features as _features
from ._stages import icp as _icp
from ._stages import prepare as _prepare
from .coarse import align_prerejective
from .icp import ICP_METHODS
from .result import RegistrationResult

@dataclass(frozen=True)
class RegisterConfig:
    """Settings of :func:`register` (PCL's ``alignment_prerejective`` tutorial / ``pcl_ref register``, bounded).

    Lengths in metres; ``None`` lengths derive from the voxel leaf: normals radius ``2 * voxel``, FPFH
    radius ``5 * voxel``, RANSAC inlier distance ``2.5 * voxel``, ICP correspondence distance ``2 * voxel``.
    ``voxel_m="auto"`` (default) picks the leaf from the clouds: at least their point spacing (median
    4th-neighbour distance) and coarse enough that the source keeps at most ``max_voxels`` voxels (the
    RANSAC scores each of them per hypothesis) and the target 4 x as many. PCL's
    tutorial value is ``voxel_m=0.005``.
    """

    voxel_m: float | str = "auto"
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
    #: ``"gicp"``) are better with ``icp_full_resolution=False``; they ignore the time budget.
    icp_method: str = "pcl"
    icp_max_correspondence_m: float | None = None
    icp_max_iterations: int = 50
    #: ICP on the full-resolution clouds (as ``pcl_ref``) rather than the voxelised ones. The target
    #: is cropped to the aligned source's bounding box grown by ``icp_crop_margin_m`` (default 5 x ICP distance).
    icp_full_resolution: bool = True
    icp_crop_margin_m: float | None = None
    #: With ``icp_full_resolution``, ICP uses a seeded random subset of at most this many source points
    #: (None = all, as PCL): ICP iterations and scoring stay bounded on 300k-point scans.
    icp_max_points: int | None = 20000
    #: Wall-clock budget of the whole call (seconds); None = unbounded. The RANSAC gets up to 60 % of it and
    #: ICP stops at 85 %; a budget 90 % spent before the RANSAC starts raises RegistrationError.
    time_budget_s: float | None = 10.0
    #: Largest number of source voxels that ``voxel_m="auto"`` allows (4 x as many target voxels).
    max_voxels: int = 2000
    #: Statistical outlier removal (PCL's, 20 neighbours, 2 standard deviations) on the voxelised clouds.
    remove_outliers: bool = False
    #: Neighbours per point at most in the FPFH (``k_max``, the nearest ones); None = no cap (PCL).
    max_neighbors: int | None = 200
    #: Raise RegistrationError when a cloud is a line or a plane (unobservable registration).
    check_observability: bool = True
    #: Compare the answer with its half turns about the source's principal axes and say whether it is
    #: ``reliable`` or ``ambiguous`` (:mod:`semslam.registration.ambiguity`; three extra ICPs on the voxelised clouds).
    check_flips: bool = True

    def __post_init__(self) -> None:
        c = "RegisterConfig"
        if not (isinstance(self.voxel_m, str) and self.voxel_m == "auto"):
            if isinstance(self.voxel_m, str):
                raise InputError(f"The 'voxel_m' argument of {c} must be 'auto' or a length in metres. "
                                 f"Got {self.voxel_m!r} instead.")
            check_positive("voxel_m", self.voxel_m, caller=c)
        for name in ("normal_radius_m", "feature_radius_m", "max_correspondence_m", "icp_max_correspondence_m",
                     "icp_crop_margin_m", "time_budget_s"):
            if getattr(self, name) is not None:
                check_positive(name, getattr(self, name), caller=c)
        check_int("max_iterations", self.max_iterations, caller=c, minimum=1)
        check_int("n_samples", self.n_samples, caller=c, minimum=3)
        check_int("k_correspondences", self.k_correspondences, caller=c, minimum=1)
        check_int("icp_max_iterations", self.icp_max_iterations, caller=c, minimum=1)
        check_int("max_voxels", self.max_voxels, caller=c, minimum=10)
        if self.icp_max_points is not None:
            check_int("icp_max_points", self.icp_max_points, caller=c, minimum=3)
        if self.max_neighbors is not None:
            check_int("max_neighbors", self.max_neighbors, caller=c, minimum=2)
        check_choice("icp_method", self.icp_method, (*ICP_METHODS, "none"), caller=c)
        if not 0 < float(self.similarity) <= 1:
            raise InputError(f"The 'similarity' argument of {c} must be in (0, 1]. Got {self.similarity!r} instead.")
        if not 0 <= float(self.inlier_fraction) <= 1:
            raise InputError(f"The 'inlier_fraction' argument of {c} must be in [0, 1]. Got {self.inlier_fraction!r} instead.")

    def resolved(self, name: str, voxel_m: float | None = None) -> float:
        """A length setting, with its default derived from the voxel leaf (``voxel_m``, needed when 'auto')."""
        factors = {"normal_radius_m": 2.0, "feature_radius_m": 5.0, "max_correspondence_m": 2.5,
                   "icp_max_correspondence_m": 2.0}
        value = getattr(self, name)
        if value is not None:
            return float(value)
        if name == "icp_crop_margin_m":
            return 5.0 * self.resolved("icp_max_correspondence_m", voxel_m)
        voxel = voxel_m if voxel_m is not None else self.voxel_m
        if isinstance(voxel, str):
            raise InputError(f"RegisterConfig.resolved({name!r}) needs the voxel leaf when voxel_m is 'auto'.")
        return factors[name] * float(voxel)

    def to_dict(self) -> dict:
        return asdict(self)


def register(source: Any, target: Any, config: RegisterConfig | None = None, *, seed: Any = 0,
             progress: Any = None) -> RegistrationResult:
    """Align ``source`` onto ``target``: features + prerejective RANSAC (coarse) then ICP (fine).

    Parameters
    ----------
    source, target : PointCloud or array-like of shape (N, 3)
        Clouds in metres, each in its own frame; their viewpoints orient the normals.
    config : RegisterConfig, optional
        Settings (bounded PCL tutorial defaults: automatic voxel, 10 s budget).
    seed : int or numpy Generator
        Seed of the RANSAC.
    progress : bool or callable, optional
        Progress bar (see :mod:`semslam._progress`), in percent of the work.

    Returns
    -------
    RegistrationResult
        ``T_target_source`` after ICP; ``fitness`` and ``inlier_rmse_m`` are those of the final stage
        (ICP distance), ``converged`` is the coarse stage's; ``extras["coarse"]`` is the coarse result,
        ``extras["voxel_m"]`` the leaf used, ``extras["budget_exhausted"]`` whether the time budget stopped
        the RANSAC or ICP; ``timings_ms`` has ``downsample``, ``features``, ``coarse``, ``icp`` and ``total``.

    Raises
    ------
    RegistrationError
        A cloud too small after voxelisation, a line or a plane (unobservable), or a time budget spent
        before the RANSAC could start.
    """
    cfg = config or RegisterConfig()
    if not isinstance(cfg, RegisterConfig):
        raise InputError(f"The 'config' argument of register must be a RegisterConfig. Got {type(cfg).__name__} instead.")
    src_cloud, tgt_cloud = _as_cloud("source", source), _as_cloud("target", target)
    clock = _Clock(cfg.time_budget_s)
    with progress_steps(progress, 100, "register", "%") as step:
        prep = _prepare(src_cloud.points_xyz_m, tgt_cloud.points_xyz_m, cfg, clock)
        src, tgt, voxel = prep["source"], prep["target"], prep["voxel_m"]
        step(10)
        t1 = time.perf_counter()
        feats = [_features(name, pts, cloud.viewpoint_xyz_m, cfg, voxel, clock)
                 for name, pts, cloud in (("source", src, src_cloud), ("target", tgt, tgt_cloud))]
        step(20)
        t2 = time.perf_counter()
        done = [30]

        def on_batch(n_drawn: int) -> None:
            share = max(n_drawn / cfg.max_iterations, clock.fraction_of(t2, RANSAC_SHARE))
            new = 30 + int(55 * min(1.0, share))
            step(max(0, new - done[0]))
            done[0] = max(done[0], new)

        coarse = align_prerejective(
            src, feats[0], tgt, feats[1], max_iterations=cfg.max_iterations, n_samples=cfg.n_samples,
            k_correspondences=cfg.k_correspondences, similarity=cfg.similarity,
            max_correspondence_m=cfg.resolved("max_correspondence_m", voxel), inlier_fraction=cfg.inlier_fraction,
            seed=seed, deadline=clock.at(RANSAC_SHARE), on_batch=on_batch)
        step(max(0, 85 - done[0]))
        t3 = time.perf_counter()
        timings = {"downsample": 1e3 * (t1 - clock.start), "features": 1e3 * (t2 - t1), "coarse": 1e3 * (t3 - t2)}
        extras = {"voxel_m": voxel, "n_source_voxels": len(src), "n_target_voxels": len(tgt),
                  "n_far_outliers": prep["n_far"], "n_statistical_outliers": prep["n_sor"],
                  "budget_exhausted": bool(coarse.extras.get("budget_exhausted")), "time_budget_s": cfg.time_budget_s}
        fine = None
        if cfg.icp_method != "none" and coarse.converged:
            fine = _icp(prep, coarse, cfg, voxel, clock)
        step(15)
    if fine is None:
        timings["total"] = 1e3 * (time.perf_counter() - clock.start)
        return _replace(coarse, timings, coarse, extras)
    timings["icp"] = 1e3 * (time.perf_counter() - t3)
    timings["total"] = 1e3 * (time.perf_counter() - clock.start)
    extras["budget_exhausted"] = extras["budget_exhausted"] or bool(fine.extras.get("budget_exhausted"))
    extras.update(_verdict(prep, fine, coarse.converged, cfg, voxel))
    return RegistrationResult(
        T_target_source=fine.T_target_source, fitness=fine.fitness, inlier_rmse_m=fine.inlier_rmse_m,
        n_iterations=fine.n_iterations, converged=coarse.converged, timings_ms=timings, n_inliers=fine.n_inliers,
        max_correspondence_m=fine.max_correspondence_m, method=f"prerejective+{fine.method}",
        extras={"coarse": coarse.to_dict(), "icp_converged": fine.converged, **extras},
    )


def _verdict(prep: dict, fine: RegistrationResult, converged: bool, cfg: RegisterConfig, voxel: float) -> dict:
    """``reliable`` / ``ambiguous`` of the answer and its half-turned alternatives (:func:`flip_check`)."""
    from .ambiguity import MIN_FITNESS, flip_check

    if not cfg.check_flips:
        return {}
    chk = flip_check(prep["source"], prep["target"], fine.T_target_source.matrix,
                     max_correspondence_m=cfg.resolved("icp_max_correspondence_m", voxel))
    reliable = bool(converged and not chk["ambiguous"] and chk["fitness"] >= MIN_FITNESS)
    return {"reliable": reliable, "ambiguous": chk["ambiguous"], "flip_check_fitness": chk["fitness"],
            "flip_alternatives": chk["alternatives"]}


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


def _replace(res: RegistrationResult, timings: dict, coarse: RegistrationResult, extras: dict) -> RegistrationResult:
    return RegistrationResult(res.T_target_source, res.fitness, res.inlier_rmse_m, res.n_iterations, res.converged,
                              timings, res.n_inliers, res.max_correspondence_m, res.method,
                              {**res.extras, "coarse": coarse.to_dict(), **extras})
