"""Plausibility ranges of every physical quantity entering semslam, in one table, and the one checker.

A value outside its range is a unit mistake (millimetres in a ``_m`` key, degrees in a ``_rad`` key, kPa for
Pa), a corrupt record (a pressure of 1e300 Pa, a quaternion of norm 1e300, a stamp at 2^31 s) or a setting that
would make the work unbounded (``history_rate_hz = 1e9``, ``max_predict_dt_s = 1e-9``). It is refused with one
line naming where the value came from (file and key, topic, argument), the range and the value (wrapped here)::

    The vehicle file 'v.toml' key 'scanner.xyz_m[0]' must be in [-20, 20] m (millimetres given for metres?).
    Got 600.0 instead.

The ranges are wide on purpose: anything a real AUV, its sensors or a sane filter setting can produce passes;
they catch wrong units and corruption, not unusual vehicles. :func:`limits_markdown` renders the table
(``docs/limits.md``, the README's "Limits" section).

Bottom layer: imports only :mod:`semslam.errors`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from typing import Any

from .errors import SemslamError

__all__ = ["Limit", "LIMITS", "PlausibilityError", "check", "check_each", "limits_markdown"]


class PlausibilityError(SemslamError, ValueError):
    """A physical quantity or setting is outside its documented plausibility range (see :data:`LIMITS`)."""


@dataclass(frozen=True)
class Limit:
    """Closed range ``[lo, hi]`` of one quantity, in ``unit`` (SI, radians)."""

    lo: float
    hi: float
    unit: str
    what: str  #: the quantity, for the table
    applies_to: str  #: where semslam checks it
    hint: str = ""  #: the likely mistake when the value is too large (" (degrees given for radians?)")
    integer: bool = False

    def contains(self, value: float) -> bool:
        return math.isfinite(value) and self.lo <= value <= self.hi


_PI = math.pi
_MM = " (millimetres given for metres?)"
_DEG = " (degrees given for radians?)"
_V = "vehicle file"
_S = "SLAM config ([slam.*] of --config)"


def _veh(lo, hi, unit, what, hint="", integer=False) -> Limit:
    return Limit(lo, hi, unit, what, _V, hint, integer)


def _cfg(lo, hi, unit, what, hint="", integer=False) -> Limit:
    return Limit(lo, hi, unit, what, _S, hint, integer)


#: Every range, by the name of the quantity (``vehicle.<section>.<key>``, ``slam.<section>.<key>``, ``bag.*``,
#: ``stamps.*``). Change a range here only: the checks and the documentation both read this table.
LIMITS: dict[str, Limit] = {
    # -- vehicle description: mounting ------------------------------------------------------------------
    "vehicle.extrinsic.xyz_m": _veh(-20.0, 20.0, "m", "extrinsic translation, per axis (scanner, DVL)", _MM),
    "vehicle.extrinsic.rpy_rad": _veh(-2 * _PI, 2 * _PI, "rad", "extrinsic roll, pitch, yaw", _DEG),
    # -- vehicle description: scanner ------------------------------------------------------------------
    "vehicle.scanner.line_count": _veh(0, 1e6, "1", "scanner lines per sweep (0: unknown)", integer=True),
    "vehicle.scanner.min_range_m": _veh(0.0, 1e3, "m", "scanner minimum range (< maximum range)", _MM),
    "vehicle.scanner.max_range_m": _veh(1e-3, 1e3, "m", "scanner maximum range (> minimum range)", _MM),
    "vehicle.scanner.fov_rad": _veh(1e-3, _PI, "rad", "scanner field of view (full cone)", _DEG),
    "vehicle.scanner.rate_hz": _veh(1e-3, 1e3, "Hz", "scanner sweep rate"),
    "vehicle.scanner.camera_xyz_m": _veh(-2.0, 2.0, "m", "triangulation camera from the laser, per axis "
                                         "(scanner frame)", _MM),
    # -- vehicle description: DVL ----------------------------------------------------------------------
    "vehicle.dvl.noise_abs_mps": _veh(1e-4, 1.0, "m/s", "DVL white noise, absolute part (> 0: a noiseless DVL "
                                      "makes the filter overconfident)"),
    "vehicle.dvl.noise_rel": _veh(0.0, 0.5, "1", "DVL white noise, part proportional to speed"),
    "vehicle.dvl.max_speed_mps": _veh(1e-3, 50.0, "m/s", "DVL maximum speed"),
    "vehicle.dvl.degraded_noise_factor": _veh(1.0, 1e3, "1", "DVL noise multiplier off a flat bottom"),
    "vehicle.dvl.scale_factor_sigma": _veh(0.0, 0.5, "1", "DVL scale-factor error (1 sigma)"),
    "vehicle.dvl.misalignment_sigma_rad": _veh(0.0, 0.5, "rad", "DVL misalignment (1 sigma)", _DEG),
    "vehicle.dvl.bias_sigma_mps": _veh(0.0, 1.0, "m/s", "DVL bias (1 sigma)"),
    "vehicle.dvl.bias_tau_s": _veh(1e-3, 1e7, "s", "DVL bias correlation time"),
    "vehicle.dvl.degraded_bias_sigma_mps": _veh(0.0, 1.0, "m/s", "DVL bias off a flat bottom (1 sigma)"),
    "vehicle.dvl.degraded_bias_tau_s": _veh(1e-3, 1e7, "s", "DVL bias correlation time off a flat bottom"),
    "vehicle.dvl.beam_angle_rad": _veh(0.0, 1.2, "rad", "DVL beam angle off the DVL's z axis", _DEG),
    "vehicle.dvl.beam_azimuth_rad": _veh(-2 * _PI, 2 * _PI, "rad", "DVL beam azimuths", _DEG),
    "vehicle.dvl.flat_bottom_tolerance_m": _veh(1e-4, 10.0, "m", "beam bottom-point depth spread on a flat bottom",
                                                _MM),
    # -- vehicle description: AHRS, depth --------------------------------------------------------------
    "vehicle.attitude.noise_rpy_rad": _veh(0.0, 0.5, "rad", "AHRS white noise per axis", _DEG),
    "vehicle.attitude.yaw_bias_walk_rad_per_sqrt_s": _veh(0.0, 0.1, "rad/sqrt(s)", "AHRS yaw-bias random walk"),
    "vehicle.depth.noise_m": _veh(1e-5, 10.0, "m", "depth white noise (> 0)", _MM),
    "vehicle.depth.water_density_kg_m3": _veh(900.0, 1100.0, "kg/m^3", "water density"),
    "vehicle.depth.atmospheric_pressure_pa": _veh(5e4, 2e5, "Pa", "surface (atmospheric) pressure",
                                                  " (kPa or bar given for Pa?)"),
    # -- SLAM config -----------------------------------------------------------------------------------
    "slam.motion.velocity_rw_mps_per_sqrt_s": _cfg(0.0, 10.0, "m/s/sqrt(s)", "body acceleration noise"),
    "slam.motion.unaided_velocity_rw_mps_per_sqrt_s": _cfg(0.0, 10.0, "m/s/sqrt(s)",
                                                           "body acceleration noise without DVL"),
    "slam.motion.unaided_after_s": _cfg(1e-3, 3600.0, "s", "DVL silence before the unaided noise applies"),
    "slam.motion.unknown_velocity_sigma_mps": _cfg(0.0, 20.0, "m/s", "spread of an unknown initial velocity"),
    "slam.motion.max_predict_dt_s": _cfg(1e-3, 10.0, "s", "longest prediction step (work: 1 step per this "
                                         "much dive time)"),
    "slam.motion.yaw_bias_sigma_rad": _cfg(0.0, _PI, "rad", "prior AHRS yaw-bias spread", _DEG),
    "slam.gating.gate_probability": _cfg(0.5, 1.0, "1", "association gate probability (bounds excluded)"),
    "slam.gating.sensor_gate_probability": _cfg(0.5, 1.0, "1", "DVL/depth gate probability (bounds excluded)"),
    "slam.gating.creation_gate_probability": _cfg(0.5, 1.0, "1", "landmark-creation gate probability (bounds "
                                                  "excluded)"),
    "slam.gating.candidate_radius_m": _cfg(1e-3, 1e4, "m", "association candidate radius"),
    "slam.gating.sensor_gate_max_rejections": _cfg(0, 1e6, "1", "sensor rejections in a row before accepting",
                                                   integer=True),
    "slam.initialisation.initial_position_sigma_m": _cfg(1e-6, 1e3, "m", "launch-point spread"),
    "slam.initialisation.initial_velocity_sigma_mps": _cfg(1e-6, 20.0, "m/s", "initial velocity spread"),
    "slam.initialisation.start_window_s": _cfg(1e-3, 3600.0, "s", "window after the first attitude for the start's "
                                               "depth and fix"),
    "slam.initialisation.max_fix_age_s": _cfg(1e-3, 1e6, "s", "oldest position fix taken as the start point"),
    "slam.initialisation.unknown_depth_sigma_m": _cfg(1e-3, 1e4, "m", "start depth spread without a pressure sample"),
    "slam.initialisation.unknown_position_sigma_m": _cfg(1e-3, 1e7, "m", "start north/east spread without a fix"),
    "slam.initialisation.consensus_position_m": _cfg(1e-4, 100.0, "m", "consensus position tolerance"),
    "slam.initialisation.consensus_attitude": _cfg(1e-4, 10.0, "1", "consensus attitude tolerance"),
    "slam.initialisation.consensus_min_observations": _cfg(1, 1e4, "1", "detections to create a landmark",
                                                           integer=True),
    "slam.initialisation.consensus_max_age_s": _cfg(1e-3, 1e6, "s", "oldest detection in a consensus"),
    "slam.initialisation.unobservable_var_rad2": _cfg(1e-6, 100.0, "rad^2", "variance of an unobservable rotation"),
    "slam.initialisation.survey_position_sigma_m": _cfg(1e-6, 1e3, "m", "surveyed landmark position spread"),
    "slam.initialisation.survey_rotation_sigma_rad": _cfg(1e-6, _PI, "rad", "surveyed landmark rotation spread",
                                                          _DEG),
    "slam.map.dense_max_landmarks": _cfg(0, 500, "1", "landmarks in the dense filter (memory: (6 n)^2 doubles)",
                                         integer=True),
    "slam.map.active_radius_m": _cfg(1e-3, 1e4, "m", "active-area radius"),
    "slam.output.history_rate_hz": _cfg(1e-3, 100.0, "Hz", "history (and smoother) epochs per second of dive"),
    "slam.output.smoother_max_mb": _cfg(0.0, 1e5, "MB", "smoother history budget, memory then a temporary file (> 0)"),
    # -- ROS bags: message values ----------------------------------------------------------------------
    "bag.fluid_pressure_pa": Limit(0.0, 1.2e8, "Pa", "absolute pressure (FluidPressure; 0-11 km of sea water)",
                                   "BagDecoder.depth", " (kPa or bar given for Pa?)"),
    "nav.depth_m": Limit(-100.0, 11_000.0, "m", "depth (from a pressure or a pose message; a depth log's value)",
                         "BagDecoder.depth (error); SlamSession.add_depth (skipped, counted)"),
    "bag.quaternion_norm": Limit(0.9, 1.1, "1", "norm of an orientation quaternion (normalised when inside)",
                                 "BagDecoder.attitude"),
    "nav.dvl_velocity_mps": Limit(-20.0, 20.0, "m/s", "valid DVL velocity, per axis",
                                  "SlamSession.add_dvl (skipped, counted)"),
    "bag.angular_rate_radps": Limit(-50.0, 50.0, "rad/s", "IMU angular rate (not read by semslam: the AHRS "
                                    "orientation is the input)", "(not read)"),
    # -- stamps ----------------------------------------------------------------------------------------
    "stamps.attitude_gap_s": Limit(0.0, 3600.0, "s", "gap between successive attitude stamps, and from the run's "
                                   "start to the first one (the filter predicts through it: work and memory grow "
                                   "with it)", "SlamSession.add_attitude"),
    "stamps.history_epochs": Limit(0.0, 1e6, "1", "history epochs of one run: (attitude stamp - start) x "
                                   "history_rate_hz (memory: ~1 kB each)", "SlamSession.add_attitude"),
    "stamps.predict_steps": Limit(0.0, 1e8, "1", "prediction steps of one run: (attitude stamp - start) / "
                                  "max_predict_dt_s (CPU: ~20 us each)", "SlamSession.add_attitude"),
}


@cache
def _error_class(base: type) -> type:
    """A class both ``base`` (the caller's family: DatasetError, ConfigError, ...) and PlausibilityError."""
    if issubclass(base, PlausibilityError):
        return base
    return type(f"Implausible{base.__name__}", (PlausibilityError, base), {"__module__": __name__})


def _fmt(x: float) -> str:
    return f"{x:g}"


def _message(where: str, lim: Limit, value: Any) -> str:
    over = isinstance(value, (int, float)) and math.isfinite(value) and abs(value) > lim.hi
    unit = "" if lim.unit == "1" else f" {lim.unit}"
    return (f"{where} must be in [{_fmt(lim.lo)}, {_fmt(lim.hi)}]{unit}{lim.hint if over else ''}. "
            f"Got {value!r} instead.")


def check(name: str, value: Any, where: str, *, error: type = PlausibilityError) -> float:
    """``value`` as a float (an int for an integer quantity) when it is a finite number inside ``LIMITS[name]``;
    else raise ``error`` (also a :class:`PlausibilityError`) with one line: ``where`` (as "The vehicle file 'x'
    key 'dvl.noise_m'"), the range, the unit and the value."""
    lim = LIMITS[name]
    cls = _error_class(error)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise cls(f"{where} must be a number. Got {value!r} instead.")
    v = float(value)
    if not lim.contains(v):
        raise cls(_message(where, lim, value))
    if lim.integer:
        if v != int(v):
            raise cls(f"{where} must be a whole number. Got {value!r} instead.")
        return int(v)
    return v


def check_each(name: str, values: Any, where: str, *, error: type = PlausibilityError) -> tuple:
    """:func:`check` on each element of a sequence (the first bad one is named with its index)."""
    out = []
    for i, v in enumerate(values):
        out.append(check(name, v, f"{where}[{i}]" if len(values) > 1 else where, error=error))
    return tuple(out)


def limits_markdown() -> str:
    """The table of :data:`LIMITS` as Markdown (``docs/limits.md``)."""
    lines = ["# Plausibility limits", "",
             "Generated by `semslam.limits.limits_markdown()` from `semslam/limits.py` (the one place these ranges",
             "are defined). A value outside its range is refused with a one-line error naming the file and key (or",
             "topic, or argument), the range and the value. Closed ranges, SI units, radians.", "",
             "| quantity | range | unit | what | checked in |", "|---|---|---|---|---|"]
    for key, lim in LIMITS.items():
        lines.append(f"| `{key}` | [{_fmt(lim.lo)}, {_fmt(lim.hi)}] | {lim.unit} | {lim.what} | {lim.applies_to} |")
    lines += ["", "Decisions:", "",
              "- A vehicle file must give the scanner extrinsic (`[scanner]` `xyz_m`/`rpy_rad` or `matrix`): a",
              "  missing one was silently the identity. A scanner at the vehicle origin is written",
              "  `xyz_m = [0, 0, 0]`. With no vehicle file at all, the documented Girona 500 defaults apply",
              "  (`VehicleDescription.girona500()`, `--vehicle girona500`).",
              "- An empty vehicle file (no section) is an error naming the missing scanner extrinsic.",
              "- The scanner's `min_range_m` must be below its `max_range_m`.",
              "- Bags: a pressure, depth or orientation quaternion outside its range is an error naming the topic.",
              "- Stamps: the SLAM session's work (prediction steps, history epochs) grows with the time the attitude",
              "  covers; an attitude stamp more than `stamps.attitude_gap_s` after the previous one (or after the",
              "  run's start) is an error naming both stamps, so that one corrupt stamp (2^31 s) cannot make the",
              "  run predict for 68 years. Other sensors' messages beyond the last attitude are skipped and counted",
              "  (`skipped_beyond_attitude`). The whole run's work is bounded too: its history epochs",
              "  (`stamps.history_epochs`, span x `history_rate_hz`) and prediction steps (`stamps.predict_steps`,",
              "  span / `max_predict_dt_s`); beyond them the error says which setting to change (or to split the",
              "  dive).",
              "- A valid DVL velocity or a depth sample outside `nav.*` is skipped and counted in the run's metrics",
              "  (`skipped_implausible`): after five rejections in a row the sensor gate would have accepted them.", ""]
    return "\n".join(lines)
