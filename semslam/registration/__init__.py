"""Pairwise registration of two clouds: prerejective RANSAC on FPFH (coarse), ICP with small_gicp (fine), the
upright 4-DoF alignment, and the ambiguity of a result. The 6-DoF pose of a recognised object against its model
(search, ICP, covariance, symmetries) is :mod:`semslam.pose`.

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
