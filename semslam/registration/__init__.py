"""Pairwise registration of two clouds (``T_target_source``): :func:`register`, PCL's pipeline (voxel grid,
FPFH, prerejective RANSAC :func:`align_prerejective` for the coarse step, ICP :func:`align_icp` for the fine one),
the gravity-aligned 4-DoF :func:`align_upright` when both clouds know where up is, and the ambiguity of a result
(:mod:`~semslam.registration.ambiguity`). The 6-DoF pose of a recognised object against its model (grid search,
ICP, covariance, symmetries) is :mod:`semslam.pose`.

>>> result = register(source_cloud, target_cloud, RegisterConfig(voxel_m=0.005))   # doctest: +SKIP
>>> result.T_target_source, result.fitness, result.inlier_rmse_m                  # doctest: +SKIP
"""

from .coarse import align_prerejective
from .icp import ICP_METHODS, IcpTarget, align_icp, prepare_icp_target
from .pipeline import RegisterConfig, register
from .result import RegistrationResult
from .upright import UprightConfig, align_upright

__all__ = [
    "ICP_METHODS",
    "IcpTarget",
    "RegisterConfig",
    "RegistrationResult",
    "UprightConfig",
    "align_icp",
    "align_prerejective",
    "align_upright",
    "prepare_icp_target",
    "register",
]
