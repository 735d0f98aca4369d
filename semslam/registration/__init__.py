"""Registration and pose estimation: prerejective RANSAC on FPFH (coarse), ICP with small_gicp (fine),
pose covariance and symmetry handling for recognised objects.

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

from .pose import PoseConfig, PoseEstimate, PoseModel, estimate_object_pose, prepare_pose_model  # noqa: E402

__all__ += ["PoseConfig", "PoseEstimate", "PoseModel", "estimate_object_pose", "prepare_pose_model"]
