"""ICP refinement of an object pose against its :class:`~.model.PoseModel` and the scores of refined
hypotheses: wide then fine ICP from a prior (:func:`_refine`), small_gicp on a prepared source cloud, the
numba point-to-plane ICP on the distance field's nearest points with the exact nearest model points it ends on
(:func:`_icp_field_nearest`, reused by the covariance), and the final fit / visibility / back-facing scores
that select among the grid search's refined hypotheses (:func:`_final_scores`, :func:`back_facing_shares`).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import small_gicp

from ..geometry import RigidTransform, orthonormalize_transform
from ..registration._icp_kernels import icp_plane_field
from ..registration.icp import ICP_METHODS, align_icp
from ..registration.result import RegistrationResult, _inlier_statistics_of_distances
from .model import PoseConfig, PoseModel, _nearest
from .search import RangeImage

__all__ = ["back_facing_shares"]


def _refine(cluster: np.ndarray, model: PoseModel, cfg: PoseConfig, T_init: np.ndarray) -> RegistrationResult:
    """Wide then fine ICP of the cluster onto the model from ``T_init`` (``T_object_scanner``)."""
    init = T_init
    if cfg.icp_wide_correspondence_m > 0:
        init = align_icp(cluster, model.icp_target, init_T=init, max_correspondence_m=cfg.icp_wide_correspondence_m,
                         max_iterations=cfg.icp_max_iterations).T_target_source
    return align_icp(cluster, model.icp_target, init_T=init, max_correspondence_m=cfg.icp_max_correspondence_m,
                     max_iterations=cfg.icp_max_iterations)


def _icp_small_gicp(src: np.ndarray, model: PoseModel, cfg: PoseConfig, T_init: np.ndarray,
                    max_corr: float) -> RegistrationResult:
    return align_icp(src, model.icp_target, init_T=T_init, max_correspondence_m=max_corr,
                     max_iterations=cfg.icp_max_iterations)


def _small_gicp_T(source: Any, model: PoseModel, cfg: PoseConfig, T_init: np.ndarray, max_corr: float) -> np.ndarray:
    """``T_object_scanner`` after :func:`semslam.registration.icp.align_icp`'s small_gicp call on a prepared
    source cloud."""
    tgt = model.icp_target
    res = small_gicp.align(tgt.sg_cloud, source, tgt.sg_tree, init_T_target_source=np.array(T_init, dtype=np.float64),
                           registration_type=ICP_METHODS[tgt.method], max_correspondence_distance=float(max_corr),
                           num_threads=1, max_iterations=int(cfg.icp_max_iterations), rotation_epsilon=1e-4,
                           translation_epsilon=1e-5)
    T = np.array(res.T_target_source)
    orthonormalize_transform(T)
    return T


def _icp_field_run(src: np.ndarray, model: PoseModel, cfg: PoseConfig, T_init: np.ndarray, max_corr: float):
    f = model.distance_field
    return icp_plane_field(np.ascontiguousarray(src, dtype=np.float64), np.array(T_init, dtype=np.float64), f.params,
                           f.index, model.icp_target.points_xyz_m, model.normals_object, float(max_corr),
                           int(cfg.icp_max_iterations), 1e-4, 1e-5)


def _icp_field_nearest(src: np.ndarray, model: PoseModel, cfg: PoseConfig, T_init: np.ndarray, max_corr: float):
    """Point-to-plane ICP on the distance field's nearest points (numba) as a RegistrationResult, and the
    exact nearest model points of the aligned source (``(p, d, j)``: aligned points (N, 3), distances (N,)
    inf beyond ``max_corr``, rows of ``icp_target``), which the covariance reuses. Fitness and RMSE are
    :func:`semslam.registration.result.inlier_statistics`'s (the radius grid returns the KD-tree's distances)."""
    t0 = time.perf_counter()
    T, n_it, converged, _ = _icp_field_run(src, model, cfg, T_init, max_corr)
    t1 = time.perf_counter()
    orthonormalize_transform(T)
    p = src @ T[:3, :3].T + T[:3, 3]
    d, j = _nearest(model, p, max_corr)
    fitness, rmse, n_in = _inlier_statistics_of_distances(d, max_corr)
    res = RegistrationResult(
        T_target_source=RigidTransform(T), fitness=fitness, inlier_rmse_m=rmse, n_iterations=n_it,
        converged=converged, n_inliers=n_in, max_correspondence_m=max_corr, method="plane_icp",
        timings_ms={"icp": 1e3 * (t1 - t0), "total": 1e3 * (time.perf_counter() - t0)}, extras={})
    return res, (p, d, j)


def _final_score(cluster: np.ndarray, image: RangeImage, model: PoseModel, cfg: PoseConfig, T_os: np.ndarray,
                 ) -> tuple[float, float]:
    """Fit and visibility costs of a refined hypothesis (exact nearest model points)."""
    p = cluster @ T_os[:3, :3].T + T_os[:3, 3]
    d = _nearest(model, p, cfg.fit_tau_m)[0]
    fit = float(np.mean(np.minimum(d, cfg.fit_tau_m) ** 2)) / cfg.fit_tau_m ** 2
    vis = float(image.visibility_cost(T_os[None, :3, :3], T_os[None, :3, 3], model.visibility_points,
                                      model.visibility_normals, cfg.visibility_tol_m)[0])
    return fit, vis


def back_facing_shares(cluster: np.ndarray, vp: np.ndarray, model: PoseModel, Ts: list) -> np.ndarray:
    """Per ``T_object_scanner`` of ``Ts``: the share of cluster points whose nearest outward model normal faces
    away from the sensor (0 for a front view, ~1 for the object seen turned around)."""
    if model.visibility_points is None or not len(model.visibility_points) or not Ts:
        return np.zeros(len(Ts))
    n = len(cluster)
    ps = [cluster @ T[:3, :3].T + T[:3, 3] for T in Ts]
    js = model.visibility_tree.query(np.vstack(ps), workers=-1)[1]  # one query of every pose's points, both cores
    out = np.empty(len(Ts))
    for k, (T, p) in enumerate(zip(Ts, ps)):
        j = js[k * n:(k + 1) * n]
        out[k] = float(np.mean(np.einsum("ij,ij->i", model.visibility_normals[j], T[:3, :3] @ vp + T[:3, 3] - p) < 0))
    return out


def _final_scores(cluster: np.ndarray, image: RangeImage, model: PoseModel, cfg: PoseConfig,
                  Ts: list) -> list[tuple[float, float]]:
    """:func:`_final_score` of each of ``Ts`` (the same numbers), with one nearest-point and one visibility call."""
    if not Ts:
        return []
    n = len(cluster)
    p = np.vstack([cluster @ T[:3, :3].T + T[:3, 3] for T in Ts])
    d = _nearest(model, p, cfg.fit_tau_m)[0]
    tau = cfg.fit_tau_m
    Rs = np.stack([T[:3, :3] for T in Ts])
    ts = np.stack([T[:3, 3] for T in Ts])
    vis = image.visibility_cost(Rs, ts, model.visibility_points, model.visibility_normals, cfg.visibility_tol_m)
    return [(float(np.mean(np.minimum(d[k * n:(k + 1) * n], tau) ** 2)) / tau ** 2, float(vis[k]))
            for k in range(len(Ts))]
