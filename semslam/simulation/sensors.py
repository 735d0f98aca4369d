"""Navigation sensors: DVL (body velocity), AHRS (attitude), pressure depth. Each samples the
trajectory's closed-form truth at its own rate and adds its configured errors (see
:mod:`semslam.simulation.config` for the defaults and their sources)."""

from __future__ import annotations

import numpy as np

from ..geometry import rotations_from_rpy, wrap_angle
from .config import AhrsConfig, DepthConfig, DvlConfig, FixConfig, WorldConfig
from ..dataset import AttitudeLog, DepthLog, DvlLog, PositionFixLog
from .trajectory import Trajectory
from .world import floor_depth_m, over_slope

#: beam azimuths of the simulated Janus DVL in its (= the body) frame, degrees
DVL_BEAM_AZIMUTHS_DEG = (45.0, 135.0, 225.0, 315.0)


def sensor_stamps(rate_hz: float, duration_s: float) -> np.ndarray:
    """``k / rate_hz`` for every k with stamp <= ``duration_s`` (exact multiples, no drift)."""
    n = int(np.floor(duration_s * rate_hz + 1e-9)) + 1
    return np.arange(n) / rate_hz


def _beam_directions(position_ned_m: np.ndarray, rpy_rad: np.ndarray, beam_angle_rad: float) -> np.ndarray:
    """(N, 4, 3) world directions of the four Janus beams (azimuths 45 + k 90 degrees in the body frame)."""
    az = np.radians(DVL_BEAM_AZIMUTHS_DEG)
    beams_body = np.column_stack([np.sin(beam_angle_rad) * np.cos(az), np.sin(beam_angle_rad) * np.sin(az),
                                  np.full(4, np.cos(beam_angle_rad))])
    return np.einsum("nij,bj->nbi", rotations_from_rpy(rpy_rad), beams_body)


def dvl_beam_ranges(world: WorldConfig, position_ned_m: np.ndarray, rpy_rad: np.ndarray,
                    beam_angle_rad: float) -> np.ndarray:
    """(N, 4) slant range (m) of each beam to the tank's floor or sloped sides (bisection on the floor's
    height along the beam, to 0.1 mm): what a real DVL reports per beam."""
    beams = _beam_directions(position_ned_m, rpy_rad, beam_angle_rad)
    p = position_ned_m[:, None, :]
    down = np.maximum(beams[..., 2], 1e-3)
    hi = np.maximum((world.tank_depth_m - position_ned_m[:, 2])[:, None] / down, 0.0)  # to the flat floor plane
    lo = np.zeros_like(hi)
    for _ in range(40):  # the floor is never below the flat plane: the crossing lies in [0, hi]
        mid = 0.5 * (lo + hi)
        q = p + beams * mid[..., None]
        below = q[..., 2] >= floor_depth_m(world, q[..., 0], q[..., 1])
        hi = np.where(below, mid, hi)
        lo = np.where(below, lo, mid)
    return 0.5 * (lo + hi)


def dvl_beams_over_slope(
    world: WorldConfig, position_ned_m: np.ndarray, rpy_rad: np.ndarray, beam_angle_rad: float
) -> np.ndarray:
    """True where any of the four Janus beams (azimuths 45 + k 90 degrees in the body frame,
    ``beam_angle_rad`` from the body z axis) reaches the floor on a slope (flat-floor approximation)."""
    beams = _beam_directions(position_ned_m, rpy_rad, beam_angle_rad)
    down = np.maximum(beams[..., 2], 1e-3)
    altitude = floor_depth_m(world, position_ned_m[:, 0], position_ned_m[:, 1]) - position_ned_m[:, 2]
    reach = altitude[:, None] / down  # range to the flat floor plane
    feet = position_ned_m[:, None, :2] + beams[..., :2] * reach[..., None]
    return over_slope(world, feet[..., 0], feet[..., 1]).any(axis=1)


def gauss_markov(n: int, dt_s: float, sigma: float, tau_s: float, rng: np.random.Generator, dim: int = 3,
                 driven: np.ndarray | None = None) -> np.ndarray:
    """``n`` samples (n, dim) of a first-order Gauss-Markov process (std ``sigma``, correlation time
    ``tau_s``) sampled every ``dt_s``: ``b_k = a b_(k-1) + w_k``, ``a = exp(-dt/tau)``,
    ``w ~ N(0, sigma^2 (1 - a^2))``, ``b_0 ~ N(0, sigma^2)`` (exact discretisation, scipy lfilter).
    With ``driven`` (n,) bool the noise enters only where True (the process decays elsewhere) and
    ``b_0 = 0`` unless ``driven[0]``."""
    from scipy.signal import lfilter

    a = float(np.exp(-dt_s / tau_s))
    w = rng.normal(0.0, 1.0, (n, dim)) * sigma * np.sqrt(1.0 - a * a)
    w[0] = rng.normal(0.0, sigma, dim)
    if driven is not None:
        w[~np.asarray(driven, dtype=bool)] = 0.0
    return lfilter([1.0], [1.0, -a], w, axis=0)


def simulate_dvl(traj: Trajectory, world: WorldConfig, cfg: DvlConfig, rng: np.random.Generator) -> DvlLog:
    """DVL log: ``(1 + k) Rz(delta) v + b(t)`` + white noise (0.3 % |v| + 1 mm/s by default), worse over
    slopes, with outliers and dropouts (NaN rows, ``valid`` False). See :class:`DvlConfig`."""
    t = sensor_stamps(cfg.rate_hz, traj.duration_s)
    truth = traj.sample(t)
    v = truth.velocity_body_mps
    slope = dvl_beams_over_slope(world, truth.position_ned_m, truth.rpy_rad, cfg.beam_angle_rad)
    sigma = cfg.noise_rel * np.linalg.norm(v, axis=1) + cfg.noise_abs_mps
    sigma = np.where(slope, sigma * cfg.slope_noise_factor, sigma)
    noise = rng.normal(0.0, 1.0, v.shape) * sigma[:, None]
    p_out = np.where(slope, cfg.slope_outlier_prob, cfg.outlier_prob)
    outlier = rng.random(len(t)) < p_out
    spikes = rng.normal(0.0, cfg.outlier_std_mps, v.shape)
    p_drop = np.where(slope, cfg.slope_dropout_prob, cfg.dropout_prob)
    altitude = floor_depth_m(world, truth.position_ned_m[:, 0], truth.position_ned_m[:, 1]) - truth.position_ned_m[:, 2]
    valid = (rng.random(len(t)) >= p_drop) & (altitude <= cfg.max_altitude_m)
    # systematic errors (drawn after the white terms: a white-only config keeps its former draws)
    k, delta = rng.normal(0.0, 1.0, 2) * (cfg.scale_factor_sigma, cfg.misalignment_sigma_rad)
    bias = gauss_markov(len(t), 1.0 / cfg.rate_hz, cfg.bias_sigma_mps, cfg.bias_tau_s, rng)
    bias += gauss_markov(len(t), 1.0 / cfg.rate_hz, cfg.slope_bias_sigma_mps, cfg.slope_bias_tau_s, rng, driven=slope)
    c, s = np.cos(delta), np.sin(delta)
    v_sys = (1.0 + k) * np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]]) + bias
    meas = v_sys + noise + np.where(outlier[:, None], spikes, 0.0)
    meas[~valid] = np.nan
    # per-beam slant ranges (drawn last: the velocity draws are those of a DVL without range output)
    ranges = dvl_beam_ranges(world, truth.position_ned_m, truth.rpy_rad, cfg.beam_angle_rad)
    ranges = np.maximum(ranges + rng.normal(0.0, cfg.range_noise_m, ranges.shape), 1e-3)
    ranges[~valid] = np.nan
    return DvlLog(t, meas, valid, ranges)


def simulate_ahrs(traj: Trajectory, cfg: AhrsConfig, rng: np.random.Generator) -> AttitudeLog:
    """AHRS log: true roll, pitch, yaw + white noise + yaw bias (constant plus random walk), wrapped."""
    t = sensor_stamps(cfg.rate_hz, traj.duration_s)
    truth = traj.sample(t)
    noise = rng.normal(0.0, 1.0, (len(t), 3)) * np.asarray(cfg.noise_rpy_rad)
    walk_steps = rng.normal(0.0, 1.0, len(t)) * cfg.yaw_bias_walk_rad_per_sqrt_s * np.sqrt(1.0 / cfg.rate_hz)
    walk_steps[0] = 0.0
    bias = cfg.yaw_bias_rad + np.cumsum(walk_steps)
    rpy = truth.rpy_rad + noise
    rpy[:, 2] += bias
    return AttitudeLog(t, wrap_angle(rpy))


def simulate_depth(traj: Trajectory, cfg: DepthConfig, rng: np.random.Generator) -> DepthLog:
    """Pressure depth log: world z + white noise + constant bias."""
    t = sensor_stamps(cfg.rate_hz, traj.duration_s)
    z = traj.sample(t).position_ned_m[:, 2]
    return DepthLog(t, z + cfg.bias_m + rng.normal(0.0, cfg.noise_m, len(t)))


def simulate_fixes(traj: Trajectory, cfg: FixConfig, rng: np.random.Generator) -> PositionFixLog | None:
    """Surface GPS fixes before the dive (the vehicle above its start point: it then dives straight down) and
    USBL fixes during it, with the errors and stated covariances of :class:`FixConfig`."""
    t_parts, p_parts, c_parts, src = [], [], [], []
    start = traj.sample(np.array([0.0])).position_ned_m[0, 0:2]
    if cfg.gps_count:
        t = -cfg.gps_before_start_s - np.arange(cfg.gps_count)[::-1] / cfg.gps_rate_hz
        bias = rng.normal(0.0, cfg.gps_bias_sigma_m, 2)
        p = start + bias + rng.normal(0.0, cfg.gps_noise_m, (len(t), 2))
        var = cfg.gps_bias_sigma_m ** 2 + cfg.gps_noise_m ** 2
        t_parts.append(t)
        p_parts.append(p)
        c_parts.append(np.broadcast_to(np.eye(2) * var, (len(t), 2, 2)))
        src += ["gps"] * len(t)
    if cfg.usbl_rate_hz:
        t = sensor_stamps(cfg.usbl_rate_hz, traj.duration_s)
        p = traj.sample(t).position_ned_m[:, 0:2] + rng.normal(0.0, cfg.usbl_noise_m, (len(t), 2))
        t_parts.append(t)
        p_parts.append(p)
        c_parts.append(np.broadcast_to(np.eye(2) * cfg.usbl_noise_m ** 2, (len(t), 2, 2)))
        src += ["usbl"] * len(t)
    if not t_parts:
        return None
    return PositionFixLog(np.concatenate(t_parts), np.concatenate(p_parts), np.concatenate(c_parts), tuple(src))
