"""Run the semantic EKF over a mission in one mode and evaluate it against the ground truth.

Modes: ``dr`` (DVL + depth + AHRS dead reckoning), ``position`` (object positions only), ``pose`` (the
papers' cascade: full-pose test, else position test), ``pose+heading`` (``pose`` with an AHRS yaw-bias
state; observability-constrained when no landmark is surveyed, since a constant bias is then unobservable).
Events (DVL, depth, each detection at its own stamp, history epochs) are processed in time order; the
prediction runs in steps of at most ``max_predict_dt_s`` with the AHRS attitude interpolated at each step's
midpoint (the interpolation halves at most the variance of the AHRS white noise; the filter accounts for it).
The filter starts at the launch point, which defines the world frame, known to ``initial_position_sigma_m``.
With ``smooth`` (default) the run also yields the RTS-smoothed trajectory (:mod:`semslam.slam.smoother`: the
estimate at each epoch given the whole mission, for maps and evaluation; the online estimate is unchanged).
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from .._atomic import atomic_write_text
from .._validation import as_rng, check_choice
from ..detection import Detection
from ..errors import ConfigError, SlamError
from ..geometry import rotation_from_rpy, rpy_from_rotation
from ..simulation.mission import Mission
from ..symmetry import Symmetry
from . import _ekf_kernels as kern
from .association import (
    GateThresholds,
    associate,
    associate_jcbb,
    innovation,
    measurement_from_detection,
)
from .consensus import ConsensusInitializer, Observation
from .detections import TruthDetectionConfig, simulate_detections
from .ekf import SemanticEkf
from .metrics import nis_summary, trajectory_metrics
from .smoother import RtsRecorder

MODES = ("dr", "position", "pose", "pose+heading")
_EZ = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class SlamConfig:
    """Filter settings (SI units, radians). :meth:`for_mission` takes the sensor noise from the mission."""

    #: white body-frame acceleration noise (m/s/sqrt(s)): one number, or (surge, sway, heave). The default follows
    #: the teleoperated vehicle (simulator truth in cruise: surge acceleration rms 0.018 m/s^2 from a 0.02 m/s speed
    #: wander, sway 0.008 from a 2 deg crab, heave 0.009 from the altitude wave; the launch and stop ramps' 0.1 m/s^2
    #: are caught by the DVL's manoeuvre reset). (0.05, 0.01, 0.02) made the filter pessimistic; a near-zero surge
    #: noise would be right only for a vehicle that never changes speed (and diverges at the launch ramp)
    velocity_rw_mps_per_sqrt_s: float | tuple = (0.02, 0.01, 0.01)
    dvl_noise_abs_mps: float = 0.001
    dvl_noise_rel: float = 0.003
    dvl_max_speed_mps: float = 1.5
    dvl_slope_noise_factor: float = 5.0
    dvl_calibration: bool = True
    dvl_scale_sigma: float = 0.005
    dvl_misalignment_sigma_rad: float = math.radians(0.5)
    dvl_bias_sigma_mps: float = 0.003
    dvl_bias_tau_s: float = 20.0
    dvl_slope_bias_sigma_mps: float = 0.015
    dvl_slope_bias_tau_s: float = 5.0
    dvl_slope_map: bool = True
    depth_sigma_m: float = 0.02
    ahrs_sigma_rpy_rad: tuple = (math.radians(0.2), math.radians(0.2), math.radians(1.0))
    propagate_attitude_noise: bool = True
    yaw_bias_sigma_rad: float = math.radians(3.0)
    yaw_bias_rw_rad_per_sqrt_s: float = 0.0
    #: pose+heading without surveyed landmarks: keep the unobservable common rotation (map, trajectory and bias)
    #: unobservable (observability-constrained EKF, see SemanticEkf.constrain_heading_nullspace)
    observability_constrained: bool = True
    #: the launch point defines the world frame (as in the papers, whose ground truth starts at the vehicle's start):
    #: the filter knows it to this standard deviation per axis (a surveyed mark; 0.01 for a 1 cm fix), and the
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
    detections: TruthDetectionConfig = field(default_factory=TruthDetectionConfig)

    def __post_init__(self) -> None:
        vrw = self.velocity_rw_mps_per_sqrt_s
        if not isinstance(vrw, (int, float)):
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
            if isinstance(v, float) and not math.isfinite(v):
                raise ConfigError(f"The {f.name!r} field of SlamConfig must be finite. Got {v!r} instead.")
        for name in ("max_predict_dt_s", "history_rate_hz", "depth_sigma_m", "consensus_position_m", "smoother_max_mb"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"The {name!r} field of SlamConfig must be > 0. Got {getattr(self, name)!r} instead.")
        if not 0.5 < self.gate_probability < 1.0 or not 0.5 < self.sensor_gate_probability < 1.0:
            raise ConfigError("The gate probabilities of SlamConfig must be in (0.5, 1).")
        if self.dvl_bias_tau_s <= 0 or self.dvl_slope_noise_factor < 1:
            raise ConfigError("SlamConfig needs dvl_bias_tau_s > 0 and dvl_slope_noise_factor >= 1. "
                              f"Got {self.dvl_bias_tau_s!r} and {self.dvl_slope_noise_factor!r} instead.")
        if isinstance(self.surveyed_objects, str) or not all(isinstance(n, str) for n in self.surveyed_objects):
            raise ConfigError(f"The 'surveyed_objects' field of SlamConfig must be a sequence of object names. "
                              f"Got {self.surveyed_objects!r} instead.")
        object.__setattr__(self, "surveyed_objects", tuple(self.surveyed_objects))
        if len(self.ahrs_sigma_rpy_rad) != 3:
            raise ConfigError(f"The 'ahrs_sigma_rpy_rad' field of SlamConfig must be 3 numbers. Got {self.ahrs_sigma_rpy_rad!r} instead.")
        object.__setattr__(self, "ahrs_sigma_rpy_rad", tuple(float(x) for x in self.ahrs_sigma_rpy_rad))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["detections"] = self.detections.to_dict()
        d["ahrs_sigma_rpy_rad"] = list(self.ahrs_sigma_rpy_rad)
        d["surveyed_objects"] = list(self.surveyed_objects)
        if isinstance(self.velocity_rw_mps_per_sqrt_s, tuple):
            d["velocity_rw_mps_per_sqrt_s"] = list(self.velocity_rw_mps_per_sqrt_s)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "SlamConfig":
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ConfigError(f"Unknown field(s) {sorted(unknown)} in a SlamConfig record. Expected some of {sorted(names)}.")
        d = dict(d)
        if "detections" in d and isinstance(d["detections"], dict):
            d["detections"] = TruthDetectionConfig(**d["detections"])
        return cls(**d)

    @classmethod
    def for_mission(cls, mission: Mission, **overrides) -> "SlamConfig":
        """Defaults with the sensor noise levels and the scanner field of view read from ``mission.config``
        (``mission.json``'s ``simulator`` section, i.e. ``SimulatorConfig.to_dict()``, or the same sections at
        the top level) when present. Only what a navigator knows from the sensor specifications is read: noise
        levels and the standard deviations of the calibration errors, never the per-mission draws."""
        c = mission.config or {}
        c = c.get("simulator", c) or {}
        kw: dict = {}
        dvl, ahrs, depth, sc = (c.get(k, {}) or {} for k in ("dvl", "ahrs", "depth", "scanner"))
        for src, dst in (("noise_abs_mps", "dvl_noise_abs_mps"), ("noise_rel", "dvl_noise_rel"),
                         ("slope_noise_factor", "dvl_slope_noise_factor"), ("scale_factor_sigma", "dvl_scale_sigma"),
                         ("misalignment_sigma_rad", "dvl_misalignment_sigma_rad"),
                         ("bias_sigma_mps", "dvl_bias_sigma_mps"), ("bias_tau_s", "dvl_bias_tau_s"),
                         ("slope_bias_sigma_mps", "dvl_slope_bias_sigma_mps"),
                         ("slope_bias_tau_s", "dvl_slope_bias_tau_s")):
            if src in dvl:
                kw[dst] = max(float(dvl[src]), 1.0) if dst == "dvl_slope_noise_factor" else float(dvl[src])
        if dvl and not any(float(dvl.get(k, 0.0)) > 0 for k in ("scale_factor_sigma", "misalignment_sigma_rad",
                                                                 "bias_sigma_mps", "slope_bias_sigma_mps")):
            kw["dvl_calibration"] = False
        if "yaw_bias_walk_rad_per_sqrt_s" in ahrs:
            kw["yaw_bias_rw_rad_per_sqrt_s"] = float(ahrs["yaw_bias_walk_rad_per_sqrt_s"])
        if "noise_rpy_rad" in ahrs:
            kw["ahrs_sigma_rpy_rad"] = tuple(float(x) for x in ahrs["noise_rpy_rad"])
        if "noise_m" in depth:
            kw["depth_sigma_m"] = max(float(depth["noise_m"]), 1e-4)
        det = {}
        if "max_range_m" in sc:
            det["max_range_m"] = float(sc["max_range_m"])
        if "min_range_m" in sc:
            det["min_range_m"] = float(sc["min_range_m"])
        if "sweep_fov_rad" in sc:
            det["fov_rad"] = float(min(sc["sweep_fov_rad"], sc.get("line_fov_rad", sc["sweep_fov_rad"])))
        if "scan_rate_hz" in sc:
            det["scan_rate_hz"] = float(sc["scan_rate_hz"])
        det.update(overrides.pop("detections", {}) if isinstance(overrides.get("detections"), dict) else {})
        cfg = cls(**kw, detections=TruthDetectionConfig(**det))
        return replace(cfg, **overrides) if overrides else cfg


@dataclass(frozen=True, eq=False)
class LandmarkEstimate:
    """A mapped landmark at the end of the run (pose in the world frame, covariance x y z roll pitch yaw)."""

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

    @property
    def position_error_m(self) -> np.ndarray | None:
        if self.truth_position_ned_m is None:
            return None
        return np.linalg.norm(self.position_ned_m - self.truth_position_ned_m, axis=1)


def builtin_symmetries() -> dict[str, Symmetry]:
    """Symmetry per class of the simulator's built-in objects (empty if the simulator is unavailable)."""
    try:
        from ..simulation import builtin_objects

        return {k: v.symmetry for k, v in builtin_objects().items()}
    except Exception:  # pragma: no cover - simulator absent or failing: no symmetry knowledge
        return {}


def run_slam(mission: Mission, detections_by_scan: dict[int, list[Detection]] | None = None, *, mode: str = "pose",
             config: SlamConfig | None = None, seed=0, symmetries: dict[str, Symmetry] | None = None) -> SlamResult:
    """Run the filter over ``mission`` in ``mode`` (see module docstring).

    Parameters
    ----------
    mission : Mission
        Navigation logs (and ground truth for the metrics and the truth-based detections).
    detections_by_scan : dict, optional
        ``{scan_id: [Detection]}`` in the scanner frame, each with ``stamp_s``. None: the truth-based
        source (:func:`~semslam.slam.detections.simulate_detections`, seeded by ``seed``).
    mode : {"dr", "position", "pose", "pose+heading"}
    config : SlamConfig, optional
        Default :meth:`SlamConfig.for_mission`.
    seed : int or numpy Generator
        Seeds the truth-based detections.
    symmetries : dict, optional
        Symmetry per class label (default: the simulator's built-in objects).
    """
    check_choice("mode", mode, MODES, caller="run_slam")
    if not isinstance(mission, Mission):
        raise SlamError(f"The 'mission' argument of run_slam must be a Mission. Got {type(mission).__name__} instead.")
    cfg = config or SlamConfig.for_mission(mission)
    rng = as_rng(seed, caller="run_slam")
    symmetries = builtin_symmetries() if symmetries is None else symmetries
    # initial-state and survey errors: their own stream (spawning draws nothing), the same in every mode
    init_rng = rng.spawn(1)[0] if isinstance(seed, np.random.Generator) else \
        np.random.default_rng(np.random.SeedSequence([int(seed), 0x5EED]))
    if detections_by_scan is None and mode != "dr":
        detections_by_scan = simulate_detections(mission, cfg.detections, seed=rng, symmetries=symmetries)
    return _Runner(mission, cfg, mode, symmetries, init_rng).run(detections_by_scan or {})


def _drift_since(P_now: np.ndarray, P_then: list[np.ndarray]) -> np.ndarray:
    """Covariance of ``mean_i (e_now - e_i)``, the vehicle's position-error growth since each of ``n``
    observations (``P_then`` their position covariances, oldest first), as for a random walk: the growth
    since observation ``i`` is the positive part ``D_i`` of ``P_now - P_i``, growths are nested, so
    ``cov(e_now - e_i, e_now - e_j) = D_max(i, j)`` and the mean's covariance is ``sum_ij D_max(i,j) / n^2``."""
    n = len(P_then)
    if n == 0:
        return np.zeros((3, 3))
    out = np.zeros((3, 3))
    for i, Pi in enumerate(P_then):
        w, V = np.linalg.eigh(0.5 * ((P_now - Pi) + (P_now - Pi).T))
        D = (V * np.maximum(w, 0.0)) @ V.T
        out += (2 * i + 1) * D  # D_i is the later member for pairs (i, j <= i): 2 i + 1 of them
    return out / (n * n)


def _slope_test(world: dict, beam_angle_rad: float):
    """``f(position, R_world_vehicle) -> bool``: does a Janus beam (azimuths 45 + k 90 deg, ``beam_angle_rad`` off the body z)
    reach the tank floor outside its flat rectangle? The same geometry as the simulator's
    ``dvl_beams_over_slope`` (flat-floor approximation), for one pose, without array overhead."""
    from ..simulation.config import WorldConfig

    w = WorldConfig.from_dict(world)
    hx, hy = w.tank_length_m / 2 - w.slope_run_m, w.tank_width_m / 2 - w.slope_run_m
    sb, cb = math.sin(beam_angle_rad), math.cos(beam_angle_rad)
    beams = [(sb * math.cos(math.radians(a)), sb * math.sin(math.radians(a)), cb) for a in (45.0, 135.0, 225.0, 315.0)]

    def over(p: np.ndarray, R_world_vehicle: np.ndarray) -> bool:  # 4 beams, plain floats: ~10 us
        px, py, pz = float(p[0]), float(p[1]), float(p[2])
        if abs(px) > hx or abs(py) > hy:
            return True
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R_world_vehicle.tolist()
        for bx, by, bz in beams:
            dz = max(r20 * bx + r21 * by + r22 * bz, 1e-3)
            reach = (w.tank_depth_m - pz) / dz
            if abs(px + (r00 * bx + r01 * by + r02 * bz) * reach) > hx or abs(py + (r10 * bx + r11 * by + r12 * bz) * reach) > hy:
                return True
        return False

    return over


class _Runner:
    def __init__(self, mission: Mission, cfg: SlamConfig, mode: str, symmetries: dict[str, Symmetry],
                 init_rng: np.random.Generator) -> None:
        self.m, self.cfg, self.mode, self.sym = mission, cfg, mode, symmetries
        self.init_rng = init_rng
        self.gate = GateThresholds(cfg.gate_probability)
        a = mission.ahrs
        if len(a.stamp_s) == 0:
            raise SlamError("The mission has no AHRS samples: the filter needs the attitude as input.")
        self._att_t = a.stamp_s
        self._att = np.unwrap(a.rpy_rad, axis=0)
        s = np.asarray(cfg.ahrs_sigma_rpy_rad)
        self._ahrs_var = np.diag(s**2)
        self.log: list[dict] = []
        self.consensus = ConsensusInitializer(cfg.consensus_position_m, cfg.consensus_attitude,
                                              cfg.consensus_min_observations, cfg.consensus_max_age_s)
        self._thr = {d: self.gate.threshold(d) for d in range(1, 7)}
        self._rejections: dict[str, int] = {}
        self._sensor_thr = {d: GateThresholds(cfg.sensor_gate_probability).threshold(d) for d in (1, 3)}
        self._over_slope = None  # (position, rpy) -> bool: a DVL beam on the tank's slopes (known tank map)
        sim = (mission.config or {}).get("simulator", {}) or {}
        if cfg.dvl_slope_map and isinstance(sim.get("world"), dict):
            self._over_slope = _slope_test(sim["world"], (sim.get("dvl") or {}).get("beam_angle_rad", math.radians(30.0)))

    # ------------------------------------------------------------------ helpers
    def attitude(self, t: float) -> np.ndarray:
        """AHRS roll, pitch, yaw (unwrapped) linearly interpolated at ``t`` (held beyond the ends, as np.interp)."""
        return self.attitude_at(t)[0]

    def attitude_at(self, t: float) -> tuple[np.ndarray, float]:
        """``(rpy, f)``: the interpolated AHRS attitude and the factor ``f = (1 - w)^2 + w^2`` by which the
        interpolation (weight ``w``) of two samples with independent white errors scales their variance."""
        a, ts = self._att, self._att_t
        i = int(np.searchsorted(ts, t))
        if i == 0:
            return a[0].copy(), 1.0
        if i >= len(ts):
            return a[-1].copy(), 1.0
        t0, t1 = ts[i - 1], ts[i]
        if t1 <= t0:
            return a[i].copy(), 1.0
        w = (t - t0) / (t1 - t0)
        return a[i - 1] + w * (a[i] - a[i - 1]), (1.0 - w) ** 2 + w * w

    def attitude_cov_world(self, rpy: np.ndarray, var_factor: float = 1.0) -> np.ndarray | None:
        """World-frame rotation covariance (rad^2) of the AHRS attitude ``rpy`` (its white noise, scaled by
        ``var_factor`` for an interpolated attitude); None when attitude noise is not propagated."""
        if not self.cfg.propagate_attitude_noise:
            return None
        E = kern.rpy_to_world_rate(rpy)
        return E @ (self._ahrs_var * var_factor) @ E.T

    def predict_to(self, t: float) -> None:
        cfg, ekf = self.cfg, self.ekf
        while self.t < t - 1e-12:
            dt = min(cfg.max_predict_dt_s, t - self.t)
            rpy, f = self.attitude_at(self.t + dt / 2)
            R = rotation_from_rpy(*rpy)
            slope = self._over_slope is not None and ekf.dvl_calibration and self._over_slope(ekf.xa[0:3], R)
            ekf.predict(dt, R, velocity_rw=cfg.velocity_rw_mps_per_sqrt_s,
                        attitude_cov_world=self.attitude_cov_world(rpy, f), yaw_bias_rw=cfg.yaw_bias_rw_rad_per_sqrt_s,
                        dvl_on_slope=bool(slope))
            self.t += dt

    def _log(self, **kw) -> None:
        self.log.append(kw)

    # ------------------------------------------------------------------ main loop
    def run(self, detections_by_scan: dict[int, list[Detection]]) -> SlamResult:
        m, cfg = self.m, self.cfg
        starts = [s[0] for s in (m.ahrs.stamp_s, m.dvl.stamp_s, m.depth.stamp_s) if len(s)]
        if m.truth is not None:
            starts.append(m.truth.stamp_s[0])
        t0 = float(max(min(starts), self._att_t[0]))
        ends = [s[-1] for s in (m.ahrs.stamp_s, m.dvl.stamp_s, m.depth.stamp_s) if len(s)]
        t_end = float(max(ends))
        # the start: a known launch point (truth + an N(0, initial_position_sigma) fix error, drawn so that the
        # initial NEES is chi-square like every later one), zero velocity unless the DVL says otherwise
        p0 = m.truth.interpolate_position(t0)[0] if m.truth is not None else np.zeros(3)
        dp0 = self.init_rng.normal(0.0, cfg.initial_position_sigma_m, 3)
        if m.truth is not None and cfg.perturb_initial_position:
            p0 = p0 + dp0
        v0 = np.zeros(3)
        valid = np.flatnonzero(m.dvl.valid)
        if len(valid):
            v0 = m.dvl.velocity_body_mps[valid[0]]
        heading = self.mode == "pose+heading"
        calib = cfg.dvl_calibration
        ekf = SemanticEkf(p0, v0, np.eye(6 + 8 * calib + heading), yaw_bias=heading, dvl_calibration=calib,
                          dvl_bias_sigma_mps=cfg.dvl_bias_sigma_mps, dvl_bias_tau_s=cfg.dvl_bias_tau_s,
                          dvl_slope_bias_sigma_mps=cfg.dvl_slope_bias_sigma_mps,
                          dvl_slope_bias_tau_s=cfg.dvl_slope_bias_tau_s)
        var0 = [cfg.initial_position_sigma_m**2] * 3 + [cfg.initial_velocity_sigma_mps**2] * 3
        if calib:
            var0 += [max(cfg.dvl_bias_sigma_mps, 1e-6)**2] * 3 + [1e-12] * 3 + [max(cfg.dvl_scale_sigma, 1e-6)**2,
                                                                   max(cfg.dvl_misalignment_sigma_rad, 1e-6)**2]
        if heading:
            var0 += [cfg.yaw_bias_sigma_rad**2]
        ekf.P[...] = np.diag(var0)
        ekf._set_active(np.arange(ekf.n_v))
        ekf.constrain_heading_nullspace(heading and cfg.observability_constrained)
        if cfg.smooth:
            ekf.recorder = RtsRecorder(n_keep=6, max_bytes=cfg.smoother_max_mb * 1e6)
        self.ekf = ekf
        self.t = t0
        if cfg.surveyed_objects:
            self._add_surveyed(t0)

        # events: (stamp, order, kind, index)
        ev = []
        ev += [(float(t), 1, "dvl", i) for i, t in enumerate(m.dvl.stamp_s) if t >= t0]
        ev += [(float(t), 2, "depth", i) for i, t in enumerate(m.depth.stamp_s) if t >= t0]
        groups: dict = {}
        if self.mode != "dr":
            # each detection at its own stamp (the pipeline stamps a detection with the median time of its
            # cluster's points: a line scanner sees each object at its own time); one event per distinct stamp
            for sid, dets in detections_by_scan.items():
                for d in dets:
                    st = float(d.stamp_s)
                    if not math.isfinite(st):
                        raise SlamError(f"Every detection given to run_slam needs a finite 'stamp_s'. Got {d.stamp_s!r} "
                                        f"in scan {sid} instead.")
                    groups.setdefault((st, sid), []).append(d)
            ev += [(st, 3, "scan", key) for key in groups for st in (key[0],)]
        hist_t = np.arange(t0, t_end + 1e-9, 1.0 / cfg.history_rate_hz)
        ev += [(float(t), 4, "hist", i) for i, t in enumerate(hist_t)]
        ev.sort(key=lambda e: (e[0], e[1]))
        H = {"t": [], "p": [], "Pp": [], "v": [], "Pv": [], "b": [], "bv": [], "c": []}
        for t, _, kind, i in ev:
            self.predict_to(t)
            if kind == "dvl":
                self.update_dvl(t, i)
            elif kind == "depth":
                self.update_depth(t, i)
            elif kind == "scan":
                self.process_scan(t, groups[i])
            else:
                ekf = self.ekf
                if ekf.recorder is not None:
                    ekf.recorder.mark(ekf)
                H["t"].append(t)
                H["p"].append(ekf.xa[0:3].copy())
                H["Pp"].append(ekf.Paa[0:3, 0:3].copy())
                H["v"].append(ekf.xa[3:6].copy())
                H["Pv"].append(ekf.Paa[3:6, 3:6].copy())
                H["b"].append(ekf.yaw_bias_rad())
                H["bv"].append(float(ekf.Paa[ekf.i_yaw, ekf.i_yaw]) if ekf.yaw_bias else 0.0)
                H["c"].append(ekf.dvl_calibration_state())
        return self._result(H)

    def _add_surveyed(self, t0: float) -> None:
        """Landmarks of surveyed objects (a known reference structure): the object's true pose plus an
        N(0, survey sigma) error, independent of the vehicle. They make the absolute heading observable."""
        cfg, m = self.cfg, self.m
        byname = {o.name: o for o in m.objects}
        missing = [n for n in cfg.surveyed_objects if n not in byname]
        if missing:
            raise SlamError(f"The 'surveyed_objects' of SlamConfig must name objects of the mission "
                            f"({sorted(byname)}). Got {missing} instead.")
        poses, covs, labels = [], [], []
        for name in cfg.surveyed_objects:
            o = byname[name]
            R = kern.so3_exp(self.init_rng.normal(0.0, cfg.survey_rotation_sigma_rad, 3)) @ o.T_world_object.rotation
            p = o.T_world_object.translation_m + self.init_rng.normal(0.0, cfg.survey_position_sigma_m, 3)
            rpy = rpy_from_rotation(R)
            Einv = kern.world_rate_to_rpy(rpy)
            C = np.zeros((6, 6))
            C[0:3, 0:3] = np.eye(3) * cfg.survey_position_sigma_m**2
            C[3:6, 3:6] = Einv @ Einv.T * cfg.survey_rotation_sigma_rad**2
            poses.append(np.concatenate([p, rpy]))
            covs.append(0.5 * (C + C.T))
            labels.append(o.label)
        self.ekf.add_prior_landmarks(np.array(poses), np.array(covs), labels, stamp_s=t0,
                                     names=list(cfg.surveyed_objects))
        self.n_surveyed = len(poses)

    # ------------------------------------------------------------------ sensor updates
    def _linear_update(self, t, kind, idx, Hc, z, Rn, dof) -> None:
        ekf = self.ekf
        loc = ekf._loc[idx[0]] if len(idx) == 1 else -1
        if loc >= 0:  # scalar fast path (depth): no index gymnastics
            h = float(Hc[0, 0])
            nu = z - h * ekf.xa[loc]
            s = h * h * ekf.Paa[loc, loc] + float(Rn[0, 0])
            d2 = float(nu[0] * nu[0] / s) if s > 0 else float("inf")
        else:
            nu = z - Hc @ ekf.mean(idx)
            d2 = kern.mahalanobis2(nu, ekf.innovation_cov(idx, Hc, Rn))
        ok = d2 <= self._sensor_thr[dof]
        # gate lock-out guard: after `sensor_gate_max_rejections` consecutive rejections the filter, not the
        # sensor, is wrong (e.g. an unmodelled acceleration): accept the measurement to re-converge
        n_rej = self._rejections.get(kind, 0)
        forced = (not ok) and n_rej >= self.cfg.sensor_gate_max_rejections
        if ok or forced:
            ekf.update(idx, Hc, nu, Rn)
            self._rejections[kind] = 0
        else:
            self._rejections[kind] = n_rej + 1
        self._log(stamp_s=t, kind=kind, nis=d2, dof=dof, threshold=self._sensor_thr[dof], accepted=bool(ok or forced),
                  **({"reason": "gate_reset"} if forced else {}))

    def update_dvl(self, t: float, i: int) -> None:
        m, cfg = self.m, self.cfg
        if not m.dvl.valid[i]:
            self._log(stamp_s=t, kind="dvl_dropout", accepted=False)
            return
        z = m.dvl.velocity_body_mps[i]
        speed = float(np.linalg.norm(z))
        if speed > cfg.dvl_max_speed_mps:
            self._log(stamp_s=t, kind="dvl", nis=float("nan"), dof=3, accepted=False, reason="max_speed")
            return
        sigma = cfg.dvl_noise_abs_mps + cfg.dvl_noise_rel * speed
        ekf = self.ekf
        if ekf.dvl_calibration:  # z = (1 + k) Rz(delta) v + b
            idx = np.arange(3, 3 + 11)
            x = ekf.mean(idx)
            v, b, k, dl = x[0:3], x[3:6] + x[6:9], x[9], x[10]
            c, s_ = np.cos(dl), np.sin(dl)
            Rz = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
            dRz = np.array([[-s_, -c, 0.0], [c, -s_, 0.0], [0.0, 0.0, 0.0]])
            Hc = np.column_stack([(1.0 + k) * Rz, np.eye(3), np.eye(3), Rz @ v, (1.0 + k) * dRz @ v])
            nu = z - ((1.0 + k) * Rz @ v + b)
        else:
            idx, Hc = np.arange(3, 6), np.eye(3)
            nu = z - ekf.mean(idx)
        thr = self._sensor_thr[3]
        # two hypotheses, as the sensor is specified: nominal noise, or degraded (beams on a slope: noise x factor);
        # neither: an outlier, rejected. Several rejections in a row mean the *prediction* is wrong (an
        # unmodelled acceleration): inflate the velocity covariance by the innovation, then update (no lock-out)
        reason = ""
        hyps = (1.0, cfg.dvl_slope_noise_factor**2)
        if self._over_slope is not None:  # the navigator knows the tank: one hypothesis, from its own position
            hyps = hyps[1:] if self._over_slope(ekf.xa[0:3], rotation_from_rpy(*self.attitude(t))) else hyps[:1]
        for f2 in hyps:
            Rn = np.eye(3) * sigma**2 * f2
            d2 = kern.mahalanobis2(nu, ekf.innovation_cov(idx, Hc, Rn))
            if d2 <= thr:
                reason = "nominal" if f2 == 1.0 else "degraded"
                break
        n_rej = self._rejections.get("dvl", 0)
        if not reason and n_rej >= cfg.sensor_gate_max_rejections:
            ekf.inflate(np.arange(3, 6), np.diag(nu**2))
            Rn = np.eye(3) * sigma**2
            reason = "maneuver"
        if reason:
            ekf.update(idx, Hc, nu, Rn)
            self._rejections["dvl"] = 0
        else:
            self._rejections["dvl"] = n_rej + 1
        self._log(stamp_s=t, kind="dvl", nis=d2, dof=3, threshold=thr, accepted=bool(reason),
                  reason=reason or "outlier")

    def update_depth(self, t: float, i: int) -> None:
        self._linear_update(t, "depth", np.array([2]), np.ones((1, 1)), np.array([self.m.depth.depth_m[i]]),
                            np.array([[self.cfg.depth_sigma_m**2]]), 1)

    # ------------------------------------------------------------------ object updates
    def _landmark_positions(self) -> np.ndarray:
        ekf = self.ekf
        offs = np.array([lm.offset for lm in ekf.landmarks], dtype=np.intp)
        if len(offs) == 0:
            return np.zeros((0, 3))
        pos = ekf.x[offs[:, None] + np.arange(3)]
        loc = ekf._loc[offs]
        a = loc >= 0
        pos[a] = ekf.xa[loc[a][:, None] + np.arange(3)]
        return pos

    def _ensure_active(self, j: int) -> None:
        ekf, cfg = self.ekf, self.cfg
        if ekf.is_active(j):
            return
        if len(ekf.landmarks) <= cfg.dense_max_landmarks:
            ids = range(len(ekf.landmarks))
        else:
            ekf.flush()
            d = np.linalg.norm(self._landmark_positions() - ekf.xa[0:3], axis=1)
            ids = set(np.flatnonzero(d < cfg.active_radius_m).tolist()) | {j}
        ekf.set_active_landmarks(ids)

    def process_scan(self, t: float, dets: list[Detection]) -> None:
        ekf, cfg = self.ekf, self.cfg
        rpy, f = self.attitude_at(t)
        R_ahrs = rotation_from_rpy(*rpy)
        att_cov = self.attitude_cov_world(rpy, f)
        meas = [measurement_from_detection(d, self.m.T_vehicle_scanner, symmetry=self.sym.get(d.label),
                                           unobservable_var_rad2=cfg.unobservable_var_rad2, index=k)
                for k, d in enumerate(dets)]
        test = "position" if self.mode == "position" else "pose"
        labels = [lm.label for lm in ekf.landmarks]
        lpos = self._landmark_positions()
        p = ekf.xa[0:3]
        unassociated = []
        for label in sorted({x.label for x in meas}):
            M = [x for x in meas if x.label == label]
            L = [j for j, lb in enumerate(labels) if lb == label
                 and np.linalg.norm(lpos[j] - p) < cfg.candidate_radius_m]
            d2 = np.full((len(M), len(L)), np.inf)
            inns = {}
            for a, x in enumerate(M):
                for b, j in enumerate(L):
                    inn = innovation(ekf, j, x, R_ahrs, att_cov, orientation_innovation=cfg.orientation_innovation)
                    inns[(a, b)] = inn
                    d2[a, b] = inn.d2_position
            gate = d2 <= self._thr[3]
            if cfg.association == "jcbb" and len(M) > 1:
                pairs = associate_jcbb(inns, ekf, len(M), gate, cfg.gate_probability)
            else:
                pairs = associate(d2, gate)
            paired = {a for a, _ in pairs}
            for a, b in pairs:
                self._update_landmark(t, M[a], L[b], R_ahrs, att_cov, test, dets[M[a].index])
            for a, x in enumerate(M):
                if a not in paired:
                    if gate[a].any():  # compatible with a landmark taken by another detection: ambiguous, drop
                        self._log(stamp_s=t, kind="landmark", accepted=False, test="none", label=label,
                                  detection=x.index, reason="ambiguous")
                    else:
                        unassociated.append(x)
        for x in unassociated:
            self._to_consensus(t, x, R_ahrs, att_cov, dets[x.index])

    def _update_landmark(self, t, x, j, R_ahrs, att_cov, test, det) -> None:
        ekf = self.ekf
        self._ensure_active(j)
        inn = innovation(ekf, j, x, R_ahrs, att_cov, orientation_innovation=self.cfg.orientation_innovation)
        lm = ekf.landmarks[j]
        common = dict(stamp_s=t, kind="landmark", landmark=j, label=x.label, landmark_label=lm.label,
                      detection=x.index, object_name=det.extras.get("object_name", ""))
        if test == "pose" and inn.dof_pose > 3 and inn.d2_pose <= self._thr[inn.dof_pose]:
            which, d2, dof = "pose", inn.d2_pose, inn.dof_pose
        elif inn.d2_position <= self._thr[3]:
            which, d2, dof = "position", inn.d2_position, 3
        else:
            self._log(**common, nis=inn.d2_position, dof=3, threshold=self._thr[3], accepted=False, test="none")
            return
        if x.label != lm.label:  # pragma: no cover - guarded by construction
            raise SlamError("internal error: cross-class landmark update")
        Hc, nu, Rn = inn.rows(which)
        ekf.update(inn.idx, Hc, nu, Rn)
        lm.last_seen_s = t
        lm.n_updates += 1
        self._log(**common, nis=d2, dof=dof, threshold=self._thr[dof], accepted=True, test=which)

    def _to_consensus(self, t, x, R_ahrs, att_cov, det) -> None:
        ekf = self.ekf
        R = ekf.true_attitude(R_ahrs)
        p = ekf.xa[0:3].copy()
        axes_w = x.unobservable_axes_vehicle @ R.T
        obs = Observation(x.label, t, p + R @ x.p_vehicle_object_m, R @ x.R_vehicle_object, x.symmetry, axes_w,
                          payload=(R, p, x, att_cov, det.extras.get("object_name", ""), ekf.Paa[0:3, 0:3].copy()))
        res = self.consensus.add(obs)
        self._log(stamp_s=t, kind="candidate", label=x.label, detection=x.index, accepted=res is not None,
                  object_name=det.extras.get("object_name", ""))
        if res is None:
            return
        members, pos, R_mean = res
        self._add_landmark(t, members, pos, R_mean)

    def _add_landmark(self, t, members, pos, R_mean) -> None:
        ekf = self.ekf
        n = len(members)
        rpy = rpy_from_rotation(R_mean)
        Cp = np.zeros((3, 3))
        Cr = np.zeros((3, 3))
        for o in members:
            R, p, x, att_cov, _, _ = o.payload
            N = x.noise_cov
            Cp += R @ N[0:3, 0:3] @ R.T
            Cr += R @ N[3:6, 3:6] @ R.T
            if att_cov is not None:
                d = o.position_world_m - p
                Cp += kern.skew(d) @ att_cov @ kern.skew(d).T
                Cr += att_cov
        Cp /= n * n
        Cr /= n * n
        # the members' world positions carry the vehicle's error at *their* stamps, the new landmark is tied to
        # the vehicle *now*: add the covariance of the mean displacement error since then (else the landmark looks
        # n-fold more precise relative to the vehicle than it is, and the next detections fail the gate)
        Cp += _drift_since(ekf.Paa[0:3, 0:3], [o.payload[5] for o in sorted(members, key=lambda o: o.stamp_s)])
        axes = members[0].axes_world
        for u in axes:  # free rotation about an unobservable axis: wide prior, never updated
            Cr += np.outer(u, u) * np.pi**2
        Einv = kern.world_rate_to_rpy(rpy)
        noise = np.zeros((6, 6))
        noise[0:3, 0:3] = Cp
        noise[3:6, 3:6] = Einv @ Cr @ Einv.T
        G = np.zeros((6, ekf.n_v))
        G[0:3, 0:3] = np.eye(3)
        if ekf.yaw_bias:
            G[0:3, ekf.i_yaw] = -kern.skew(_EZ) @ (pos - ekf.xa[0:3])
            G[5, ekf.i_yaw] = -1.0
        names = [o.payload[4] for o in members]
        name = max(set(names), key=names.count) if names else ""
        j = ekf.add_landmark(np.concatenate([pos, rpy]), G, noise, label=members[0].label, stamp_s=t, name=name)
        ekf.landmarks[j].first_seen_s = min(o.stamp_s for o in members)
        self._log(stamp_s=t, kind="new_landmark", landmark=j, label=members[0].label, accepted=True,
                  n_observations=n, object_name=name)

    # ------------------------------------------------------------------ results
    def _result(self, H: dict) -> SlamResult:
        m, ekf = self.m, self.ekf
        ekf.flush()
        stamps = np.asarray(H["t"])
        pos = np.asarray(H["p"]).reshape(-1, 3)
        Pp = np.asarray(H["Pp"]).reshape(-1, 3, 3)
        truth = m.truth.interpolate_position(stamps) if m.truth is not None else None
        landmarks = []
        for j, lm in enumerate(ekf.landmarks):
            pose = ekf.landmark_pose(j)
            landmarks.append(self._evaluate_landmark(j, lm, pose, ekf.landmark_cov(j)))
        metrics: dict = {"mode": self.mode, "n_landmarks": len(landmarks), "duration_s": float(stamps[-1] - stamps[0]) if len(stamps) else 0.0}
        if truth is not None and len(stamps):
            metrics.update(trajectory_metrics(pos, truth, Pp))
        nis: dict = {}
        for r in self.log:
            if r.get("accepted") and "nis" in r and np.isfinite(r["nis"]):
                key = r["kind"] if r["kind"] != "landmark" else f"landmark_{r['test']}_{r['dof']}dof"
                nis.setdefault(key, ([], r["dof"]))[0].append(r["nis"])
        metrics["nis"] = nis_summary(nis)
        ups = [r for r in self.log if r["kind"] == "landmark" and r.get("accepted")]
        metrics["landmark_updates"] = {"pose": sum(r["test"] == "pose" for r in ups),
                                       "position": sum(r["test"] == "position" for r in ups),
                                       "rejected": sum(r["kind"] == "landmark" and not r.get("accepted") for r in self.log)}
        metrics["cross_class_updates"] = sum(r["label"] != r["landmark_label"] for r in ups)
        byname = {lm.landmark_id: lm.matched_object for lm in landmarks}
        metrics["wrong_object_updates"] = sum(bool(r.get("object_name")) and r["object_name"] != byname.get(r["landmark"])
                                              for r in ups)
        metrics["dvl_rejected"] = sum(r["kind"] == "dvl" and not r["accepted"] for r in self.log)
        metrics["dvl_degraded"] = sum(r["kind"] == "dvl" and r.get("reason") == "degraded" for r in self.log)
        metrics["dvl_maneuver_resets"] = sum(r["kind"] == "dvl" and r.get("reason") == "maneuver" for r in self.log)
        lp = np.array([lm.nees_position for lm in landmarks])
        lq = np.array([lm.nees_pose for lm in landmarks])
        metrics["landmark_nees_position"] = lp[np.isfinite(lp)].tolist()
        metrics["landmark_nees_pose"] = lq[np.isfinite(lq)].tolist()
        metrics["dvl_dropouts"] = sum(r["kind"] == "dvl_dropout" for r in self.log)
        if landmarks and m.objects:
            pe = np.array([lm.position_error_m for lm in landmarks])
            oe = np.array([lm.orientation_error_rad for lm in landmarks])
            metrics["landmark_position_error_mean_m"] = float(np.nanmean(pe)) if np.isfinite(pe).any() else None
            metrics["landmark_position_error_max_m"] = float(np.nanmax(pe)) if np.isfinite(pe).any() else None
            metrics["landmark_orientation_error_mean_deg"] = float(np.degrees(np.nanmean(oe))) if np.isfinite(oe).any() else None
            metrics["n_objects_mapped"] = len({lm.matched_object for lm in landmarks if lm.matched_object})
        sm = None
        if ekf.recorder is not None:
            sm = ekf.recorder.smooth(ekf)
            metrics["smoother"] = {"status": ekf.recorder.status}
            if sm is not None and len(sm.x) != len(stamps):  # pragma: no cover - guarded by construction
                raise SlamError("internal error: smoothed epochs do not match the history")
            if sm is not None and truth is not None and len(stamps):
                metrics["smoother"].update(trajectory_metrics(sm.x[:, 0:3], truth, sm.P[:, 0:3, 0:3]))
        return SlamResult(self.mode, stamps, pos, Pp, np.asarray(H["v"]).reshape(-1, 3),
                          np.asarray(H["Pv"]).reshape(-1, 3, 3), np.asarray(H["b"]), truth, landmarks, self.log,
                          metrics, self.cfg, np.asarray(H["c"]).reshape(-1, 8) if ekf.dvl_calibration else None,
                          np.asarray(H["bv"]) if ekf.yaw_bias else None,
                          None if sm is None else sm.x[:, 0:3].copy(),
                          None if sm is None else sm.P[:, 0:3, 0:3].copy(),
                          None if sm is None else sm.x[:, 3:6].copy())

    def _evaluate_landmark(self, j, lm, pose, cov) -> LandmarkEstimate:
        objs = [o for o in self.m.objects if o.label == lm.label]
        if not objs:
            return LandmarkEstimate(j, lm.label, pose, cov, lm.first_seen_s, lm.last_seen_s, lm.n_updates)
        d = [np.linalg.norm(o.T_world_object.translation_m - pose[:3]) for o in objs]
        o = objs[int(np.argmin(d))]
        sym = self.sym.get(lm.label, Symmetry())
        R_est = rotation_from_rpy(*pose[3:6])
        R_true = o.T_world_object.rotation
        if sym.kind == "continuous":
            a = sym.axis_object
            err = float(np.arccos(np.clip((R_est @ a) @ (R_true @ a), -1, 1)))
        else:
            from .association import align_rotation

            err = float(np.linalg.norm(kern.so3_log(align_rotation(R_est, R_true, sym, np.zeros((0, 3))) @ R_true.T)))
        e_p = o.T_world_object.translation_m - pose[:3]
        nees_p = kern.mahalanobis2(e_p, cov[:3, :3])
        nees_q = float("nan")
        if sym.kind != "continuous":
            from .association import align_rotation

            R_al = align_rotation(R_true, R_est, sym, np.zeros((0, 3)))  # the equivalent truth closest to the estimate
            e = np.concatenate([e_p, kern.world_rate_to_rpy(pose[3:6]) @ kern.so3_log(R_al @ R_est.T)])
            nees_q = kern.mahalanobis2(e, cov)
        return LandmarkEstimate(j, lm.label, pose, cov, lm.first_seen_s, lm.last_seen_s, lm.n_updates, o.name,
                                float(min(d)), err, nees_p, nees_q)


# ---------------------------------------------------------------------- writing a run directory
def write_run(result: SlamResult, out_dir: str | Path) -> Path:
    """Write ``trajectory.csv``, ``trajectory_smoothed.csv`` (when smoothed), ``landmarks.csv``, ``updates.csv``,
    ``metrics.json`` and ``config.json`` (each atomically) into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    head = ["stamp_s", "x_m", "y_m", "z_m", "u_mps", "v_mps", "w_mps"]
    head += [f"cov_p_{a}{b}" for a in "xyz" for b in "xyz" if a <= b] + [f"cov_v_{a}{b}" for a in "uvw" for b in "uvw" if a <= b]
    head += ["yaw_bias_rad"] + (["truth_x_m", "truth_y_m", "truth_z_m"] if result.truth_position_ned_m is not None else [])
    w.writerow(head)
    iu = np.triu_indices(3)
    for k in range(len(result.stamps_s)):
        row = [result.stamps_s[k], *result.position_ned_m[k], *result.velocity_body_mps[k],
               *result.position_cov_m2[k][iu], *result.velocity_cov[k][iu], result.yaw_bias_rad[k]]
        if result.truth_position_ned_m is not None:
            row += list(result.truth_position_ned_m[k])
        w.writerow([f"{v:.9g}" for v in row])
    atomic_write_text(out / "trajectory.csv", buf.getvalue())
    if result.smoothed_position_ned_m is not None:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["stamp_s", "x_m", "y_m", "z_m", "u_mps", "v_mps", "w_mps"]
                   + [f"cov_p_{a}{b}" for a in "xyz" for b in "xyz" if a <= b])
        for k in range(len(result.stamps_s)):
            row = [result.stamps_s[k], *result.smoothed_position_ned_m[k], *result.smoothed_velocity_body_mps[k],
                   *result.smoothed_position_cov_m2[k][iu]]
            w.writerow([f"{v:.9g}" for v in row])
        atomic_write_text(out / "trajectory_smoothed.csv", buf.getvalue())

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    i6 = np.triu_indices(6)
    names = ["x", "y", "z", "roll", "pitch", "yaw"]
    w.writerow(["landmark_id", "label", "x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad", "first_seen_s",
                "last_seen_s", "n_updates", "matched_object", "position_error_m", "orientation_error_rad"]
               + [f"cov_{names[a]}_{names[b]}" for a, b in zip(*i6)])
    for lm in result.landmarks:
        w.writerow([lm.landmark_id, lm.label, *[f"{v:.9g}" for v in lm.pose_xyzrpy], f"{lm.first_seen_s:.6f}",
                    f"{lm.last_seen_s:.6f}", lm.n_updates, lm.matched_object, f"{lm.position_error_m:.6g}",
                    f"{lm.orientation_error_rad:.6g}", *[f"{v:.9g}" for v in lm.covariance_6x6[i6]]])
    atomic_write_text(out / "landmarks.csv", buf.getvalue())

    cols = ["stamp_s", "kind", "accepted", "test", "nis", "dof", "threshold", "landmark", "label", "detection",
            "object_name", "reason"]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in result.update_log:
        w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    atomic_write_text(out / "updates.csv", buf.getvalue())

    from ..cli._output import to_jsonable

    atomic_write_text(out / "metrics.json", json.dumps(to_jsonable(result.metrics), indent=2) + "\n")
    atomic_write_text(out / "config.json", json.dumps(to_jsonable(result.config.to_dict()), indent=2) + "\n")
    return out
