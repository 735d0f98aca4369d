"""The 6-DoF pose of a recognised object against its class model (:func:`estimate_object_pose`; the per-class
model is :class:`PoseModel`, prepared once by :func:`prepare_pose_model`).

By default a deterministic grid search over SO(3), scored on the model's distance field with a visibility
(free-space) term (:mod:`~semslam.pose.search`, its indexes in :mod:`~semslam.pose.search_index`), then ICP of the
best distinct hypotheses (:mod:`~semslam.pose.icp_refine`), the orientation canonicalised under the object's
symmetry and a 6x6 covariance (:mod:`~semslam.pose.covariance`). The papers' FPFH + prerejective RANSAC is an
option (``PoseConfig(coarse_method="ransac")``), not the default; a prior pose skips the search.
Pairwise registration of two clouds is :mod:`semslam.registration`.
"""

from .estimate import PoseConfig, PoseEstimate, estimate_object_pose
from .model import PoseModel, prepare_pose_model

__all__ = ["PoseConfig", "PoseEstimate", "PoseModel", "estimate_object_pose", "prepare_pose_model"]
