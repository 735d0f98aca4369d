"""What a SLAM run gives: the state at any time (:class:`SlamEstimate`), and the history of a whole run with its
map and metrics (:class:`SlamResult`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import SlamConfig


@dataclass(frozen=True, eq=False)
class LandmarkEstimate:
    """A mapped landmark (pose in the world frame, covariance x y z roll pitch yaw). The error fields are
    filled by :func:`semslam.evaluation.slam_run.evaluate_run` when ground truth exists (NaN otherwise)."""

    landmark_id: int
    label: str
    pose_xyzrpy: np.ndarray
    covariance_6x6: np.ndarray
    first_seen_s: float
    last_seen_s: float
    n_updates: int
    matched_object: str = ""
    position_error_m: float = float("nan")
    orientation_error_rad: float = float("nan")
    nees_position: float = float("nan")  #: 3 dof, against the matched object's true position
    nees_pose: float = float("nan")  #: 6 dof (modulo a discrete symmetry); NaN for a continuous symmetry
    name: str = ""  #: the object name carried by the detections that created it (simulated data), else ""


@dataclass(frozen=True, eq=False)
class SlamEstimate:
    """The filter's state at ``stamp_s``: vehicle position (world NED) and body velocity with covariances,
    the AHRS yaw bias (0 unless estimated) and the landmarks."""

    stamp_s: float
    position_ned_m: np.ndarray
    position_cov_m2: np.ndarray
    velocity_body_mps: np.ndarray
    velocity_cov: np.ndarray
    yaw_bias_rad: float
    landmarks: list[LandmarkEstimate]


@dataclass(frozen=True, eq=False)
class SlamResult:
    """History of one run (arrays for plots) and its metrics. ``K`` history epochs."""

    mode: str
    stamps_s: np.ndarray  #: (K,)
    position_ned_m: np.ndarray  #: (K, 3)
    position_cov_m2: np.ndarray  #: (K, 3, 3)
    velocity_body_mps: np.ndarray  #: (K, 3)
    velocity_cov: np.ndarray  #: (K, 3, 3)
    yaw_bias_rad: np.ndarray  #: (K,)
    truth_position_ned_m: np.ndarray | None  #: (K, 3)
    landmarks: list[LandmarkEstimate]
    update_log: list[dict]
    metrics: dict
    config: SlamConfig
    dvl_calibration: np.ndarray | None = None  #: (K, 8) [b (3), slope b (3) (m/s), k, delta (rad)] if estimated
    yaw_bias_var_rad2: np.ndarray | None = None  #: (K,) variance of the yaw-bias estimate (pose+heading mode)
    #: the RTS-smoothed trajectory (estimate at each epoch from the whole mission), None unless smoothed
    smoothed_position_ned_m: np.ndarray | None = None  #: (K, 3)
    smoothed_position_cov_m2: np.ndarray | None = None  #: (K, 3, 3)
    smoothed_velocity_body_mps: np.ndarray | None = None  #: (K, 3)
    #: (K, 3) vehicle roll, pitch, yaw (rad, NED): the AHRS attitude at each epoch, yaw corrected by the estimated
    #: yaw bias (the filter's attitude: an input, not a state, so it has no covariance here)
    attitude_rpy_rad: np.ndarray | None = None
    #: (6L, 6L) joint covariance of the final map's landmark poses (their cross-covariances: landmarks mapped
    #: from one trajectory share its errors, e.g. a common GPS offset); None for an old or empty result
    landmark_joint_covariance: np.ndarray | None = None

    @property
    def position_error_m(self) -> np.ndarray | None:
        if self.truth_position_ned_m is None:
            return None
        return np.linalg.norm(self.position_ned_m - self.truth_position_ned_m, axis=1)
