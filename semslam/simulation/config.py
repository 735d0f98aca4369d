"""Simulator configuration: frozen dataclasses with documented defaults (SI units, radians).

Where the defaults come from:

* Objects and tank: Himri et al. 2018/2019 (four PVC fittings on the floor of the CIRS tank, ~16 x 8 x
  5 m, Girona 500 flown in an approximate square over them, ~3 loops).
* Scanner: the papers' Girona laser scanner (laser line + galvanometer mirror + camera, 3-10 Hz). Noise
  is triangulation-like: sigma = ``noise_floor_m + noise_range2_per_m * r**2`` along the camera ray.
* Kinect: 640 x 480, f = 525 px, baseline 7.5 cm, disparity quantised to 1/8 px; depth error growing
  with the square of depth, sigma_z ~ 1.5e-3 * z**2 (Khoshelham & Elberink 2012).
* Navigation sensors (design/slam-notes.md section 3): DVL 5 Hz, white sigma = 0.3 % |v| + 1 mm/s per
  axis, worse over the tank's sloped sides (the papers' observed drift), plus a per-mission scale factor
  (0.5 %) and yaw misalignment (0.5 deg) and a Gauss-Markov bias (3 mm/s, 20 s): ~1-2 % of distance
  travelled of dead-reckoning drift (see :class:`DvlConfig`); AHRS 20 Hz, Xsens MTi-300-like
  0.2 / 0.2 / 1.0 degree white noise; pressure depth 10 Hz, 2 cm.

Every config has ``to_dict`` / ``from_dict`` (JSON round trip, used for mission.json).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from ..errors import SimulationError


def _check(cfg: Any, positive: tuple[str, ...] = (), nonneg: tuple[str, ...] = (), prob: tuple[str, ...] = ()) -> None:
    name = type(cfg).__name__
    for attr in positive + nonneg + prob:
        v = getattr(cfg, attr)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise SimulationError(f"The {attr!r} field of {name} must be a finite number. Got {v!r} instead.")
    for attr in positive:
        if getattr(cfg, attr) <= 0:
            raise SimulationError(f"The {attr!r} field of {name} must be > 0. Got {getattr(cfg, attr)!r} instead.")
    for attr in nonneg:
        if getattr(cfg, attr) < 0:
            raise SimulationError(f"The {attr!r} field of {name} must be >= 0. Got {getattr(cfg, attr)!r} instead.")
    for attr in prob:
        if not 0 <= getattr(cfg, attr) <= 1:
            raise SimulationError(f"The {attr!r} field of {name} must be a probability in [0, 1]. Got {getattr(cfg, attr)!r} instead.")


def _check_vec(cfg: Any, attr: str, n: int) -> None:
    v = getattr(cfg, attr)
    ok = isinstance(v, (tuple, list)) and len(v) == n and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
    if not ok:
        raise SimulationError(f"The {attr!r} field of {type(cfg).__name__} must be {n} finite numbers. Got {v!r} instead.")
    object.__setattr__(cfg, attr, tuple(float(x) for x in v))


class _Dict:
    def to_dict(self) -> dict:
        return dataclasses.asdict(self)  # type: ignore[call-overload]

    @classmethod
    def from_dict(cls, d: dict) -> Any:
        if not isinstance(d, dict):
            raise SimulationError(f"A {cls.__name__} record must be a mapping. Got {type(d).__name__} instead.")
        names = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
        unknown = set(d) - set(names)
        if unknown:
            raise SimulationError(f"Unknown field(s) {sorted(unknown)} in a {cls.__name__} record. Expected some of {sorted(names)}.")
        kwargs = {}
        for k, v in d.items():
            sub = _SUBCONFIGS.get(k)
            kwargs[k] = sub.from_dict(v) if sub is not None and cls is SimulatorConfig else (tuple(v) if isinstance(v, list) else v)
        return cls(**kwargs)


@dataclass(frozen=True)
class WorldConfig(_Dict):
    """The CIRS-like tank (world NED, origin at the water surface above the tank centre, x along the
    tank's long side) and what lies on its floor.

    The floor is flat at ``tank_depth_m`` except near the walls, where it rises linearly over
    ``slope_run_m`` to the rim at z = 0. The four fittings sit at the corners of a square of side
    ``object_spacing_m`` centred at ``objects_centre_ne_m`` (north, east), in their most probable
    resting pose with a random yaw and +-``placement_jitter_m`` of position jitter.
    """

    tank_length_m: float = 16.0
    tank_width_m: float = 8.0
    tank_depth_m: float = 5.0
    slope_run_m: float = 1.5
    object_spacing_m: float = 1.75
    objects_centre_ne_m: tuple = (0.0, 1.4)
    placement_jitter_m: float = 0.15
    clutter: bool = False
    n_clutter: int = 6

    def __post_init__(self) -> None:
        _check(self, positive=("tank_length_m", "tank_width_m", "tank_depth_m", "object_spacing_m"),
               nonneg=("slope_run_m", "placement_jitter_m"))
        _check_vec(self, "objects_centre_ne_m", 2)
        if 2 * self.slope_run_m >= min(self.tank_length_m, self.tank_width_m):
            raise SimulationError(f"The 'slope_run_m' field of WorldConfig must be < half the tank width. Got {self.slope_run_m} instead.")
        if isinstance(self.n_clutter, bool) or not isinstance(self.n_clutter, int) or self.n_clutter < 0:
            raise SimulationError(f"The 'n_clutter' field of WorldConfig must be an integer >= 0. Got {self.n_clutter!r} instead.")


@dataclass(frozen=True)
class TrajectoryConfig(_Dict):
    """Girona 500-like flight: a square with rounded corners through the four objects, ``loops`` times,
    at ``speed_mps`` and ``altitude_m`` above the flat floor, with small roll/pitch oscillations.

    The papers' vehicle was teleoperated, so it holds neither its speed nor its heading exactly:
    ``speed_wander_mps`` is the rms of a smooth surge-speed fluctuation (three sinusoids, periods 4-12 s,
    random phases) and ``crab_rms_rad`` the rms of the heading's offset from the course (two sinusoids,
    periods 5-10 s), which gives a sway velocity. Both fade in and out with the launch and stop ramps;
    0 gives the ideal flight at exactly ``speed_mps`` along the path."""

    loops: int = 3
    speed_mps: float = 0.3
    altitude_m: float = 1.5
    corner_radius_m: float = 0.35
    altitude_wave_m: float = 0.1
    roll_amplitude_rad: float = math.radians(1.5)
    pitch_amplitude_rad: float = math.radians(2.0)
    truth_rate_hz: float = 50.0
    start_ramp_s: float = 3.0
    speed_wander_mps: float = 0.02
    crab_rms_rad: float = math.radians(2.0)

    def __post_init__(self) -> None:
        _check(self, positive=("speed_mps", "altitude_m", "truth_rate_hz"),
               nonneg=("corner_radius_m", "altitude_wave_m", "roll_amplitude_rad", "pitch_amplitude_rad", "start_ramp_s",
                       "speed_wander_mps", "crab_rms_rad"))
        if self.speed_wander_mps > 0.25 * self.speed_mps:
            raise SimulationError("The 'speed_wander_mps' field of TrajectoryConfig must be <= speed_mps / 4 (the vehicle "
                                  f"never stops or reverses). Got {self.speed_wander_mps} with speed_mps "
                                  f"{self.speed_mps} instead.")
        if self.crab_rms_rad > math.radians(10.0):
            raise SimulationError(f"The 'crab_rms_rad' field of TrajectoryConfig must be <= 10 degrees. Got {self.crab_rms_rad} rad instead.")
        if isinstance(self.loops, bool) or not isinstance(self.loops, int) or self.loops < 1:
            raise SimulationError(f"The 'loops' field of TrajectoryConfig must be an integer >= 1. Got {self.loops!r} instead.")


@dataclass(frozen=True)
class ScannerConfig(_Dict):
    """The laser scanner (frame: z out of the viewport along the optical axis, x along the baseline
    from the laser to the camera, y = z cross x). The galvanometer sweeps the laser plane (spanned by y
    and the sweep direction) from -``sweep_fov_rad``/2 to +``sweep_fov_rad``/2 about y in
    ``1 / scan_rate_hz`` seconds, ``n_lines`` lines of ``points_per_line`` samples spread over
    ``line_fov_rad``. The camera sits ``baseline_m`` along +x, toed in by ``camera_toe_in_rad``.

    ``T_vehicle_scanner`` (xyz metres, rpy radians): default 0.6 m forward, 0.3 m below the vehicle
    origin, the optical axis along the vehicle z (looking down) and the scanner x along the vehicle x.
    """

    scan_rate_hz: float = 3.0
    n_lines: int = 320
    points_per_line: int = 320
    sweep_fov_rad: float = math.radians(50.0)
    line_fov_rad: float = math.radians(50.0)
    baseline_m: float = 0.3
    camera_toe_in_rad: float = math.radians(5.0)
    camera_fov_rad: float = math.radians(70.0)
    min_range_m: float = 0.3
    max_range_m: float = 4.0
    noise_floor_m: float = 0.0005
    noise_range2_per_m: float = 0.001
    dropout_prob: float = 0.02
    backscatter_prob: float = 0.001
    attenuation_per_m: float = 0.3
    only_when_objects_in_view: bool = True
    T_vehicle_scanner_xyz_m: tuple = (0.6, 0.0, 0.3)
    T_vehicle_scanner_rpy_rad: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        _check(self, positive=("scan_rate_hz", "sweep_fov_rad", "line_fov_rad", "baseline_m", "camera_fov_rad", "max_range_m"),
               nonneg=("camera_toe_in_rad", "min_range_m", "noise_floor_m", "noise_range2_per_m", "attenuation_per_m"),
               prob=("dropout_prob", "backscatter_prob"))
        for attr in ("n_lines", "points_per_line"):
            v = getattr(self, attr)
            if isinstance(v, bool) or not isinstance(v, int) or v < 2:
                raise SimulationError(f"The {attr!r} field of ScannerConfig must be an integer >= 2. Got {v!r} instead.")
        if self.min_range_m >= self.max_range_m:
            raise SimulationError(f"The 'min_range_m' field of ScannerConfig must be < max_range_m ({self.max_range_m}). Got {self.min_range_m} instead.")
        if self.sweep_fov_rad >= math.pi or self.line_fov_rad >= math.pi:
            raise SimulationError("The fields 'sweep_fov_rad' and 'line_fov_rad' of ScannerConfig must be < pi.")
        _check_vec(self, "T_vehicle_scanner_xyz_m", 3)
        _check_vec(self, "T_vehicle_scanner_rpy_rad", 3)


@dataclass(frozen=True)
class KinectConfig(_Dict):
    """Kinect-like depth camera for the view database: views every 360/n degrees of azimuth around the
    object (in its most probable resting pose) at ``elevation_rad`` above the floor, ``distance_m`` from
    its centre of mass. Depth noise sigma_z = ``depth_noise_per_m * z**2``, applied in disparity and
    quantised to ``disparity_step_px`` (f * baseline / z).

    The defaults are the papers' bench (45 degrees, 0.7 m). The built-in recognition database uses
    :data:`semslam.simulation.kinect.SURVEY_KINECT` instead (75 degrees, 1.5 m: the survey geometry)."""

    width_px: int = 640
    height_px: int = 480
    focal_px: float = 525.0
    baseline_m: float = 0.075
    disparity_step_px: float = 0.125
    depth_noise_per_m: float = 0.0015
    distance_m: float = 0.7
    elevation_rad: float = math.radians(45.0)

    def __post_init__(self) -> None:
        _check(self, positive=("focal_px", "baseline_m", "distance_m"), nonneg=("disparity_step_px", "depth_noise_per_m", "elevation_rad"))
        for attr in ("width_px", "height_px"):
            v = getattr(self, attr)
            if isinstance(v, bool) or not isinstance(v, int) or v < 8:
                raise SimulationError(f"The {attr!r} field of KinectConfig must be an integer >= 8. Got {v!r} instead.")
        if self.elevation_rad >= math.pi / 2:
            raise SimulationError(f"The 'elevation_rad' field of KinectConfig must be < pi/2. Got {self.elevation_rad} instead.")


@dataclass(frozen=True)
class DvlConfig(_Dict):
    """Doppler velocity log (body-frame velocity, bottom lock).

    Measurement model (body frame): ``z = (1 + k) Rz(delta) v + b(t) + n`` with

    * ``k ~ N(0, scale_factor_sigma**2)`` drawn once per mission (sound-speed and beam-angle errors:
      a 1 % sound-speed error is a ~1 % velocity scale error; "0.5 %V" long-term accuracy figures,
      Tang et al. 2013; Water Linked A50 1 % / 0.1 %),
    * ``delta ~ N(0, misalignment_sigma_rad**2)`` a yaw mounting misalignment drawn once per mission
      (uncalibrated DVL-to-AHRS alignment errors of the order of a degree: Kinsey & Whitcomb 2007,
      "In situ alignment calibration of attitude and Doppler sensors", IEEE JOE 32(2)),
    * ``b(t)`` a first-order Gauss-Markov bias per axis (stationary std ``bias_sigma_mps``, correlation
      time ``bias_tau_s``): the "+- x mm/s" term of DVL specifications (0.5 cm/s in Tang et al. 2013,
      3 mm/s for a 120 kHz unit; design/slam-notes.md section 3), which does not average out over a
      few seconds. Its correlation time (20 s: ~6 m of travel, bottom-texture and altitude dependent) is a
      modelling assumption, not a datasheet figure. A body-fixed *constant* error (scale, misalignment, a
      slow bias) cancels over every closed loop of the square; the 20 s bias does not, so that with the
      defaults an AHRS + DVL dead reckoning drifts ~1 % of the distance travelled (slam-notes section 3:
      1-2 % for an AHRS + DVL vehicle),
    * ``n`` white noise per axis, sigma = ``noise_rel`` * |v| + ``noise_abs_mps``.

    When any of the four Janus beams (``beam_angle_rad`` from vertical) hits the sloped sides, the white
    sigma is multiplied by ``slope_noise_factor``, the outlier and dropout probabilities become the
    ``slope_*`` ones, and a second Gauss-Markov bias (std ``slope_bias_sigma_mps``, correlation time
    ``slope_bias_tau_s``) is driven; it decays with that time once the beams are back on the flat floor (the
    papers: flying over the tank's ~73-degree slopes "is known to generate a significant noise on the DVL
    readings" and caused most of their dead-reckoning drift; the magnitudes are assumptions). An outlier adds N(0,
    ``outlier_std_mps``) per axis; a dropout is an invalid
    (NaN) row. Setting the four systematic terms to 0 gives a white-noise-only DVL.
    """

    rate_hz: float = 5.0
    noise_rel: float = 0.003
    noise_abs_mps: float = 0.001
    dropout_prob: float = 0.01
    outlier_prob: float = 0.0
    outlier_std_mps: float = 0.1
    slope_noise_factor: float = 5.0
    slope_dropout_prob: float = 0.1
    slope_outlier_prob: float = 0.05
    beam_angle_rad: float = math.radians(30.0)
    max_altitude_m: float = 30.0
    #: white noise of each beam's slant range to the bottom (m), written like a real DVL's per-beam data
    range_noise_m: float = 0.01
    scale_factor_sigma: float = 0.005
    misalignment_sigma_rad: float = math.radians(0.5)
    bias_sigma_mps: float = 0.003
    bias_tau_s: float = 20.0
    slope_bias_sigma_mps: float = 0.015
    slope_bias_tau_s: float = 5.0

    def __post_init__(self) -> None:
        _check(self, positive=("rate_hz", "slope_noise_factor", "max_altitude_m", "bias_tau_s", "slope_bias_tau_s"),
               nonneg=("noise_rel", "noise_abs_mps", "outlier_std_mps", "beam_angle_rad", "range_noise_m", "scale_factor_sigma",
                       "misalignment_sigma_rad", "bias_sigma_mps", "slope_bias_sigma_mps"),
               prob=("dropout_prob", "outlier_prob", "slope_dropout_prob", "slope_outlier_prob"))

    @classmethod
    def white(cls, **kw: Any) -> DvlConfig:
        """A DVL with white noise only (no scale factor, misalignment or bias): the pre-realism model."""
        return cls(**{"scale_factor_sigma": 0.0, "misalignment_sigma_rad": 0.0, "bias_sigma_mps": 0.0,
                      "slope_bias_sigma_mps": 0.0, **kw})


@dataclass(frozen=True)
class AhrsConfig(_Dict):
    """Attitude (roll, pitch, yaw) with white noise ``noise_rpy_rad`` and a yaw bias: constant
    ``yaw_bias_rad`` plus a random walk of ``yaw_bias_walk_rad_per_sqrt_s`` (0 = off)."""

    rate_hz: float = 20.0
    noise_rpy_rad: tuple = (math.radians(0.2), math.radians(0.2), math.radians(1.0))
    yaw_bias_rad: float = 0.0
    yaw_bias_walk_rad_per_sqrt_s: float = 0.0

    def __post_init__(self) -> None:
        _check(self, positive=("rate_hz",), nonneg=("yaw_bias_walk_rad_per_sqrt_s",))
        _check_vec(self, "noise_rpy_rad", 3)
        if min(self.noise_rpy_rad) < 0:
            raise SimulationError(f"The 'noise_rpy_rad' field of AhrsConfig must be >= 0. Got {self.noise_rpy_rad} instead.")
        if not math.isfinite(self.yaw_bias_rad):
            raise SimulationError(f"The 'yaw_bias_rad' field of AhrsConfig must be finite. Got {self.yaw_bias_rad} instead.")


@dataclass(frozen=True)
class DepthConfig(_Dict):
    """Pressure depth (metres, world z) with white noise ``noise_m`` and a constant ``bias_m``."""

    rate_hz: float = 10.0
    noise_m: float = 0.02
    bias_m: float = 0.0

    def __post_init__(self) -> None:
        _check(self, positive=("rate_hz",), nonneg=("noise_m",))
        if not math.isfinite(self.bias_m):
            raise SimulationError(f"The 'bias_m' field of DepthConfig must be finite. Got {self.bias_m} instead.")


@dataclass(frozen=True)
class FixConfig(_Dict):
    """Position fixes as a vehicle records them (off by default: the papers' indoor tank has no GPS).

    ``gps_count`` surface GPS fixes (``sensor_msgs/NavSatFix``) at ``gps_rate_hz``, the last one
    ``gps_before_start_s`` before the dive starts, with the vehicle at the surface above its start point (it then
    dives straight down). Their error is a per-dive constant (``gps_bias_sigma_m`` per axis: multipath, the
    constellation) plus white noise (``gps_noise_m``); each fix states the covariance of both, as a receiver's
    reported accuracy would. ``usbl_rate_hz`` > 0 adds USBL fixes during the dive (white, ``usbl_noise_m`` per
    horizontal axis). The world frame is local NED about (``origin_latitude_deg``, ``origin_longitude_deg``)."""

    gps_count: int = 0
    gps_rate_hz: float = 1.0
    gps_before_start_s: float = 5.0
    gps_bias_sigma_m: float = 2.0
    gps_noise_m: float = 0.5
    usbl_rate_hz: float = 0.0
    usbl_noise_m: float = 0.3
    origin_latitude_deg: float = 41.9785
    origin_longitude_deg: float = 2.8053

    def __post_init__(self) -> None:
        _check(self, positive=("gps_rate_hz", "gps_before_start_s"),
               nonneg=("gps_bias_sigma_m", "gps_noise_m", "usbl_rate_hz", "usbl_noise_m"))
        if isinstance(self.gps_count, bool) or not isinstance(self.gps_count, int) or not 0 <= self.gps_count <= 3600:
            raise SimulationError(f"The 'gps_count' field of FixConfig must be an integer in [0, 3600]. Got "
                                  f"{self.gps_count!r} instead.")
        if self.gps_count and self.gps_bias_sigma_m ** 2 + self.gps_noise_m ** 2 <= 0:
            raise SimulationError("The GPS fixes of FixConfig need a non-zero error (gps_bias_sigma_m or gps_noise_m): "
                                  "a fix with a zero covariance cannot be fused.")
        if self.usbl_rate_hz and self.usbl_noise_m <= 0:
            raise SimulationError("The 'usbl_noise_m' field of FixConfig must be > 0 with USBL fixes.")
        _check(self, nonneg=())
        if not (-90 < self.origin_latitude_deg < 90 and -180 <= self.origin_longitude_deg <= 180):
            raise SimulationError("The origin of FixConfig must be a latitude in (-90, 90) and a longitude in "
                                  f"[-180, 180] (degrees). Got {self.origin_latitude_deg!r}, "
                                  f"{self.origin_longitude_deg!r} instead.")

    @property
    def any(self) -> bool:
        return self.gps_count > 0 or self.usbl_rate_hz > 0


@dataclass(frozen=True)
class SimulatorConfig(_Dict):
    """Everything :func:`semslam.simulation.simulate_dataset` needs (the seed is separate)."""

    world: WorldConfig = field(default_factory=WorldConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    scanner: ScannerConfig = field(default_factory=ScannerConfig)
    dvl: DvlConfig = field(default_factory=DvlConfig)
    ahrs: AhrsConfig = field(default_factory=AhrsConfig)
    depth: DepthConfig = field(default_factory=DepthConfig)
    fixes: FixConfig = field(default_factory=FixConfig)

    def __post_init__(self) -> None:
        for name, cls in _SUBCONFIGS.items():
            if not isinstance(getattr(self, name), cls):
                raise SimulationError(f"The {name!r} field of SimulatorConfig must be a {cls.__name__}. Got {type(getattr(self, name)).__name__} instead.")

    @classmethod
    def quick(cls) -> SimulatorConfig:
        """A small, fast configuration for tests and smoke runs: one loop, coarse scans (~10k rays)."""
        return cls(trajectory=TrajectoryConfig(loops=1), scanner=ScannerConfig(n_lines=100, points_per_line=100))

    def replace(self, **sections: Any) -> SimulatorConfig:
        """A copy with whole sections replaced, e.g. ``cfg.replace(dvl=DvlConfig(rate_hz=10))``."""
        return dataclasses.replace(self, **sections)


_SUBCONFIGS = {"world": WorldConfig, "trajectory": TrajectoryConfig, "scanner": ScannerConfig,
               "dvl": DvlConfig, "ahrs": AhrsConfig, "depth": DepthConfig, "fixes": FixConfig}
