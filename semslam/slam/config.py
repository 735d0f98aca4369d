"""Settings of the semantic EKF-SLAM, in sections: how the filter models motion (``motion``), gates and associates
(``gating``), starts and creates landmarks (``initialisation``), keeps a large map (``map``) and records the run
(``output``).

The sensor figures (DVL, AHRS, depth noise; DVL beam geometry) are not here: they come from the vehicle
description (:class:`semslam.dataset.VehicleDescription`), as a real vehicle's data sheets give them.

As a file (``semslam slam --config slam.toml``; a run's ``config.json`` has the same form)::

    [slam.motion]
    velocity_rw_mps_per_sqrt_s = [0.02, 0.01, 0.01]
    [slam.initialisation]
    initial_position_sigma_m = 0.01
    [slam.output]
    smooth = false
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

from .._validation import check_choice
from ..errors import ConfigError, SemslamError
from ..limits import LIMITS, check as check_limit
from ..modes import MODES  # noqa: F401 (semslam.slam.config.MODES, read by the filter's users)



def _check_types(obj) -> None:
    """Strict types (no truthy strings, no bools for numbers) and finite numbers for a section dataclass."""
    name = type(obj).__name__
    for f in fields(obj):
        v = getattr(obj, f.name)
        if f.type in ("float", "int") and (isinstance(v, bool) or not isinstance(v, (int, float))):
            raise ConfigError(f"The {f.name!r} field of {name} must be a number. Got {v!r} instead.")
        if f.type == "int" and not isinstance(v, int):
            raise ConfigError(f"The {f.name!r} field of {name} must be an integer. Got {v!r} instead.")
        if f.type == "bool" and not isinstance(v, bool):
            raise ConfigError(f"The {f.name!r} field of {name} must be true or false. Got {v!r} instead.")
        if isinstance(v, float) and not math.isfinite(v):
            raise ConfigError(f"The {f.name!r} field of {name} must be finite. Got {v!r} instead.")


def _check_ranges(obj, section: str) -> None:
    """Every number of a section inside its plausibility range (``semslam.limits.LIMITS["slam.<section>.<key>"]``,
    ``docs/limits.md``): a rate or step that would make the work unbounded, a noise figure that breaks the filter."""
    for f in fields(obj):
        name = f"slam.{section}.{f.name}"
        if name in LIMITS:
            v = getattr(obj, f.name)
            for i, x in enumerate(v if isinstance(v, tuple) else (v,)):
                idx = f" (element {i})" if isinstance(v, tuple) else ""
                check_limit(name, x, f"The {f.name!r} field of {type(obj).__name__}{idx}", error=ConfigError)


def _positive(obj, *names) -> None:
    for n in names:
        if getattr(obj, n) <= 0:
            raise ConfigError(f"The {n!r} field of {type(obj).__name__} must be > 0. Got {getattr(obj, n)!r} instead.")


@dataclass(frozen=True)
class MotionConfig:
    """The motion model and the states it estimates."""

    #: white body-frame acceleration noise (m/s/sqrt(s)): one number, or (surge, sway, heave). The default follows
    #: a teleoperated vehicle (simulator truth in cruise: surge acceleration rms 0.018 m/s^2 from a 0.02 m/s speed
    #: wander, sway 0.008 from a 2 deg crab, heave 0.009 from the altitude wave; the launch and stop ramps' 0.1 m/s^2
    #: are caught by the DVL's manoeuvre reset). (0.05, 0.01, 0.02) made the filter pessimistic; a near-zero surge
    #: noise would be right only for a vehicle that never changes speed (and diverges at the launch ramp)
    velocity_rw_mps_per_sqrt_s: float | tuple = (0.02, 0.01, 0.01)
    #: the same while the DVL is out (no accepted DVL sample for ``unaided_after_s``): nothing then catches a
    #: manoeuvre, so the noise must cover the vehicle's real velocity changes. Measured, not assumed: the default
    #: is :func:`semslam.evaluation.motion_noise.measure_unaided_motion` on the simulator's missions' DVL logs
    #: (``benchmarks/dvl_outage.py --measure``); measure your vehicle's from one of its DVL logs
    unaided_velocity_rw_mps_per_sqrt_s: float | tuple = (0.054, 0.021, 0.026)
    unaided_after_s: float = 1.0
    #: the body velocity's spread when it is not known (no DVL at the start of the run): per-axis rms of the
    #: vehicle's body velocity, measured like the unaided noise
    unknown_velocity_sigma_mps: float | tuple = (0.29, 0.02, 0.029)
    max_predict_dt_s: float = 0.1
    propagate_attitude_noise: bool = True
    #: estimate the DVL's calibration (bias, degraded-bottom bias, scale factor, misalignment) when the vehicle
    #: description gives non-zero figures for it
    dvl_calibration: bool = True
    #: tell a flat bottom from a slope by the DVL's per-beam ranges (when the log has them); else both noise
    #: hypotheses (nominal, degraded) are tried on every sample
    dvl_use_beam_ranges: bool = True
    #: prior standard deviation of the AHRS yaw bias (pose+heading mode)
    yaw_bias_sigma_rad: float = math.radians(3.0)
    #: pose+heading without surveyed landmarks: keep the unobservable common rotation (map, trajectory and bias)
    #: unobservable (observability-constrained EKF, see SemanticEkf.constrain_heading_nullspace)
    observability_constrained: bool = True

    def __post_init__(self) -> None:
        for name in ("velocity_rw_mps_per_sqrt_s", "unaided_velocity_rw_mps_per_sqrt_s", "unknown_velocity_sigma_mps"):
            vrw = getattr(self, name)
            if isinstance(vrw, bool) or not isinstance(vrw, (int, float)):
                try:
                    vrw = tuple(float(x) for x in vrw)
                except (TypeError, ValueError):
                    vrw = ()
                if len(vrw) != 3 or not all(math.isfinite(x) and x >= 0 for x in vrw):
                    raise ConfigError(f"The {name!r} field of MotionConfig must be a number or three finite numbers "
                                      f">= 0 (surge, sway, heave). Got {getattr(self, name)!r} instead.")
                object.__setattr__(self, name, vrw)
            elif not (math.isfinite(vrw) and vrw >= 0):
                raise ConfigError(f"The {name!r} field of MotionConfig must be >= 0. Got {vrw!r} instead.")
        _check_types(self)
        _positive(self, "max_predict_dt_s", "unaided_after_s")
        _check_ranges(self, "motion")


@dataclass(frozen=True)
class GatingConfig:
    """Chi-square gates of the object and sensor updates, and data association."""

    gate_probability: float = 0.99
    sensor_gate_probability: float = 0.9999
    #: after this many rejected DVL/depth samples in a row the prediction, not the sensor, is wrong: accept
    sensor_gate_max_rejections: int = 5
    association: str = "nn"
    orientation_innovation: str = "rotvec"
    #: landmarks farther than this from the vehicle are not association candidates (m)
    candidate_radius_m: float = 10.0
    #: a detection that fails the association gate (``gate_probability``) but passes this much wider one against a
    #: landmark of its class is dropped, not pooled towards a new landmark: a near miss is that landmark seen under
    #: a model error (a large heading error, say), not another object. Never narrower than ``gate_probability``
    creation_gate_probability: float = 0.99999

    def __post_init__(self) -> None:
        check_choice("association", self.association, ("nn", "jcbb"), caller="GatingConfig")
        check_choice("orientation_innovation", self.orientation_innovation, ("rotvec", "rpy"), caller="GatingConfig")
        _check_types(self)
        if not 0.5 < self.gate_probability < 1.0 or not 0.5 < self.sensor_gate_probability < 1.0:
            raise ConfigError("The gate probabilities of GatingConfig must be in (0.5, 1). Got "
                              f"{self.gate_probability!r} and {self.sensor_gate_probability!r} instead.")
        if not 0.5 < self.creation_gate_probability < 1.0:
            raise ConfigError(f"The 'creation_gate_probability' field of GatingConfig must be in (0.5, 1). Got "
                              f"{self.creation_gate_probability!r} instead.")
        if self.sensor_gate_max_rejections < 0:
            raise ConfigError(f"The 'sensor_gate_max_rejections' field of GatingConfig must be >= 0. Got "
                              f"{self.sensor_gate_max_rejections!r} instead.")
        _positive(self, "candidate_radius_m")
        _check_ranges(self, "gating")


@dataclass(frozen=True)
class InitialisationConfig:
    """The start of the run and the creation of landmarks (consensus of detections, surveyed objects)."""

    #: a dive without position fixes starts a local frame at its start point (north = east = 0), known to this
    #: standard deviation per axis (see :mod:`semslam.slam.initial`)
    initial_position_sigma_m: float = 0.001
    initial_velocity_sigma_mps: float = 0.05
    #: the start's depth and first fix are taken within this time of the first attitude sample (s)
    start_window_s: float = 2.0
    #: a position fix older than this at the start is not the start point (s)
    max_fix_age_s: float = 120.0
    #: the start's depth without a pressure sample near it (m), and its north/east when the dive has fixes but
    #: none near the start (the fixes place it as they come)
    unknown_depth_sigma_m: float = 100.0
    unknown_position_sigma_m: float = 1000.0
    consensus_position_m: float = 0.3
    consensus_attitude: float = 0.02
    consensus_min_observations: int = 4
    consensus_max_age_s: float = 60.0
    #: variance (rad^2) given to a detection's rotation about an axis its object's symmetry leaves unobservable
    unobservable_var_rad2: float = 0.25
    #: surveyed landmarks (a survey file, an earlier map) without a covariance of their own are known to these
    survey_position_sigma_m: float = 0.01
    survey_rotation_sigma_rad: float = math.radians(0.5)

    def __post_init__(self) -> None:
        _check_types(self)
        _positive(self, "initial_position_sigma_m", "initial_velocity_sigma_mps", "start_window_s", "max_fix_age_s",
                  "unknown_depth_sigma_m", "unknown_position_sigma_m", "consensus_position_m",
                  "consensus_attitude", "consensus_max_age_s", "unobservable_var_rad2", "survey_position_sigma_m",
                  "survey_rotation_sigma_rad")
        if self.consensus_min_observations < 1:
            raise ConfigError(f"The 'consensus_min_observations' field of InitialisationConfig must be >= 1. Got "
                              f"{self.consensus_min_observations!r} instead.")
        _check_ranges(self, "initialisation")


@dataclass(frozen=True)
class MapConfig:
    """A large map: the dense filter up to ``dense_max_landmarks``, then an active area around the vehicle."""

    dense_max_landmarks: int = 50
    active_radius_m: float = 10.0

    def __post_init__(self) -> None:
        _check_types(self)
        _positive(self, "active_radius_m")
        if self.dense_max_landmarks < 0:
            raise ConfigError(f"The 'dense_max_landmarks' field of MapConfig must be >= 0. Got "
                              f"{self.dense_max_landmarks!r} instead.")
        _check_ranges(self, "map")


@dataclass(frozen=True)
class OutputConfig:
    """What the run records: the history rate and the RTS-smoothed trajectory."""

    history_rate_hz: float = 2.0
    #: also estimate the trajectory from the whole mission (RTS smoother, offline; the filter is unchanged)
    smooth: bool = True
    #: budget of the smoother's history (MB; the first 16 MB in memory, the rest in a temporary file: a 30-minute
    #: dive with four landmarks needs ~0.8 GB): beyond it the smoothed trajectory is skipped, and metrics say so
    smoother_max_mb: float = 4096.0

    def __post_init__(self) -> None:
        _check_types(self)
        _positive(self, "history_rate_hz", "smoother_max_mb")
        _check_ranges(self, "output")


_SECTIONS = {"motion": MotionConfig, "gating": GatingConfig, "initialisation": InitialisationConfig,
             "map": MapConfig, "output": OutputConfig}


@dataclass(frozen=True)
class SlamConfig:
    """Filter settings (SI units, radians), in sections (see the module docstring)."""

    motion: MotionConfig = field(default_factory=MotionConfig)
    gating: GatingConfig = field(default_factory=GatingConfig)
    initialisation: InitialisationConfig = field(default_factory=InitialisationConfig)
    map: MapConfig = field(default_factory=MapConfig)
    output: OutputConfig = field(default_factory=OutputConfig)

    def __post_init__(self) -> None:
        for name, cls in _SECTIONS.items():
            if not isinstance(getattr(self, name), cls):
                raise ConfigError(f"The {name!r} section of SlamConfig must be a {cls.__name__}. Got "
                                  f"{type(getattr(self, name)).__name__} instead.")

    def updated(self, **settings: Any) -> "SlamConfig":
        """A copy with the named settings changed, whatever their section (names are unique):
        ``SlamConfig().updated(smooth=False, initial_position_sigma_m=0.01)``."""
        sections: dict[str, dict] = {}
        for key, value in settings.items():
            sec = next((s for s, cls in _SECTIONS.items() if key in {f.name for f in fields(cls)}), None)
            if sec is None:
                raise ConfigError(f"Unknown SlamConfig setting {key!r}. Expected one of "
                                  f"{sorted(f.name for cls in _SECTIONS.values() for f in fields(cls))}.")
            sections.setdefault(sec, {})[key] = value
        return replace(self, **{s: replace(getattr(self, s), **kw) for s, kw in sections.items()})

    def to_dict(self) -> dict:
        out = {}
        for name in _SECTIONS:
            d = asdict(getattr(self, name))
            out[name] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}
        return out

    @classmethod
    def from_dict(cls, d: Any, *, source: str = "a SlamConfig record") -> "SlamConfig":
        """From :meth:`to_dict`'s form: a table per section, every key optional; unknown sections or keys and
        wrong types raise :class:`~semslam.errors.ConfigError` naming ``source``."""
        if not isinstance(d, dict):
            raise ConfigError(f"{source} must be a table of SlamConfig sections. Got {type(d).__name__} instead.")
        unknown = sorted(set(d) - set(_SECTIONS))
        if unknown:
            raise ConfigError(f"Unknown section(s) {unknown} in {source}. Expected some of {sorted(_SECTIONS)}.")
        kw = {}
        for name, table in d.items():
            scls = _SECTIONS[name]
            if not isinstance(table, dict):
                raise ConfigError(f"The [{name}] section of {source} must be a table. Got {table!r} instead.")
            names = {f.name for f in fields(scls)}
            bad = sorted(set(table) - names)
            if bad:
                raise ConfigError(f"Unknown key(s) {[f'{name}.{k}' for k in bad]} in {source}. Expected some of "
                                  f"{sorted(f'{name}.{k}' for k in names)}.")
            try:
                kw[name] = scls(**table)
            except SemslamError as exc:  # ConfigError, and InputError from a choice check
                # the class kept: a plausibility error stays one (semslam.limits)
                raise (type(exc) if isinstance(exc, ConfigError) else ConfigError)(f"{source}: {exc}") from None
        return cls(**kw)
