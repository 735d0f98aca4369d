"""Settings of the semantic EKF-SLAM: how the filter models motion, gates, initialises and records.

The sensor figures (DVL, AHRS, depth noise; DVL beam geometry) are not here: they come from the vehicle
description (:class:`semslam.dataset.VehicleDescription`), as a real vehicle's data sheets give them.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from .._validation import check_choice
from ..errors import ConfigError

#: the filter's modes (see :mod:`semslam.slam.session`)
MODES = ("dr", "position", "pose", "pose+heading")


@dataclass(frozen=True)
class SlamConfig:
    """Filter settings (SI units, radians)."""

    #: white body-frame acceleration noise (m/s/sqrt(s)): one number, or (surge, sway, heave). The default follows
    #: a teleoperated vehicle (simulator truth in cruise: surge acceleration rms 0.018 m/s^2 from a 0.02 m/s speed
    #: wander, sway 0.008 from a 2 deg crab, heave 0.009 from the altitude wave; the launch and stop ramps' 0.1 m/s^2
    #: are caught by the DVL's manoeuvre reset). (0.05, 0.01, 0.02) made the filter pessimistic; a near-zero surge
    #: noise would be right only for a vehicle that never changes speed (and diverges at the launch ramp)
    velocity_rw_mps_per_sqrt_s: float | tuple = (0.02, 0.01, 0.01)
    #: estimate the DVL's calibration (bias, degraded-bottom bias, scale factor, misalignment) when the vehicle
    #: description gives non-zero figures for it
    dvl_calibration: bool = True
    #: tell a flat bottom from a slope by the DVL's per-beam ranges (when the log has them); else both noise
    #: hypotheses (nominal, degraded) are tried on every sample
    dvl_use_beam_ranges: bool = True
    propagate_attitude_noise: bool = True
    yaw_bias_sigma_rad: float = math.radians(3.0)
    #: pose+heading without surveyed landmarks: keep the unobservable common rotation (map, trajectory and bias)
    #: unobservable (observability-constrained EKF, see SemanticEkf.constrain_heading_nullspace)
    observability_constrained: bool = True
    #: the launch point defines the world frame (as in the papers, whose ground truth starts at the vehicle's start):
    #: the filter knows it to this standard deviation per axis (a surveyed mark; 0.01 for a 1 cm fix), and a
    #: simulated start is drawn from it (``perturb_initial_position``) so that the initial NEES is chi-square
    initial_position_sigma_m: float = 0.001
    initial_velocity_sigma_mps: float = 0.05
    perturb_initial_position: bool = True
    surveyed_objects: tuple = ()
    survey_position_sigma_m: float = 0.01
    survey_rotation_sigma_rad: float = math.radians(0.5)
    max_predict_dt_s: float = 0.1
    gate_probability: float = 0.99
    sensor_gate_probability: float = 0.9999
    sensor_gate_max_rejections: int = 5
    association: str = "nn"
    orientation_innovation: str = "rotvec"
    consensus_position_m: float = 0.3
    consensus_attitude: float = 0.02
    consensus_min_observations: int = 4
    consensus_max_age_s: float = 60.0
    candidate_radius_m: float = 10.0
    dense_max_landmarks: int = 50
    active_radius_m: float = 10.0
    unobservable_var_rad2: float = 0.25
    history_rate_hz: float = 2.0
    #: also estimate the trajectory from the whole mission (RTS smoother, offline; the filter is unchanged)
    smooth: bool = True
    #: memory budget of the smoother (MB): beyond it the smoothed trajectory is skipped, and metrics say so
    smoother_max_mb: float = 512.0

    def __post_init__(self) -> None:
        vrw = self.velocity_rw_mps_per_sqrt_s
        if isinstance(vrw, bool) or not isinstance(vrw, (int, float)):
            try:
                vrw = tuple(float(x) for x in vrw)
            except (TypeError, ValueError):
                vrw = ()
            if len(vrw) != 3 or not all(math.isfinite(x) and x >= 0 for x in vrw):
                raise ConfigError("The 'velocity_rw_mps_per_sqrt_s' field of SlamConfig must be a number or three "
                                  f"finite numbers >= 0 (surge, sway, heave). Got {self.velocity_rw_mps_per_sqrt_s!r} instead.")
            object.__setattr__(self, "velocity_rw_mps_per_sqrt_s", vrw)
        check_choice("association", self.association, ("nn", "jcbb"), caller="SlamConfig")
        check_choice("orientation_innovation", self.orientation_innovation, ("rotvec", "rpy"), caller="SlamConfig")
        for f in fields(self):
            v = getattr(self, f.name)
            if f.type in ("float", "int") and (isinstance(v, bool) or not isinstance(v, (int, float))):
                raise ConfigError(f"The {f.name!r} field of SlamConfig must be a number. Got {v!r} instead.")
            if f.type == "bool" and not isinstance(v, bool):
                raise ConfigError(f"The {f.name!r} field of SlamConfig must be true or false. Got {v!r} instead.")
            if isinstance(v, float) and not math.isfinite(v):
                raise ConfigError(f"The {f.name!r} field of SlamConfig must be finite. Got {v!r} instead.")
        for name in ("max_predict_dt_s", "history_rate_hz", "consensus_position_m", "smoother_max_mb",
                     "initial_velocity_sigma_mps", "consensus_max_age_s"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"The {name!r} field of SlamConfig must be > 0. Got {getattr(self, name)!r} instead.")
        if self.consensus_min_observations < 1 or self.sensor_gate_max_rejections < 0:
            raise ConfigError("SlamConfig needs consensus_min_observations >= 1 and sensor_gate_max_rejections >= 0.")
        if not 0.5 < self.gate_probability < 1.0 or not 0.5 < self.sensor_gate_probability < 1.0:
            raise ConfigError("The gate probabilities of SlamConfig must be in (0.5, 1). Got "
                              f"{self.gate_probability!r} and {self.sensor_gate_probability!r} instead.")
        if isinstance(self.surveyed_objects, str) or not all(isinstance(n, str) for n in self.surveyed_objects):
            raise ConfigError(f"The 'surveyed_objects' field of SlamConfig must be a sequence of object names. "
                              f"Got {self.surveyed_objects!r} instead.")
        object.__setattr__(self, "surveyed_objects", tuple(self.surveyed_objects))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["surveyed_objects"] = list(self.surveyed_objects)
        if isinstance(self.velocity_rw_mps_per_sqrt_s, tuple):
            d["velocity_rw_mps_per_sqrt_s"] = list(self.velocity_rw_mps_per_sqrt_s)
        return d

    @classmethod
    def from_dict(cls, d: dict, *, source: str = "a SlamConfig record") -> "SlamConfig":
        if not isinstance(d, dict):
            raise ConfigError(f"{source} must be a table of SlamConfig fields. Got {type(d).__name__} instead.")
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ConfigError(f"Unknown field(s) {sorted(unknown)} in {source}. Expected some of {sorted(names)}.")
        return cls(**d)
