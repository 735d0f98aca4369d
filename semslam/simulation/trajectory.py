"""Vehicle motion: a Girona 500-like flight around a closed square with rounded corners.

The path is analytic (straight edges joined by circular arcs), flown ``loops`` times at ``speed_mps``
with a linear speed ramp at both ends. Yaw follows the path heading; roll and pitch are small sums of
sinusoids; the altitude above the flat floor oscillates slowly. Everything is evaluated in closed form
at any stamp, so every sensor samples the same truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SimulationError
from ..geometry import rotations_from_rpy
from .config import TrajectoryConfig

#: surge-speed wander: sinusoids (period s, relative amplitude), scaled to ``speed_wander_mps`` rms
_WANDER_PERIODS_S = np.array([11.3, 6.7, 4.1])
_WANDER_WEIGHTS = np.array([0.7, 0.5, 0.35])
#: crab (heading minus course): sinusoids (period s, relative amplitude), scaled to ``crab_rms_rad`` rms
_CRAB_PERIODS_S = np.array([9.7, 5.3])
_CRAB_WEIGHTS = np.array([0.8, 0.45])


def _sines(t: np.ndarray, periods: np.ndarray, weights: np.ndarray, phases: np.ndarray, rms: float):
    """``f(t) = sum a_i sin(w_i t + phi_i)`` with ``rms(f) = rms`` and its antiderivative ``F`` (F(t) =
    -sum a_i / w_i cos(.)): (f, F)."""
    w = 2 * np.pi / periods
    a = weights * rms / np.sqrt(np.sum(weights**2) / 2)
    arg = w[None, :] * t[:, None] + phases[None, :]
    return np.sin(arg) @ a, -(np.cos(arg) @ (a / w))


@dataclass(frozen=True, eq=False)
class TrajectorySample:
    """Vehicle truth at ``stamp_s`` (N,): position NED (N, 3) m, roll-pitch-yaw (N, 3) rad, body-frame
    velocity (N, 3) m/s, world-frame velocity (N, 3) m/s."""

    stamp_s: np.ndarray
    position_ned_m: np.ndarray
    rpy_rad: np.ndarray
    velocity_body_mps: np.ndarray
    velocity_ned_mps: np.ndarray

    def T_world_vehicle(self) -> np.ndarray:
        """(N, 4, 4) homogeneous transforms."""
        T = np.broadcast_to(np.eye(4), (len(self.stamp_s), 4, 4)).copy()
        T[:, :3, :3] = rotations_from_rpy(self.rpy_rad)
        T[:, :3, 3] = self.position_ned_m
        return T


class Trajectory:
    """The flight through ``corners_ne_m`` (K, 2), a closed polygon visited in order.

    Parameters
    ----------
    corners_ne_m : array (K, 2)
        Horizontal corners (north, east), metres; K >= 3, convex, in flight order.
    floor_depth_m : float
        Depth of the flat floor; the vehicle flies at ``floor_depth_m - altitude``.
    config : TrajectoryConfig
    seed : int or Generator
        Draws the phases of the attitude and altitude oscillations.
    """

    def __init__(self, corners_ne_m, floor_depth_m: float, config: TrajectoryConfig, *, seed=0):
        from .._validation import as_rng

        c = np.asarray(corners_ne_m, dtype=float)
        if c.ndim != 2 or c.shape[1] != 2 or len(c) < 3:
            raise SimulationError(
                f"The 'corners_ne_m' argument of Trajectory must have shape (K >= 3, 2). Got {c.shape} instead."
            )
        self.config = config
        self.floor_depth_m = float(floor_depth_m)
        rng = as_rng(seed, caller="Trajectory")
        self._phase = rng.uniform(0, 2 * np.pi, 5)
        # teleoperation: surge-speed wander and crab (drawn after the attitude phases, which keep their values)
        self._wander_phase = rng.uniform(0, 2 * np.pi, len(_WANDER_PERIODS_S))
        self._crab_phase = rng.uniform(0, 2 * np.pi, len(_CRAB_PERIODS_S))
        self._build_path(c, config.corner_radius_m)
        self.length_m = config.loops * self.perimeter_m
        ramp = config.start_ramp_s
        self.duration_s = self.length_m / config.speed_mps + ramp  # two half-ramps cost ramp seconds in total

    # -- path geometry -------------------------------------------------------------------------
    def _build_path(self, c: np.ndarray, radius: float) -> None:
        k = len(c)
        edges = np.roll(c, -1, axis=0) - c
        lengths = np.linalg.norm(edges, axis=1)
        dirs = edges / lengths[:, None]
        # turn at corner i+1 between edge i and edge i+1
        nxt = np.roll(dirs, -1, axis=0)
        turn = np.arctan2(dirs[:, 0] * nxt[:, 1] - dirs[:, 1] * nxt[:, 0], np.sum(dirs * nxt, axis=1))
        cut = radius * np.tan(np.abs(turn) / 2)  # tangent length at each corner
        cut_prev = np.roll(cut, 1)
        if np.any(cut + cut_prev >= lengths):
            raise SimulationError(
                f"The 'corner_radius_m' of TrajectoryConfig ({radius}) is too large for edges of {lengths.min():.2f} m."
            )
        segs = []  # (kind, start_s, length, data)
        s = 0.0
        for i in range(k):
            p0 = c[i] + dirs[i] * cut_prev[i]
            seg_len = lengths[i] - cut_prev[i] - cut[i]
            segs.append(("line", s, seg_len, (p0, dirs[i])))
            s += seg_len
            arc_len = radius * abs(turn[i])
            if arc_len > 0:
                start = c[i] + dirs[i] * (lengths[i] - cut[i])
                sign = np.sign(turn[i])
                normal = sign * np.array([-dirs[i][1], dirs[i][0]])  # towards the arc centre
                segs.append(("arc", s, arc_len, (start + normal * radius, radius, dirs[i], sign)))
                s += arc_len
        self._segs = segs
        self.perimeter_m = s
        self._starts = np.array([seg[1] for seg in segs])

    def _path(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position (N, 2), unit tangent (N, 2) and heading in [-pi, pi] (N,) at arc length ``s``."""
        s_loop = np.mod(s, self.perimeter_m)
        idx = np.clip(np.searchsorted(self._starts, s_loop, side="right") - 1, 0, len(self._segs) - 1)
        pos = np.empty((len(s), 2))
        tan = np.empty((len(s), 2))
        for j, (kind, start, _length, data) in enumerate(self._segs):  # loop over a handful of segments
            m = idx == j
            if not m.any():
                continue
            u = s_loop[m] - start
            if kind == "line":
                p0, d = data
                pos[m] = p0 + u[:, None] * d
                tan[m] = d
            else:
                centre, r, d0, sign = data
                a = sign * u / r  # rotation of the tangent
                ca, sa = np.cos(a), np.sin(a)
                t = np.column_stack([ca * d0[0] - sa * d0[1], sa * d0[0] + ca * d0[1]])
                n = sign * np.column_stack([-t[:, 1], t[:, 0]])
                pos[m] = centre - n * r
                tan[m] = t
        return pos, tan, np.arctan2(tan[:, 1], tan[:, 0])

    # -- motion --------------------------------------------------------------------------------
    def _envelope(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``g(t)``, 0 at rest and 1 in cruise, and its derivative: the smoothstep ``3e^2 - 2e^3`` of the
        ramp ``e = v_nominal / speed``, so that ``g`` and ``g'`` are continuous (no jump in speed)."""
        Ta, T = self.config.start_ramp_s, self.duration_s
        if Ta == 0:
            return np.ones_like(t), np.zeros_like(t)
        up, down = t < Ta, t > T - Ta
        e = np.where(up, t / Ta, np.where(down, (T - t) / Ta, 1.0))
        de = np.where(up, 1.0 / Ta, np.where(down, -1.0 / Ta, 0.0))
        return e * e * (3 - 2 * e), 6 * e * (1 - e) * de

    def _arc_length(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arc length s(t) and speed v(t): linear ramp up over ``start_ramp_s``, cruise, ramp down, plus
        the speed wander ``g(t) ds(t)`` (``ds`` the wander's displacement, ``g`` the ramp envelope): it
        vanishes, with its derivative, at both ends, so the flight still starts and stops at rest."""
        cfg = self.config
        V, Ta, T = cfg.speed_mps, cfg.start_ramp_s, self.duration_s
        t = np.clip(t, 0.0, T)
        if Ta == 0:
            s, v = V * t, np.full_like(t, V)
        else:
            up, down = t < Ta, t > T - Ta
            s = np.where(up, V * t**2 / (2 * Ta), V * (t - Ta / 2))
            v = np.where(up, V * t / Ta, V)
            td = T - t
            s = np.where(down, self.length_m - V * td**2 / (2 * Ta), s)
            v = np.where(down, V * td / Ta, v)
        if cfg.speed_wander_mps > 0:
            dv, ds = _sines(t, _WANDER_PERIODS_S, _WANDER_WEIGHTS, self._wander_phase, cfg.speed_wander_mps)
            ds = (
                ds
                - _sines(np.zeros(1), _WANDER_PERIODS_S, _WANDER_WEIGHTS, self._wander_phase, cfg.speed_wander_mps)[1]
            )
            g, dg = self._envelope(t)
            s = s + g * ds
            v = v + dg * ds + g * dv
        return s, v

    def crab_rad(self, t: np.ndarray) -> np.ndarray:
        """Heading minus course (rad) at ``t``: the teleoperated vehicle's crab, faded with the ramps."""
        cfg = self.config
        t = np.clip(t, 0.0, self.duration_s)
        if cfg.crab_rms_rad == 0:
            return np.zeros_like(t)
        return self._envelope(t)[0] * _sines(t, _CRAB_PERIODS_S, _CRAB_WEIGHTS, self._crab_phase, cfg.crab_rms_rad)[0]

    def sample(self, stamp_s) -> TrajectorySample:
        """Vehicle truth at the given stamps (seconds from the mission start, clamped to the flight)."""
        t = np.atleast_1d(np.asarray(stamp_s, dtype=float))
        cfg, ph = self.config, self._phase
        s, v = self._arc_length(t)
        pos2, tan2, yaw = self._path(s)
        if cfg.crab_rms_rad > 0:
            heading = yaw + self.crab_rad(t)
            yaw = np.arctan2(np.sin(heading), np.cos(heading))
        w_alt = 2 * np.pi / 20.0
        alt = cfg.altitude_m + cfg.altitude_wave_m * np.sin(w_alt * t + ph[0])
        dalt = cfg.altitude_wave_m * w_alt * np.cos(w_alt * t + ph[0])
        z = self.floor_depth_m - alt
        w1, w2, w3, w4 = 2 * np.pi / 6.3, 2 * np.pi / 2.3, 2 * np.pi / 7.9, 2 * np.pi / 3.1
        roll = cfg.roll_amplitude_rad * (0.8 * np.sin(w1 * t + ph[1]) + 0.2 * np.sin(w2 * t + ph[2]))
        pitch = cfg.pitch_amplitude_rad * (0.8 * np.sin(w3 * t + ph[3]) + 0.2 * np.sin(w4 * t + ph[4]))
        vel_ned = np.column_stack([tan2 * v[:, None], -dalt])
        rpy = np.column_stack([roll, pitch, yaw])
        R = rotations_from_rpy(rpy)
        vel_body = np.einsum("nji,nj->ni", R, vel_ned)  # R^T v
        return TrajectorySample(t, np.column_stack([pos2, z]), rpy, vel_body, vel_ned)
