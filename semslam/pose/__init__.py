"""The 6-DoF pose of a recognised object against its model: a global search over hypotheses
(:mod:`~semslam.pose.search`, range images and their index), ICP refinement and the pose covariance with
symmetry handling (:func:`estimate_object_pose`; the per-class model is :class:`PoseModel`). Pairwise
registration of two clouds is :mod:`semslam.registration`.
"""

from .estimate import PoseConfig, PoseEstimate, estimate_object_pose
from .model import PoseModel, prepare_pose_model

__all__ = ["PoseConfig", "PoseEstimate", "PoseModel", "estimate_object_pose", "prepare_pose_model"]
