"""The inputs of :class:`~semslam.slam.session.SlamSession`: the checks of its start arguments, of the surveyed
landmarks and of every message's stamp (each raises :class:`~semslam.errors.SlamError` naming the argument, what
was expected and what was given), and the filter's initial covariance from the start and the settings."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .._validation import as_float_array
from ..errors import SlamError
from ..geometry import RigidTransform
from ..limits import LIMITS, check as check_limit

__all__ = ["check_attitude_stamp", "check_initial_position_cov", "check_joint_covariance", "check_stamp",
           "check_start_stamp", "check_surveyed_landmarks", "initial_covariance"]


def check_initial_position_cov(initial_position_cov_m2: Any) -> np.ndarray | None:
    """The start point's covariance, symmetrised (None when not given)."""
    if initial_position_cov_m2 is None:
        return None
    P = as_float_array("initial_position_cov_m2", initial_position_cov_m2, (3, 3), caller="SlamSession",
                       error=SlamError)
    if not np.allclose(P, P.T) or np.linalg.eigvalsh(0.5 * (P + P.T)).min() <= 0:
        raise SlamError("The 'initial_position_cov_m2' argument of SlamSession must be symmetric positive "
                        f"definite. Got {P.tolist()} instead.")
    return 0.5 * (P + P.T)


def check_start_stamp(start_stamp_s: Any) -> float | None:
    """The start stamp (s) as a float (None when not given)."""
    if start_stamp_s is not None:
        try:
            ok = not isinstance(start_stamp_s, bool) and math.isfinite(float(start_stamp_s))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise SlamError(f"The 'start_stamp_s' argument of SlamSession must be finite (seconds). "
                            f"Got {start_stamp_s!r} instead.")
    return None if start_stamp_s is None else float(start_stamp_s)


def check_joint_covariance(joint_covariance: Any, names: Any, surveyed_before: bool) -> np.ndarray:
    """The surveyed landmarks' joint covariance (6L, 6L), symmetrised: positive definite, given in a single call."""
    J = as_float_array("joint_covariance", joint_covariance, (6 * len(list(names)), 6 * len(list(names))),
                       caller="SlamSession.add_surveyed_landmarks", error=SlamError)
    J = 0.5 * (J + J.T)
    if surveyed_before or np.linalg.eigvalsh(J).min() <= 0:
        raise SlamError("The joint covariance of the surveyed landmarks must be positive definite, and given "
                        "in a single call.")
    return J


def check_surveyed_landmarks(names: Any, labels: Any, T_world_objects: Any, covariances_6x6: Any) -> list[tuple]:
    """``(name, label, pose, covariance or None)`` per surveyed landmark, each covariance symmetrised."""
    names, labels, poses = list(names), list(labels), list(T_world_objects)
    if not (len(names) == len(labels) == len(poses)) or not all(isinstance(T, RigidTransform) for T in poses):
        raise SlamError("SlamSession.add_surveyed_landmarks needs as many names, labels and RigidTransform poses.")
    covs = [None] * len(poses) if covariances_6x6 is None else list(covariances_6x6)
    if len(covs) != len(poses):
        raise SlamError("SlamSession.add_surveyed_landmarks needs as many covariances as poses.")
    for k, C in enumerate(covs):
        if C is not None:
            C = as_float_array("covariances_6x6", C, (6, 6), caller="SlamSession.add_surveyed_landmarks",
                               error=SlamError)
            if not np.allclose(C, C.T, atol=1e-12) or np.linalg.eigvalsh(0.5 * (C + C.T)).min() <= 0:
                raise SlamError(f"The covariance of surveyed landmark {names[k]!r} must be symmetric positive "
                                "definite.")
            covs[k] = 0.5 * (C + C.T)
    return list(zip(names, labels, poses, covs))


def check_stamp(stream: str, stamp_s: Any, *, finished: bool, last_s: float, processed_s: float) -> float:
    """A message's stamp (s) on ``stream``: a finite number, not before the stream's last one (``last_s``) nor the
    filter's time (``processed_s``), while the session is not ``finished``."""
    try:
        t = float(stamp_s)
    except (TypeError, ValueError):
        raise SlamError(f"The {stream} stamp must be a number of seconds. Got {stamp_s!r} instead.") from None
    if not math.isfinite(t):
        raise SlamError(f"The {stream} stamp must be finite. Got {stamp_s!r} instead.")
    if finished:
        raise SlamError("The session is finished: no more messages.")
    if t < last_s:
        raise SlamError(f"The {stream} stamps must not decrease. Got {t!r} after {last_s!r}.")
    if t < processed_s:
        raise SlamError(f"A {stream} message stamped {t!r} arrived after the filter had processed up to "
                        f"{processed_s!r}: messages may not arrive later than the attitude that covers them.")
    return t


def check_attitude_stamp(t: float, prev: float | None, t0: float | None, cfg: Any) -> None:
    """An attitude stamp ``t`` within ``semslam.limits``: its gap after the previous one (``prev``, else the start),
    and the history epochs and prediction steps the run up to it needs at ``cfg``'s settings."""
    if prev is not None and t - prev > LIMITS["stamps.attitude_gap_s"].hi:
        # the filter predicts (and records history) through the gap: one stamp at 2^31 s was a hang
        check_limit("stamps.attitude_gap_s", t - prev, f"The gap before the attitude stamp {t!r} s (after {prev!r} "
                    "s; a corrupt stamp?)", error=SlamError)
    span = t - t0 if t0 is not None else 0.0
    if span > 0:  # the whole run's work and memory, from its settings
        out = cfg.output.history_rate_hz
        check_limit("stamps.history_epochs", span * out, f"The history epochs up to the attitude stamp {t!r} s "
                    f"({span:g} s after the start at history_rate_hz = {out:g}; lower it or split the dive)",
                    error=SlamError)
        check_limit("stamps.predict_steps", span / cfg.motion.max_predict_dt_s, "The prediction steps up to "
                    f"the attitude stamp {t!r} s ({span:g} s after the start at max_predict_dt_s = "
                    f"{cfg.motion.max_predict_dt_s:g}; raise it or split the dive)", error=SlamError)


def initial_covariance(cfg: Any, dvl: Any, *, velocity_known: bool, dvl_calibration: bool, yaw_bias: bool,
                       position_cov_m2: np.ndarray | None) -> np.ndarray:
    """The filter's initial covariance: position, body velocity (``initial_velocity_sigma_mps`` when the start
    velocity is known, else ``unknown_velocity_sigma_mps``), the DVL calibration states (``dvl``: the vehicle's
    DVL figures) and the yaw bias; the start point's own covariance replaces the position block when given."""
    init = cfg.initialisation
    v_sigma = np.broadcast_to(init.initial_velocity_sigma_mps if velocity_known
                              else np.asarray(cfg.motion.unknown_velocity_sigma_mps, dtype=float), (3,))
    var0 = [init.initial_position_sigma_m ** 2] * 3 + [float(x) ** 2 for x in v_sigma]
    if dvl_calibration:
        d = dvl
        var0 += [max(d.bias_sigma_mps, 1e-6) ** 2] * 3 + [1e-12] * 3 + [max(d.scale_factor_sigma, 1e-6) ** 2,
                                                                      max(d.misalignment_sigma_rad, 1e-6) ** 2]
    if yaw_bias:
        var0 += [cfg.motion.yaw_bias_sigma_rad ** 2]
    P0 = np.diag(var0)
    if position_cov_m2 is not None:
        P0[0:3, 0:3] = position_cov_m2
    return P0
