"""The node's low-latency prediction: the published mode's filter state carried forward from the filter's time to the
newest attitude sample (:meth:`semslam.run.ros1.live.LiveSlam.predict_to`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Prediction", "carry_forward", "session_attitude"]


@dataclass(frozen=True, eq=False)
class Prediction:
    """The filter's state carried to ``stamp_s`` (world NED, body FRD); ``horizon_s``: how far from the filter."""

    stamp_s: float
    position_ned_m: np.ndarray
    position_cov_m2: np.ndarray
    rpy_rad: np.ndarray
    attitude_cov_world_rad2: np.ndarray | None
    velocity_body_mps: np.ndarray
    velocity_cov: np.ndarray
    horizon_s: float


def session_attitude(s) -> tuple[np.ndarray, np.ndarray | None]:
    """The session's attitude (rpy NED, yaw-bias corrected) at its current time and its world covariance."""
    rpy, f = s.attitude.at(s.t)
    rpy = np.array(rpy, dtype=float)
    rpy[2] = (rpy[2] - s.ekf.yaw_bias_rad() + np.pi) % (2 * np.pi) - np.pi
    return rpy, s.attitude.cov_world(rpy, f)


def carry_forward(s, t: float, recent_attitude: list, recent_dvl: list) -> Prediction:
    """The session ``s``'s filter state carried from its time ``s.t <= t`` to ``t`` through ``recent_attitude``
    (``(stamp, rpy)``, received after the filter's time) and the valid DVL samples ``recent_dvl`` (``(stamp,
    velocity in the DVL frame)``): see :meth:`~semslam.run.ros1.live.LiveSlam.predict_to`."""
    from ...geometry import rotation_from_rpy

    ts = float(s.t)
    ekf = s.ekf
    p, v = ekf.position_ned_m.copy(), ekf.velocity_body_mps.copy()
    v_filter = v.copy()
    bias = ekf.yaw_bias_rad()
    prev, rpy, R = ts, None, None
    dvl = sorted(recent_dvl, key=lambda x: x[0])
    k = 0
    for ti, a in sorted(recent_attitude, key=lambda x: x[0]):
        if ti > t:
            break
        while k < len(dvl) and dvl[k][0] <= prev:  # the newest DVL sample at the interval's start
            v = s.dvl.body_velocity(dvl[k][1])
            k += 1
        rpy = a.copy()
        rpy[2] -= bias
        R = rotation_from_rpy(*rpy)
        p += R @ v * (ti - prev)
        prev = ti
    att_rpy, att_cov = session_attitude(s)
    if rpy is None:
        rpy, R = att_rpy, rotation_from_rpy(*att_rpy)
    else:
        rpy[2] = (rpy[2] + np.pi) % (2 * np.pi) - np.pi
    dt = t - ts
    P = ekf.position_cov_m2 + dt * dt * (R @ ekf.velocity_cov @ R.T)
    return Prediction(t, p, P, rpy, att_cov, v if k else v_filter, ekf.velocity_cov.copy(), dt)
