"""A streaming SLAM session: feed attitude, DVL, depth and detections as they come, ask for the estimate at any
time, finish to get the run's history, map and smoothed trajectory.

Modes: ``dr`` (DVL + depth + AHRS dead reckoning; detections ignored), ``position`` (object positions only),
``pose`` (the papers' cascade: full-pose test, else position test), ``pose+heading`` (``pose`` with an AHRS
yaw-bias state; observability-constrained when no landmark is surveyed, since a constant bias is then
unobservable).

Time. Every message carries its own stamp (s, one clock). The attitude is the filter's input: a measurement at
``t`` is processed once an attitude sample at or after ``t`` has arrived (the prediction interpolates the
attitude at the midpoint of steps of at most ``max_predict_dt_s``), or at :meth:`SlamSession.finish` (the last
attitude is then held). Pending messages are processed in stamp order (DVL, then depth, then detections at equal
stamps), so messages of different sensors may arrive interleaved in any order within that delay; each sensor's
own stamps must not decrease, and a message older than what the filter already processed raises
:class:`~semslam.errors.SlamError` (it would otherwise be silently applied at the wrong time). Equal stamps are
processed in arrival order. DVL and depth samples before the session's start stamp are ignored. The filter
predicts through every gap of the attitude: an attitude stamp more than ``LIMITS["stamps.attitude_gap_s"]``
(:mod:`semslam.limits`, one hour) after the previous one, or after the start, raises :class:`SlamError`, as does
a run whose span would need more than ``stamps.history_epochs`` history epochs or ``stamps.predict_steps``
prediction steps at its settings. DVL velocities and depths outside ``nav.*`` are skipped and counted
(``metrics["skipped_implausible"]``).

History. The state is recorded every ``1 / history_rate_hz`` s from the start (the epochs of the result and of
the RTS smoother).
"""

from __future__ import annotations

import heapq
import math
from typing import Any

import numpy as np

from .._validation import as_float_array, check_choice
from ..dataset import VehicleDescription
from ..detection import Detection
from ..errors import SlamError
from ..geometry import rotation_from_rpy
from ..limits import LIMITS
from ..symmetry import Symmetry
from .config import MODES, SlamConfig
from .ekf import SemanticEkf
from .mapping import ObjectMapper
from .results import LandmarkEstimate, SlamEstimate, SlamResult
from .sensors import AttitudeInput, DepthModel, DvlModel, PositionFixModel, SensorGate
from .session_inputs import (check_attitude_stamp, check_initial_position_cov, check_joint_covariance, check_stamp,
                             check_start_stamp, check_surveyed_landmarks, initial_covariance)
from .session_result import landmark_estimates, slam_result
from .smoother import RtsRecorder

_ORDER = {"dvl": 1, "depth": 2, "fix": 3, "detections": 4}
#: at finish, a message later than the last attitude sample by more than this is skipped (counted in the metrics)
MAX_ATTITUDE_EXTRAPOLATION_S = 1.0


class SlamSession:
    """The semantic EKF-SLAM fed message by message (see the module docstring).

    Parameters
    ----------
    vehicle : VehicleDescription
        Mounting and sensor figures (the filter's noise model).
    mode : {"dr", "position", "pose", "pose+heading"}
    config : SlamConfig, optional
    symmetries : dict, optional
        Symmetry per class label (no symmetry for a class not listed).
    start_stamp_s : float, optional
        Start of the run (the first epoch). Default: the stamp of the first message.
    initial_position_ned_m, initial_velocity_body_mps : array-like of shape (3,)
        The start point and the initial body velocity (known to ``initial_velocity_sigma_mps``).
        ``initial_velocity_body_mps=None``: not known (no DVL at the start): zero, known to
        ``config.motion.unknown_velocity_sigma_mps``. :func:`semslam.slam.initial.initial_state` derives both from
        the dive's own data (depth sensor, position fixes, DVL).
    initial_position_cov_m2 : array-like of shape (3, 3), optional
        The start point's covariance. Default: ``config.initialisation.initial_position_sigma_m`` squared per axis
        (a start point that defines a local frame).
    start : InitialState, optional
        The start found from the dive's own data (:func:`semslam.slam.initial.initial_state`): replaces the four
        arguments above, and the depth sample and fix it was taken from are not applied again when they arrive.

    While no DVL sample has been accepted for ``config.motion.unaided_after_s`` (an outage, a dive without DVL),
    the prediction uses the unaided process noise ``config.motion.unaided_velocity_rw_mps_per_sqrt_s``.
    """

    def __init__(self, vehicle: VehicleDescription, *, mode: str = "pose", config: SlamConfig | None = None,
                 symmetries: dict[str, Symmetry] | None = None, start_stamp_s: float | None = None,
                 initial_position_ned_m: Any = (0.0, 0.0, 0.0), initial_velocity_body_mps: Any = (0.0, 0.0, 0.0),
                 initial_position_cov_m2: Any = None, start: Any = None) -> None:
        check_choice("mode", mode, MODES, caller="SlamSession")
        if not isinstance(vehicle, VehicleDescription):
            raise SlamError(f"The 'vehicle' argument of SlamSession must be a VehicleDescription. Got "
                            f"{type(vehicle).__name__} instead.")
        cfg = SlamConfig() if config is None else config
        if not isinstance(cfg, SlamConfig):
            raise SlamError(
                f"The 'config' argument of SlamSession must be a SlamConfig. Got {type(cfg).__name__} instead."
            )
        self.vehicle, self.cfg, self.mode = vehicle, cfg, mode
        self._used: dict = {}
        if start is not None:
            from .initial import InitialState

            if not isinstance(start, InitialState):
                raise SlamError(f"The 'start' argument of SlamSession must be an InitialState. Got "
                                f"{type(start).__name__} instead.")
            start_stamp_s, initial_position_ned_m = start.start_stamp_s, start.position_ned_m
            initial_velocity_body_mps, initial_position_cov_m2 = start.velocity_body_mps, start.position_cov_m2
            self._used = dict(start.used_stamps_s)
        self.symmetries = dict(symmetries or {})
        self._p0 = as_float_array(
            "initial_position_ned_m", initial_position_ned_m, (3,), caller="SlamSession", error=SlamError
        )
        self._P0p = check_initial_position_cov(initial_position_cov_m2)
        self._v_known = initial_velocity_body_mps is not None
        self._v0 = np.zeros(3) if not self._v_known else as_float_array(
            "initial_velocity_body_mps", initial_velocity_body_mps, (3,), caller="SlamSession", error=SlamError)
        self._t0 = check_start_stamp(start_stamp_s)
        self.attitude = AttitudeInput(vehicle.attitude.noise_rpy_rad, cfg.motion.propagate_attitude_noise)
        self.dvl = DvlModel(vehicle, cfg.motion.dvl_use_beam_ranges)
        self.depth = DepthModel(vehicle)
        self.fix = PositionFixModel()
        self.gate = SensorGate(cfg)
        self.log: list[dict] = []
        self.ekf: SemanticEkf | None = None
        self._pending: list = []
        self._seq = 0
        self._last_stamp: dict[str, float] = {}
        self._processed_s = -math.inf
        self._t_end = -math.inf
        self._surveyed: list = []
        self._joint = None
        self._H: dict[str, list] = {k: [] for k in ("t", "p", "Pp", "v", "Pv", "b", "bv", "c", "rpy")}
        self._next_hist = 0
        self._finished = False
        self._before_start = 0  #: DVL and depth samples before the start stamp (ignored, counted)
        #: DVL and depth samples outside their plausibility range (semslam.limits; skipped, counted)
        self._implausible = {"dvl": 0, "depth": 0}

    # ------------------------------------------------------------------ set-up
    def _start(self, stamp_s: float) -> None:
        cfg, vehicle = self.cfg, self.vehicle
        self._t0 = stamp_s if self._t0 is None else self._t0
        d = vehicle.dvl
        heading = self.mode == "pose+heading"
        calib = cfg.motion.dvl_calibration and any(v > 0 for v in (d.scale_factor_sigma, d.misalignment_sigma_rad,
                                                               d.bias_sigma_mps, d.degraded_bias_sigma_mps))
        self._last_dvl_s = self._t0 if self._v_known else -math.inf  #: last accepted DVL sample (unaided after it)
        self._was_unaided = False
        P0 = initial_covariance(cfg, d, velocity_known=self._v_known, dvl_calibration=calib, yaw_bias=heading,
                                position_cov_m2=self._P0p)
        ekf = self._make_filter(self._p0, self._v0, P0, yaw_bias=heading, dvl_calibration=calib,
                                dvl_bias_sigma_mps=d.bias_sigma_mps, dvl_bias_tau_s=d.bias_tau_s,
                                dvl_slope_bias_sigma_mps=d.degraded_bias_sigma_mps,
                                dvl_slope_bias_tau_s=d.degraded_bias_tau_s)
        ekf.constrain_heading_nullspace(heading and cfg.motion.observability_constrained)
        ekf.recorder = self._make_recorder()
        self.ekf = ekf
        self.t = self._t0
        self._filter_ready(ekf)
        self.mapper = self._make_mapper(ekf)
        if self._surveyed:
            names, labels, poses, covs = zip(*self._surveyed)
            self.mapper.add_surveyed(self._t0, names, labels, poses, cfg.initialisation.survey_position_sigma_m,
                                     cfg.initialisation.survey_rotation_sigma_rad, covs, joint=self._joint)

    # Factory hooks of :meth:`_start`: a backend subclass (the factor graph's
    # :class:`~semslam.slam.graph.GraphSession`) replaces the filter, the smoother's recorder and the mapper here.
    def _make_filter(self, x0_position, v0_body, P0, **kw) -> SemanticEkf:
        """The filter (the arguments of :class:`SemanticEkf`)."""
        return SemanticEkf(x0_position, v0_body, P0, **kw)

    def _make_recorder(self) -> RtsRecorder | None:
        """The RTS smoother's recorder (None: no smoothed trajectory)."""
        if not self.cfg.output.smooth:
            return None
        return RtsRecorder(n_keep=6, max_bytes=self.cfg.output.smoother_max_mb * 1e6)

    def _filter_ready(self, ekf: SemanticEkf) -> None:
        """Called once the filter holds its initial state (heading constraint applied), before the mapper is made
        and before the surveyed landmarks are added."""

    def _make_mapper(self, ekf: SemanticEkf) -> ObjectMapper:
        """The object mapper (gating, association, consensus initialisation) over ``ekf``."""
        return ObjectMapper(ekf, self.cfg, self.mode, self.symmetries, self.vehicle.T_vehicle_scanner, self._log)

    def add_surveyed_landmarks(self, names, labels, T_world_objects, covariances_6x6=None,
                               joint_covariance=None) -> None:
        """Landmarks known a priori (a surveyed structure, an earlier dive's map), each with its 6x6 covariance
        (x, y, z, roll, pitch, yaw) or, without, known to ``config.initialisation.survey_position_sigma_m`` and
        ``survey_rotation_sigma_rad``; before the first message only. ``joint_covariance`` (6L, 6L): the landmarks'
        joint covariance (an earlier dive's map, whose landmarks share that dive's errors); it replaces the
        per-landmark ones (the EKF keeps it whole; the graph backends use its diagonal blocks)."""
        if self.ekf is not None:
            raise SlamError("SlamSession.add_surveyed_landmarks must be called before the first message.")
        if joint_covariance is not None:
            J = check_joint_covariance(joint_covariance, names, bool(self._surveyed))
            self._joint = J
            covariances_6x6 = [J[6 * k:6 * k + 6, 6 * k:6 * k + 6] for k in range(len(list(names)))]
        self._surveyed += check_surveyed_landmarks(names, labels, T_world_objects, covariances_6x6)

    # ------------------------------------------------------------------ messages
    def _stamp(self, stream: str, stamp_s: Any) -> float:
        t = check_stamp(stream, stamp_s, finished=self._finished, last_s=self._last_stamp.get(stream, -math.inf),
                        processed_s=self._processed_s)
        if stream == "attitude":
            check_attitude_stamp(t, self._last_stamp.get("attitude", self._t0), self._t0, self.cfg)
        self._last_stamp[stream] = t
        if self.ekf is None:
            self._start(t)
        return t

    def _push(self, t: float, kind: str, payload) -> None:
        heapq.heappush(self._pending, (t, _ORDER[kind], self._seq, kind, payload))
        self._seq += 1
        self._drain(final=False)

    def add_attitude(self, stamp_s: float, rpy_rad: Any) -> None:
        """AHRS roll, pitch, yaw (rad) of the vehicle in the world NED frame."""
        t = self._stamp("attitude", stamp_s)
        rpy = as_float_array("rpy_rad", rpy_rad, (3,), caller="SlamSession.add_attitude", error=SlamError)
        self.attitude.add(t, rpy)
        self._t_end = max(self._t_end, t)
        self._drain(final=False)

    def add_dvl(self, stamp_s: float, velocity_mps: Any, *, valid: bool = True, beam_range_m: Any = None) -> None:
        """DVL velocity (m/s) in the DVL frame (NaN allowed when not ``valid``), optional per-beam slant ranges."""
        t = self._stamp("dvl", stamp_s)
        v = as_float_array("velocity_mps", velocity_mps, (3,), caller="SlamSession.add_dvl", error=SlamError,
                           finite=bool(valid))
        r = (
            None
            if beam_range_m is None
            else as_float_array(
                "beam_range_m", beam_range_m, (None,), caller="SlamSession.add_dvl", error=SlamError, finite=False
            )
        )
        self._t_end = max(self._t_end, t)
        if valid and not all(LIMITS["nav.dvl_velocity_mps"].contains(float(x)) for x in v):
            self._implausible["dvl"] += 1  # a corrupt record: after 5 in a row the sensor gate would accept them
        elif t >= self._t0:
            self._push(t, "dvl", (bool(valid), v, r))
        else:
            self._before_start += 1

    def add_depth(self, stamp_s: float, depth_m: float) -> None:
        """Pressure depth (m, positive down)."""
        t = self._stamp("depth", stamp_s)
        z = as_float_array("depth_m", [depth_m], (1,), caller="SlamSession.add_depth", error=SlamError)[0]
        self._t_end = max(self._t_end, t)
        if not LIMITS["nav.depth_m"].contains(float(z)):
            self._implausible["depth"] += 1
        elif self._used.get("depth") == t:  # the start's own depth sample: not a second measurement
            del self._used["depth"]
        elif t >= self._t0:
            self._push(t, "depth", z)
        else:
            self._before_start += 1

    def add_position_fix(self, stamp_s: float, position_ne_m: Any, covariance_ne_m2: Any) -> None:
        """A horizontal position fix (GPS, USBL): north, east (m) in the world frame and its 2x2 covariance (m^2).
        Gated (see :class:`~semslam.slam.sensors.PositionFixModel`); a fix with a NaN or a covariance that is not
        positive definite is skipped and counted."""
        t = self._stamp("fix", stamp_s)
        p = as_float_array("position_ne_m", position_ne_m, (2,), caller="SlamSession.add_position_fix",
                           error=SlamError, finite=False)
        C = as_float_array("covariance_ne_m2", covariance_ne_m2, (2, 2), caller="SlamSession.add_position_fix",
                           error=SlamError, finite=False)
        self._t_end = max(self._t_end, t)
        usable = bool(np.isfinite(p).all() and np.isfinite(C).all() and abs(C[0, 1] - C[1, 0]) <= 1e-9 * abs(C).max()
                      and C[0, 0] > 0 and np.linalg.det(C) > 0)
        if not usable:
            self._log(stamp_s=t, kind="fix_unusable", accepted=False)
        elif self._used.get("fix") == t:  # the fix the start was taken from
            del self._used["fix"]
        elif t >= self._t0:
            self._push(t, "fix", (p, 0.5 * (C + C.T)))
        else:
            self._before_start += 1

    def add_detections(self, stamp_s: float, detections: list[Detection]) -> None:
        """Detections made at ``stamp_s`` (poses in the scanner frame); ignored in ``dr`` mode."""
        t = self._stamp("detections", stamp_s)
        dets = list(detections)
        if not all(isinstance(d, Detection) for d in dets):
            raise SlamError("The 'detections' argument of SlamSession.add_detections must hold Detection objects.")
        if self.mode != "dr" and dets:
            self._push(t, "detections", dets)

    # ------------------------------------------------------------------ processing
    def _drain(self, final: bool) -> None:
        covered = math.inf if final else self.attitude.last_stamp_s
        while self._pending and self._pending[0][0] <= covered:
            t, _, _, kind, payload = heapq.heappop(self._pending)
            if t > self.attitude.last_stamp_s + MAX_ATTITUDE_EXTRAPOLATION_S:
                # at finish, beyond the last attitude: the filter has no input to predict with (and a stamp far in
                # the future would make it predict for hours). Skipped and counted, never silently.
                self._log(stamp_s=t, kind=f"{kind}_beyond_attitude", accepted=False)
                continue
            self._history_before(t)
            self._predict_to(t)
            if self.ekf.heading_constrained and (
                self._was_unaided or t - self._last_dvl_s > self.cfg.motion.unaided_after_s
            ):
                self._was_unaided = True
                # unaided, the velocity the null direction was propagated with may have been far off: re-anchor it
                # on the current estimate (a rotation about the vehicle now; the launch prior is not a measurement)
                # so that the projection removes the direction the measurements really cannot see. Once unaided,
                # for the rest of the run: a direction propagated on from an outage's estimates made the filter
                # overconfident (first-half outage, 30 runs: ANEES 27 with the constraint resumed, 3.3 without)
                self.ekf.constrain_heading_nullspace(True)
            if kind == "dvl":
                self._update_dvl(t, *payload)
            elif kind == "depth":
                self._log(stamp_s=t, **self.depth.update(self.ekf, self.gate, payload))
            elif kind == "fix":
                self._log(stamp_s=t, **self.fix.update(self.ekf, self.gate, *payload))
            else:
                rpy, f = self.attitude.at(t)
                self.mapper.process(t, payload, rotation_from_rpy(*rpy), self.attitude.cov_world(rpy, f))
            self._processed_s = max(self._processed_s, t)
            self.attitude.forget_before(self.t)

    def _hist_stamp(self, k: int) -> float:
        return self._t0 + k * (1.0 / self.cfg.output.history_rate_hz)

    def _history_before(self, t: float, inclusive: bool = False) -> None:
        """Record every history epoch before ``t`` (at or before with ``inclusive``)."""
        while True:
            h = self._hist_stamp(self._next_hist)
            if h > t or (h == t and not inclusive):
                return
            self._predict_to(h)
            self._record(h)
            self._processed_s = max(self._processed_s, h)
            self._next_hist += 1

    def _predict_to(self, t: float) -> None:
        cfg, ekf = self.cfg, self.ekf
        degraded = bool(ekf.dvl_calibration and self.dvl.degraded)
        while self.t < t - 1e-12:
            dt = min(cfg.motion.max_predict_dt_s, t - self.t)
            rpy, f = self.attitude.at(self.t + dt / 2)
            unaided = self.t - self._last_dvl_s > cfg.motion.unaided_after_s
            ekf.predict(dt, rotation_from_rpy(*rpy), velocity_rw=cfg.motion.unaided_velocity_rw_mps_per_sqrt_s
                        if unaided else cfg.motion.velocity_rw_mps_per_sqrt_s,
                        attitude_cov_world=self.attitude.cov_world(rpy, f),
                        yaw_bias_rw=self.vehicle.attitude.yaw_bias_walk_rad_per_sqrt_s, dvl_on_slope=degraded)
            self.t += dt

    def _update_dvl(self, t: float, valid: bool, v: np.ndarray, ranges) -> None:
        flat = None
        if ranges is not None:
            flat = self.dvl.bottom_flat(ranges, rotation_from_rpy(*self.attitude.at(t)[0]))
            if flat is not None:
                self.dvl.degraded = not flat
        if not valid:
            self._log(stamp_s=t, kind="dvl_dropout", accepted=False)
            return
        rec = self.dvl.update(self.ekf, self.gate, self.dvl.body_velocity(v), flat)
        if rec["accepted"]:
            self._last_dvl_s = t
        self._log(stamp_s=t, **rec)

    def _record(self, t: float) -> None:
        ekf, H = self.ekf, self._H
        if ekf.recorder is not None:
            ekf.recorder.mark(ekf)
        H["t"].append(t)
        H["p"].append(ekf.position_ned_m.copy())
        H["Pp"].append(ekf.position_cov_m2.copy())
        H["v"].append(ekf.velocity_body_mps.copy())
        H["Pv"].append(ekf.velocity_cov.copy())
        H["b"].append(ekf.yaw_bias_rad())
        H["bv"].append(ekf.yaw_bias_var_rad2())
        H["c"].append(ekf.dvl_calibration_state())
        rpy = self.attitude.at(t)[0]
        rpy[2] = (rpy[2] - ekf.yaw_bias_rad() + np.pi) % (2 * np.pi) - np.pi
        H["rpy"].append(rpy)

    def _log(self, **kw) -> None:
        self.log.append(kw)

    # ------------------------------------------------------------------ outputs
    def _landmarks(self) -> list[LandmarkEstimate]:
        return landmark_estimates(self.ekf)

    def estimate(self) -> SlamEstimate:
        """The current estimate (after every message the attitude covers)."""
        if self.ekf is None:
            raise SlamError("SlamSession.estimate needs at least one message.")
        ekf = self.ekf
        return SlamEstimate(self.t, ekf.position_ned_m.copy(), ekf.position_cov_m2.copy(), ekf.velocity_body_mps.copy(),
                            ekf.velocity_cov.copy(), ekf.yaw_bias_rad(), self._landmarks())

    def finish(self) -> SlamResult:
        """Process what is pending (holding the last attitude), record the remaining epochs up to the last
        navigation stamp, smooth, and return the run's :class:`SlamResult` (no ground truth: see
        :func:`semslam.evaluation.slam_run.evaluate_run`)."""
        if self.ekf is None or not len(self.attitude):
            raise SlamError("The session has no attitude sample: the filter needs the attitude as input.")
        if self._finished:
            raise SlamError("SlamSession.finish was already called.")
        self._drain(final=True)
        self._history_before(min(self._t_end, self.attitude.last_stamp_s + MAX_ATTITUDE_EXTRAPOLATION_S) + 1e-9)
        self._finished = True
        return self._result()

    def _result(self) -> SlamResult:
        return slam_result(self.mode, self.cfg, self.ekf, self._H, self.log, self._before_start, self._implausible)
