"""The stages of :func:`semslam.registration.register` (preparation, features, ICP) and its time budget."""

from __future__ import annotations

import time

import numpy as np

from ..errors import DescriptorError, RegistrationError
from . import _prepare as P
from .icp import align_icp
from .result import RegistrationResult

#: Shares of the time budget: the RANSAC draws no hypothesis after the first, ICP no iteration after the
#: second; a budget spent up to the third before the RANSAC starts raises RegistrationError.
RANSAC_SHARE, ICP_SHARE, PREPARE_SHARE = 0.6, 0.85, 0.9
#: ``voxel_m="auto"`` keeps at most ``max_voxels`` source voxels and this many times more target voxels.
TARGET_VOXELS_FACTOR = 4


class Clock:
    """The time budget: ``at(f)`` is the instant when a fraction ``f`` of it is spent (None: unbounded)."""

    def __init__(self, budget_s: float | None) -> None:
        self.start = time.perf_counter()
        self.budget_s = budget_s

    def at(self, fraction: float) -> float | None:
        return None if self.budget_s is None else self.start + fraction * self.budget_s

    def fraction_of(self, since: float, until_fraction: float) -> float:
        end = self.at(until_fraction)
        if end is None or end <= since:
            return 0.0
        return (time.perf_counter() - since) / (end - since)

    def check(self, stage: str, fraction: float = PREPARE_SHARE) -> None:
        end = self.at(fraction)
        if end is not None and time.perf_counter() > end:
            raise RegistrationError(
                f"The time budget of register (time_budget_s={self.budget_s:g} s) ran out while {stage} "
                f"({time.perf_counter() - self.start:.2f} s spent, {fraction:.0%} of it allowed before the RANSAC): "
                "raise the budget or use a coarser voxel_m.")


def prepare(src_pts: np.ndarray, tgt_pts: np.ndarray, cfg, clock: Clock) -> dict:
    """Crop far outliers, choose the voxel, downsample, remove statistical outliers, check observability."""
    from ..descriptors.spacing import point_spacing_m
    from ..segmentation.voxel import voxel_downsample

    full, n_far = [], 0
    for name, pts in (("source", src_pts), ("target", tgt_pts)):
        if len(pts) < cfg.n_samples:
            raise RegistrationError(f"The {name} cloud has {len(pts)} points; register needs at least {cfg.n_samples}.")
        near = P.near_mask(pts)
        n_far += int(len(pts) - near.sum())
        full.append(pts if near.all() else pts[near])
    if cfg.voxel_m == "auto":
        spacings = []
        for name, pts in zip(("source", "target"), full):
            if len(pts) > TARGET_VOXELS_FACTOR * cfg.max_voxels:  # the voxel bound implies voxel > spacing
                spacings.append(0.0)
                continue
            try:
                spacings.append(point_spacing_m(pts))
            except DescriptorError as exc:
                raise RegistrationError(
                    f"The {name} cloud has no usable point spacing for voxel_m='auto': {exc}"
                ) from None
        # the RANSAC scores every source voxel per hypothesis; the target only costs KD-tree queries
        voxel = P.auto_voxel(full, spacings, [cfg.max_voxels, TARGET_VOXELS_FACTOR * cfg.max_voxels],
                             voxel_downsample)
    else:
        voxel = float(cfg.voxel_m)
    out = {"source_full": full[0], "target_full": full[1], "voxel_m": voxel, "n_far": n_far, "n_sor": 0}
    for name, pts in zip(("source", "target"), full):
        vox = voxel_downsample(pts, voxel)
        if cfg.remove_outliers:
            keep = P.statistical_outlier_mask(vox)
            out["n_sor"] += int(len(vox) - keep.sum())
            vox = vox[keep]
        if len(vox) < cfg.n_samples:
            raise RegistrationError(f"The {name} cloud has {len(vox)} points after a {voxel:.4g} m voxel grid; "
                                    f"register needs at least {cfg.n_samples}.")
        if cfg.check_observability:
            P.check_shape_observable(name, vox)
        out[name] = vox
    clock.check("preparing the clouds")
    return out


def features(name: str, pts: np.ndarray, viewpoint: np.ndarray, cfg, voxel: float,
              clock: Clock) -> np.ndarray:
    from ..descriptors.fpfh import compute_fpfh
    from ..descriptors import estimate_normals

    nrm = estimate_normals(pts, radius_m=cfg.resolved("normal_radius_m", voxel), viewpoint_xyz_m=viewpoint).normals_xyz
    if cfg.check_observability:
        P.check_normals_observable(name, nrm)
    feats = compute_fpfh(pts, nrm, radius_m=cfg.resolved("feature_radius_m", voxel), max_neighbors=cfg.max_neighbors)
    clock.check(f"computing the {name} features")
    return feats


def icp(prep: dict, coarse: RegistrationResult, cfg, voxel: float, clock: Clock):
    if cfg.icp_full_resolution:
        src_icp, tgt_icp = prep["source_full"], prep["target_full"]
        if cfg.icp_max_points is not None and len(src_icp) > cfg.icp_max_points:  # bounded ICP iterations
            pick = np.random.default_rng(0).choice(len(src_icp), cfg.icp_max_points, replace=False)
            src_icp = src_icp[np.sort(pick)]
    else:
        src_icp, tgt_icp = prep["source"], prep["target"]
    T0 = coarse.T_target_source
    moved = T0.apply(src_icp)
    margin = cfg.resolved("icp_crop_margin_m", voxel)
    inside = ((tgt_icp >= moved.min(axis=0) - margin) & (tgt_icp <= moved.max(axis=0) + margin)).all(axis=1)
    if np.count_nonzero(inside) < 3:
        return None
    return align_icp(src_icp, tgt_icp[inside], init_T=T0, method=cfg.icp_method,
                     max_correspondence_m=cfg.resolved("icp_max_correspondence_m", voxel),
                     max_iterations=cfg.icp_max_iterations, deadline=clock.at(ICP_SHARE))
