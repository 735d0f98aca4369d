"""semslam's estimate as ROS messages' numbers, without ROS: the frame convention of the node's outputs.

Convention (REP-103/105, what RViz and most ROS users expect): the world frame ``map`` is ENU (x east, y north,
z up), the vehicle frame ``base_link`` is FLU (x forward, y left, z up). semslam's NED world / FRD body estimate
is converted here, at the border, with :mod:`semslam.io.ros.frames`:

* position: ``p_enu = C_NED_ENU @ p_ned``; covariance ``C P C^T``;
* orientation: ``R_world_enu_vehicle_flu = C_NED_ENU @ R_world_ned_vehicle_frd @ C_FRD_FLU`` as ``quat_xyzw``;
  its covariance (small rotations about the world axes, as ``nav_msgs/Odometry`` orders them after x y z) is the
  AHRS attitude noise rotated into ENU (the attitude is the filter's input: no cross-covariance with position);
* twist: in ``base_link`` (the child frame, as ``nav_msgs/Odometry`` requires): ``v_flu = C_FRD_FLU @ v_frd``;
  the angular rate is not estimated (zero with variance :data:`UNKNOWN_VARIANCE`).

Markers (``visualization_msgs/MarkerArray``): per landmark a covariance ellipsoid (SPHERE scaled along the
eigenvectors of the ENU position covariance, :data:`ELLIPSOID_CHI2_3DOF` = 95 % region) in namespace ``LABEL`` and
a text in namespace ``LABEL/text``, both with id = the landmark id, so that a republished map updates in place.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...geometry import rotation_from_rpy
from ...io.ros.frames import C_FRD_FLU, C_NED_ENU, quat_xyzw_from_R_world_ned_vehicle_frd

__all__ = ["ELLIPSOID_CHI2_3DOF", "UNKNOWN_VARIANCE", "MarkerSpec", "OdometrySpec", "landmark_markers",
           "odometry_spec", "quat_xyzw_from_axes"]

#: the 95 % quantile of chi-square with 3 degrees of freedom: the ellipsoid holds the landmark with 95 % probability
ELLIPSOID_CHI2_3DOF = 7.814727903251178
#: variance given to what the filter does not estimate (the angular rate of the odometry's twist)
UNKNOWN_VARIANCE = 1e6
#: visualization_msgs/Marker constants
SPHERE, TEXT_VIEW_FACING, ADD = 2, 9, 0
TEXT_HEIGHT_M = 0.08


@dataclass(frozen=True, eq=False)
class OdometrySpec:
    """The numbers of a ``nav_msgs/Odometry`` (and of the ``map -> base_link`` TF) in ROS frames."""

    stamp_s: float
    position_enu_m: np.ndarray  #: (3,) of base_link in map
    quat_xyzw: np.ndarray  #: (4,) R_map_enu_base_link_flu, scalar last
    pose_covariance_6x6: np.ndarray  #: x y z (ENU, m^2) then rotations about the map's x y z (rad^2)
    velocity_flu_mps: np.ndarray  #: (3,) in base_link
    twist_covariance_6x6: np.ndarray  #: linear (FLU) then angular


@dataclass(frozen=True, eq=False)
class MarkerSpec:
    """The numbers of one ``visualization_msgs/Marker`` (frame: the map frame)."""

    ns: str
    id: int
    type: int
    position_enu_m: np.ndarray
    quat_xyzw: np.ndarray
    scale: np.ndarray
    rgba: tuple[float, float, float, float]
    text: str = ""
    action: int = ADD
    extra: dict = field(default_factory=dict)


def odometry_spec(stamp_s: float, position_ned_m: Any, position_cov_m2: Any, rpy_ned_frd_rad: Any,
                  attitude_cov_world_ned_rad2: Any, velocity_frd_mps: Any, velocity_cov_frd: Any) -> OdometrySpec:
    """The odometry of a semslam estimate (world NED, body FRD) in the node's frames (module docstring)."""
    C, B = C_NED_ENU, C_FRD_FLU
    pose_cov = np.zeros((6, 6))
    pose_cov[:3, :3] = C @ np.asarray(position_cov_m2, float).reshape(3, 3) @ C.T
    att = np.zeros((3, 3)) if attitude_cov_world_ned_rad2 is None else np.asarray(attitude_cov_world_ned_rad2, float)
    pose_cov[3:, 3:] = C @ att.reshape(3, 3) @ C.T
    twist_cov = np.zeros((6, 6))
    twist_cov[:3, :3] = B @ np.asarray(velocity_cov_frd, float).reshape(3, 3) @ B.T
    twist_cov[3:, 3:] = np.eye(3) * UNKNOWN_VARIANCE
    R = rotation_from_rpy(*np.asarray(rpy_ned_frd_rad, float))
    return OdometrySpec(
        float(stamp_s),
        C @ np.asarray(position_ned_m, float),
        quat_xyzw_from_R_world_ned_vehicle_frd(R),
        pose_cov,
        B @ np.asarray(velocity_frd_mps, float),
        twist_cov,
    )


def quat_xyzw_from_axes(axes: np.ndarray) -> np.ndarray:
    """``quat_xyzw`` of the rotation whose columns are ``axes`` (orthonormal; a reflection is turned into a
    rotation by flipping the last axis)."""
    from ...geometry import quat_wxyz_from_rotation

    R = np.array(axes, float)
    if np.linalg.det(R) < 0:
        R[:, 2] = -R[:, 2]
    w, x, y, z = quat_wxyz_from_rotation(R)
    return np.array([x, y, z, w])


def _colour(label: str) -> tuple[float, float, float]:
    """A stable colour per class (hash of the label, not of the process: the same in every run)."""
    h = hashlib.sha1(label.encode("utf-8")).digest()
    r, g, b = (0.25 + 0.75 * c / 255.0 for c in h[:3])
    return (r, g, b)


def landmark_markers(landmarks: list[Any]) -> list[MarkerSpec]:
    """Two markers per landmark (:class:`~semslam.slam.results.LandmarkEstimate`): its 95 % position ellipsoid
    (namespace = class label) and a text with its class and id (namespace ``LABEL/text``), id = landmark id."""
    out: list[MarkerSpec] = []
    k = float(np.sqrt(ELLIPSOID_CHI2_3DOF))
    for lm in landmarks:
        p_enu = C_NED_ENU @ np.asarray(lm.pose_xyzrpy, float)[:3]
        P = C_NED_ENU @ np.asarray(lm.covariance_6x6, float)[:3, :3] @ C_NED_ENU.T
        vals, vecs = np.linalg.eigh(0.5 * (P + P.T))
        sigma = np.sqrt(np.clip(vals, 0.0, None))
        r, g, b = _colour(lm.label)
        out.append(MarkerSpec(lm.label, int(lm.landmark_id), SPHERE, p_enu, quat_xyzw_from_axes(vecs),
                              np.maximum(2.0 * k * sigma, 1e-3), (r, g, b, 0.4)))
        text = f"{lm.label} #{lm.landmark_id}" + (f" ({lm.name})" if getattr(lm, "name", "") else "")
        out.append(MarkerSpec(f"{lm.label}/text", int(lm.landmark_id), TEXT_VIEW_FACING,
                              p_enu + np.array([0.0, 0.0, 0.1]), np.array([0.0, 0.0, 0.0, 1.0]),
                              np.array([0.0, 0.0, TEXT_HEIGHT_M]), (r, g, b, 1.0), text))
    return out
