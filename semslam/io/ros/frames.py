"""Frame conventions at the ROS border: REP-103/105 (ENU world, FLU body) <-> semslam (NED world, FRD body).

ROS (REP-103) expresses the world in ENU (x east, y north, z up) and bodies in FLU (x forward, y left,
z up); quaternions are ``quat_xyzw`` (scalar last). semslam uses NED (x north, y east, z down), FRD bodies
(x forward, y starboard, z down) and roll-pitch-yaw ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (intrinsic Z-Y-X,
:mod:`semslam.geometry`). Both changes of axes are fixed permutations/sign flips, their own inverses:

* world: ``x_ned = y_enu``, ``y_ned = x_enu``, ``z_ned = -z_enu`` (matrix :data:`C_NED_ENU`);
* body: ``x_frd = x_flu``, ``y_frd = -y_flu``, ``z_frd = -z_flu`` (matrix :data:`C_FRD_FLU`);
* attitude: ``R_world_ned_vehicle_frd = C_NED_ENU @ R_world_enu_vehicle_flu @ C_FRD_FLU``.

So a vehicle facing east (ROS yaw 0) has semslam yaw +pi/2, facing north has yaw 0; roll keeps its sign
(starboard down is positive in both), pitch changes sign (nose up is positive in FRD) and
``yaw_ned = pi/2 - yaw_enu``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import InputError
from ...geometry import check_rotation, quat_wxyz_from_rotation, rotation_from_quat_wxyz, rpy_from_rotation

__all__ = [
    "C_FRD_FLU",
    "C_NED_ENU",
    "imu_rpy_ned_frd",
    "imu_to_ned_frd",
    "quat_xyzw_from_R_world_ned_vehicle_frd",
    "R_world_enu_vehicle_flu_from_R_world_ned_vehicle_frd",
    "R_world_ned_vehicle_frd_from_quat_xyzw",
    "R_world_ned_vehicle_frd_from_R_world_enu_vehicle_flu",
    "rates_frd_from_flu",
    "rates_flu_from_frd",
    "rpy_ned_frd_from_quat_xyzw",
    "vectors_enu_from_ned",
    "vectors_flu_from_frd",
    "vectors_frd_from_flu",
    "vectors_ned_from_enu",
]

#: ``v_ned = C_NED_ENU @ v_enu`` (and back: the matrix is its own inverse).
C_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: ``v_frd = C_FRD_FLU @ v_flu`` (and back).
C_FRD_FLU = np.diag([1.0, -1.0, -1.0])


def _as_float(value: Any) -> np.ndarray:
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return np.full(0, np.nan)  # reported by the caller's shape check


def _vectors(name: str, value: Any, caller: str) -> np.ndarray:
    arr = _as_float(value)
    if arr.shape[-1:] != (3,) or arr.ndim not in (1, 2):
        raise InputError(f"The {name!r} argument of {caller} must have shape (3,) or (N, 3). Got {arr.shape} instead.")
    return arr


def vectors_ned_from_enu(v_enu: Any) -> np.ndarray:
    """World vectors (positions m, velocities m/s, world angular rates rad/s ...) of shape (3,) or (N, 3):
    ENU -> NED. Both changes of axes are proper rotations (det +1), so pseudovectors map like vectors."""
    return _vectors("v_enu", v_enu, "vectors_ned_from_enu") @ C_NED_ENU.T


def vectors_enu_from_ned(v_ned: Any) -> np.ndarray:
    """World vectors of shape (3,) or (N, 3): NED -> ENU."""
    return _vectors("v_ned", v_ned, "vectors_enu_from_ned") @ C_NED_ENU.T


def vectors_frd_from_flu(v_flu: Any) -> np.ndarray:
    """Body vectors (velocities m/s, accelerations m/s^2, ...) of shape (3,) or (N, 3): FLU -> FRD."""
    return _vectors("v_flu", v_flu, "vectors_frd_from_flu") * np.diag(C_FRD_FLU)


def vectors_flu_from_frd(v_frd: Any) -> np.ndarray:
    """Body vectors of shape (3,) or (N, 3): FRD -> FLU."""
    return _vectors("v_frd", v_frd, "vectors_flu_from_frd") * np.diag(C_FRD_FLU)


def rates_frd_from_flu(omega_flu_rad_s: Any) -> np.ndarray:
    """Body angular rates (rad/s), shape (3,) or (N, 3): FLU -> FRD. Angular velocity is a (pseudo)vector
    and the body change of axes is a proper rotation (pi about x), so it maps like any body vector:
    ``p_frd = p_flu``, ``q_frd = -q_flu``, ``r_frd = -r_flu``."""
    return _vectors("omega_flu_rad_s", omega_flu_rad_s, "rates_frd_from_flu") * np.diag(C_FRD_FLU)


def rates_flu_from_frd(omega_frd_rad_s: Any) -> np.ndarray:
    """Body angular rates (rad/s), shape (3,) or (N, 3): FRD -> FLU."""
    return _vectors("omega_frd_rad_s", omega_frd_rad_s, "rates_flu_from_frd") * np.diag(C_FRD_FLU)


def R_world_ned_vehicle_frd_from_R_world_enu_vehicle_flu(R_world_enu_vehicle_flu: Any) -> np.ndarray:
    """3x3 attitude: ROS (ENU world, FLU body) -> semslam (NED world, FRD body)."""
    R = check_rotation("R_world_enu_vehicle_flu", R_world_enu_vehicle_flu,
                       caller="R_world_ned_vehicle_frd_from_R_world_enu_vehicle_flu")
    return C_NED_ENU @ R @ C_FRD_FLU


def R_world_enu_vehicle_flu_from_R_world_ned_vehicle_frd(R_world_ned_vehicle_frd: Any) -> np.ndarray:
    """3x3 attitude: semslam (NED world, FRD body) -> ROS (ENU world, FLU body)."""
    R = check_rotation("R_world_ned_vehicle_frd", R_world_ned_vehicle_frd,
                       caller="R_world_enu_vehicle_flu_from_R_world_ned_vehicle_frd")
    return C_NED_ENU @ R @ C_FRD_FLU


def _rotation_from_quat_xyzw(quat_xyzw: Any, caller: str) -> np.ndarray:
    q = _as_float(quat_xyzw)
    norm = float(np.linalg.norm(q)) if q.shape == (4,) else 0.0
    if q.shape != (4,) or not np.isfinite(q).all() or norm < 1e-9:
        raise InputError(f"The 'quat_xyzw' argument of {caller} must be 4 finite numbers (x, y, z, w) with a "
                         f"non-zero norm. Got {quat_xyzw!r:.60} instead.")
    return rotation_from_quat_wxyz(q[[3, 0, 1, 2]])


def R_world_ned_vehicle_frd_from_quat_xyzw(quat_xyzw: Any) -> np.ndarray:
    """Attitude of a ROS orientation ``quat_xyzw`` (of FLU body in ENU world, normalised here) as the
    semslam rotation ``R_world_ned_vehicle_frd`` (3x3)."""
    R = _rotation_from_quat_xyzw(quat_xyzw, "R_world_ned_vehicle_frd_from_quat_xyzw")
    return C_NED_ENU @ R @ C_FRD_FLU


def quat_xyzw_from_R_world_ned_vehicle_frd(R_world_ned_vehicle_frd: Any) -> np.ndarray:
    """ROS orientation ``quat_xyzw`` (FLU body in ENU world, scalar last, ``w >= 0``) of a semslam attitude."""
    w, x, y, z = quat_wxyz_from_rotation(R_world_enu_vehicle_flu_from_R_world_ned_vehicle_frd(R_world_ned_vehicle_frd))
    return np.array([x, y, z, w])


def rpy_ned_frd_from_quat_xyzw(quat_xyzw: Any) -> np.ndarray:
    """Roll, pitch, yaw (rad) in semslam's convention (NED/FRD, intrinsic Z-Y-X) of a ROS ``quat_xyzw``."""
    return rpy_from_rotation(R_world_ned_vehicle_frd_from_quat_xyzw(quat_xyzw))


def imu_to_ned_frd(msg: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Convert a ``sensor_msgs/Imu`` (REP-103: ENU orientation, FLU body) to semslam's frames.

    Returns
    -------
    rpy_rad : ndarray of shape (3,)
        Roll, pitch, yaw of ``R_world_ned_vehicle_frd`` (NaN when the message has no orientation, i.e.
        ``orientation_covariance[0] == -1`` as REP-145 specifies).
    angular_velocity_frd_rad_s : ndarray of shape (3,)
    linear_acceleration_frd_m_s2 : ndarray of shape (3,)
    """
    def vec(v: Any) -> np.ndarray:
        return np.array([v.x, v.y, v.z], dtype=np.float64)

    return (imu_rpy_ned_frd(msg), rates_frd_from_flu(vec(msg.angular_velocity)),
            vectors_frd_from_flu(vec(msg.linear_acceleration)))


def imu_rpy_ned_frd(msg: Any) -> np.ndarray:
    """The attitude alone of :func:`imu_to_ned_frd` (what a recorded dive reads of its Imu messages, 20-100 a
    second: the rates and accelerations are not converted)."""
    cov = np.asarray(getattr(msg, "orientation_covariance", ()), dtype=np.float64).reshape(-1)
    if cov.size and cov[0] == -1.0:
        return np.full(3, np.nan)
    o = msg.orientation
    return rpy_ned_frd_from_quat_xyzw([o.x, o.y, o.z, o.w])
