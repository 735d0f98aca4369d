"""Fine alignment: ICP refinement with small_gicp (point-to-plane by default, point-to-point, GICP).

The target is prepared once (:func:`prepare_icp_target`: small_gicp cloud, its KD-tree and normals or
covariances, plus a scipy KD-tree for scoring) and can be reused for many sources, e.g. one object model
registered against many clusters.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import small_gicp
from scipy.spatial import cKDTree

from .._validation import as_float_array, check_choice, check_int, check_positive
from ..errors import RegistrationError
from ..geometry import RigidTransform, orthonormalize_transform
from ._icp_kernels import icp_pcl
from .result import RegistrationResult, inlier_statistics

#: ICP variants: our name -> small_gicp ``registration_type``.
ICP_METHODS = {"plane": "PLANE_ICP", "point": "ICP", "gicp": "GICP", "pcl": None}
_CALLER = "align_icp"


@dataclass(frozen=True, eq=False)
class IcpTarget:
    """A target cloud prepared for :func:`align_icp` (build with :func:`prepare_icp_target`).

    Attributes
    ----------
    points_xyz_m : ndarray of shape (M, 3)
        Target points (metres, target frame).
    normals_xyz : ndarray of shape (M, 3) or None
        Unit normals estimated by small_gicp from ``normals_k`` neighbours (zero rows where it had
        fewer than 5 neighbours); None for point-to-point ICP.
    method : str
        ``"plane"``, ``"point"``, ``"gicp"`` or ``"pcl"``.
    tree : cKDTree
        The points' KD-tree (scoring, ``"pcl"``).
    normals_k : int
        Neighbours of the normals or covariances.
    sg_cloud, sg_tree
        small_gicp's cloud (with its normals or covariances) and KD-tree, built on first use: the pose
        pipeline's own ICP (the distance field's) only needs the normals, which the on-disk cache keeps.
    """

    points_xyz_m: np.ndarray
    normals_xyz: np.ndarray | None
    method: str
    tree: cKDTree
    normals_k: int = 20
    _small_gicp: list = field(default_factory=list, repr=False)

    @property
    def sg_cloud(self) -> Any:
        return self._small_gicp_parts()[0]

    @property
    def sg_tree(self) -> Any:
        return self._small_gicp_parts()[1]

    def _small_gicp_parts(self) -> list:
        if not self._small_gicp and self.method != "pcl":
            self._small_gicp[:] = _small_gicp_target(self.points_xyz_m, self.method, self.normals_k)
        return self._small_gicp or [None, None]


def _small_gicp_target(pts: np.ndarray, method: str, normals_k: int) -> list:
    """small_gicp's cloud of ``pts`` with its normals (``"plane"``) or covariances (``"gicp"``), and its KD-tree."""
    cloud = small_gicp.PointCloud(pts)
    tree = small_gicp.KdTree(cloud)
    if method == "plane":
        small_gicp.estimate_normals(cloud, tree, num_neighbors=normals_k)
    elif method == "gicp":
        small_gicp.estimate_covariances(cloud, tree, num_neighbors=normals_k)
    return [cloud, tree]


def prepare_icp_target(points_xyz_m: Any, *, method: str = "plane", normals_k: int = 20) -> IcpTarget:
    """Prepare a target cloud ``(M, 3)`` (metres) for repeated :func:`align_icp` calls.

    The normals of ``"plane"`` come through the on-disk cache (:mod:`semslam._cache`): on a pose model of 16 laser
    views (~130 000 points) they are 0.1-0.3 s of every class's first pose in a fresh process."""
    from .._cache import cached_arrays

    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller="prepare_icp_target")
    check_choice("method", method, tuple(ICP_METHODS), caller="prepare_icp_target")
    normals_k = check_int("normals_k", normals_k, caller="prepare_icp_target", minimum=5)
    if len(pts) < 3:
        raise RegistrationError(f"ICP needs a target of at least 3 points. Got {len(pts)} instead.")
    target = IcpTarget(pts, None, method, cKDTree(pts), normals_k)
    if method != "plane":
        return target

    def build() -> dict:
        parts = target._small_gicp_parts()  # built now: kept for align_icp
        return {"normals": np.ascontiguousarray(parts[0].normals()[:, :3])}

    normals = cached_arrays("icp_normals_v1", [pts, normals_k], build)["normals"]
    return IcpTarget(pts, normals, method, target.tree, normals_k, target._small_gicp)


def align_icp(
    source_points: Any, target: Any, *, init_T: Any = None, method: str = "plane",
    max_correspondence_m: float = 0.01, max_iterations: int = 30, rotation_eps_rad: float = 1e-4,
    translation_eps_m: float = 1e-5, normals_k: int = 20, transformation_epsilon: float = 1e-8,
    euclidean_fitness_epsilon: float = -np.inf, deadline: float | None = None,
) -> RegistrationResult:
    """Refine ``T_target_source`` by ICP (small_gicp, Gauss-Newton on SE(3), one thread).

    Parameters
    ----------
    source_points : array-like of shape (N, 3)
        Source points (metres, source frame).
    target : array-like of shape (M, 3) or IcpTarget
        Target points (metres, target frame), or a target already prepared with :func:`prepare_icp_target`
        (its ``method`` then wins over ``method``).
    init_T : array-like (4, 4) or RigidTransform, optional
        Initial ``T_target_source`` (identity by default), e.g. the coarse alignment.
    method : {"plane", "point", "gicp", "pcl"}
        Point-to-plane (target normals), point-to-point, generalized ICP (all small_gicp), or ``"pcl"``:
        PCL's ``IterativeClosestPoint`` (point-to-point, SVD steps, PCL's stopping rules; a slow
        numpy loop kept to reproduce PCL's results and unit test).
    max_correspondence_m : float
        Pairs farther apart are ignored by ICP; also the inlier distance of ``fitness`` and ``inlier_rmse_m``.
    max_iterations : int
        Iteration cap.
    rotation_eps_rad, translation_eps_m : float
        Convergence: the update is smaller than both.
    normals_k : int
        Neighbours for target normals (plane) or covariances (gicp, also for the source).
    transformation_epsilon, euclidean_fitness_epsilon : float
        ``"pcl"`` only: PCL's ``setTransformationEpsilon`` (compared with the squared incremental
        translation, and ``1 - eps`` with the cosine of its rotation angle) and ``setEuclideanFitnessEpsilon``
        (relative MSE change; ``-inf`` = off, PCL's default). ``rotation_eps_rad`` and
        ``translation_eps_m`` are ignored then.
    deadline : float, optional
        ``"pcl"`` only: a ``time.perf_counter()`` instant after which no new iteration starts (the result
        is then not converged and ``extras["budget_exhausted"]`` is True). The small_gicp variants run
        their ``max_iterations`` uninterrupted.

    Returns
    -------
    RegistrationResult
        ``fitness`` = inlier fraction of the source, ``inlier_rmse_m`` = RMS point-to-point distance of
        those inliers; ``extras`` holds small_gicp's final error and inlier count.
    """
    t0 = time.perf_counter()
    src = as_float_array("source_points", source_points, (None, 3), caller=_CALLER)
    if not isinstance(target, IcpTarget):
        target = prepare_icp_target(target, method=method, normals_k=normals_k)
    max_corr = check_positive("max_correspondence_m", max_correspondence_m, caller=_CALLER)
    max_iterations = check_int("max_iterations", max_iterations, caller=_CALLER, minimum=1)
    rot_eps = check_positive("rotation_eps_rad", rotation_eps_rad, caller=_CALLER)
    trans_eps = check_positive("translation_eps_m", translation_eps_m, caller=_CALLER)
    if len(src) < 3:
        raise RegistrationError(f"ICP needs a source of at least 3 points. Got {len(src)} instead.")
    T0 = np.eye(4) if init_T is None else (
        init_T.matrix if isinstance(init_T, RigidTransform) else RigidTransform(init_T).matrix)
    if target.method == "pcl":
        return _align_pcl(src, target, T0, max_corr, max_iterations, transformation_epsilon,
                          euclidean_fitness_epsilon, deadline, t0)
    return _align_small_gicp(src, target, T0, max_corr, max_iterations, rot_eps, trans_eps, normals_k, t0)


def _align_pcl(src: np.ndarray, target: IcpTarget, T0: np.ndarray, max_corr: float, max_iterations: int,
               transformation_epsilon: float, euclidean_fitness_epsilon: float, deadline: float | None,
               t0: float) -> RegistrationResult:
    """:func:`align_icp` with ``method="pcl"``: PCL's loop (:func:`._icp_kernels.icp_pcl`) until ``deadline``."""
    t1 = time.perf_counter()
    end = np.inf if deadline is None else float(deadline)
    T, n_it, converged = icp_pcl(src, target.tree, T0, max_corr, max_iterations, float(transformation_epsilon),
                                 float(euclidean_fitness_epsilon), deadline=end)
    extras = {"budget_exhausted": True} if not converged and time.perf_counter() >= end else {}
    return _result(src, target, T, n_it, converged, max_corr, t0, t1, extras)


def _align_small_gicp(src: np.ndarray, target: IcpTarget, T0: np.ndarray, max_corr: float, max_iterations: int,
                      rot_eps: float, trans_eps: float, normals_k: int, t0: float) -> RegistrationResult:
    """:func:`align_icp` with a small_gicp method (one thread; source covariances for GICP)."""
    source = small_gicp.PointCloud(src)
    if target.method == "gicp":
        small_gicp.estimate_covariances(source, num_neighbors=normals_k)
    t1 = time.perf_counter()
    res = small_gicp.align(
        target.sg_cloud, source, target.sg_tree, init_T_target_source=np.array(T0),
        registration_type=ICP_METHODS[target.method], max_correspondence_distance=max_corr,
        num_threads=1, max_iterations=max_iterations, rotation_epsilon=rot_eps, translation_epsilon=trans_eps,
    )
    return _result(src, target, np.array(res.T_target_source), int(res.iterations), bool(res.converged), max_corr,
                   t0, t1, {"sg_error": float(res.error), "sg_num_inliers": int(res.num_inliers)})


def _result(src, target, T, n_iterations, converged, max_corr, t0, t1, extras) -> RegistrationResult:
    t2 = time.perf_counter()
    orthonormalize_transform(T)
    fitness, rmse, n_in = inlier_statistics(src @ T[:3, :3].T + T[:3, 3], target.tree, max_corr)
    return RegistrationResult(
        T_target_source=RigidTransform(T), fitness=fitness, inlier_rmse_m=rmse,
        n_iterations=n_iterations, converged=converged, n_inliers=n_in,
        max_correspondence_m=max_corr, method=f"{target.method}_icp",
        timings_ms={"icp": 1e3 * (t2 - t1), "total": 1e3 * (time.perf_counter() - t0)},
        extras=extras,
    )
