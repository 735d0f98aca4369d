"""Sensor models of the filter: the attitude input (AHRS), the DVL and the depth sensor.

Each model takes its noise figures from the vehicle description and acts on the filter through its named
state blocks (:meth:`SemanticEkf.indices`); none knows where the data came from.
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from ..dataset import VehicleDescription
from ..errors import SlamError
from ..geometry import rotation_from_rpy
from . import _ekf_kernels as kern
from .association import GateThresholds
from .config import SlamConfig
from .ekf import SemanticEkf


class AttitudeInput:
    """The AHRS attitude as the filter's input, fed sample by sample in time order.

    Angles are unwrapped as they arrive (the same arithmetic as ``numpy.unwrap`` over the whole log) and
    linearly interpolated at any stamp covered by the samples (held beyond the ends). Old samples are dropped
    once the filter has passed them, so memory stays bounded on a dive of any length.
    """

    def __init__(self, sigma_rpy_rad, propagate_noise: bool = True) -> None:
        self._t: list[float] = []
        self._a: list[np.ndarray] = []
        self._raw_last: np.ndarray | None = None
        self._correction = np.zeros(3)
        self._var = np.diag(np.asarray(sigma_rpy_rad, dtype=float) ** 2)
        self.propagate_noise = propagate_noise

    def __len__(self) -> int:
        return len(self._t)

    @property
    def last_stamp_s(self) -> float:
        return self._t[-1] if self._t else -math.inf

    @property
    def first_stamp_s(self) -> float:
        return self._t[0] if self._t else math.inf

    def add(self, stamp_s: float, rpy_rad: np.ndarray) -> None:
        rpy = np.asarray(rpy_rad, dtype=float)
        if self._raw_last is not None:
            dd = rpy - self._raw_last
            ddmod = np.mod(dd + np.pi, 2 * np.pi) - np.pi
            ddmod[(ddmod == -np.pi) & (dd > 0)] = np.pi
            corr = ddmod - dd
            corr[np.abs(dd) < np.pi] = 0.0
            self._correction = self._correction + corr
        self._raw_last = rpy
        self._t.append(float(stamp_s))
        self._a.append(rpy + self._correction)

    def forget_before(self, stamp_s: float) -> None:
        """Drop samples no interpolation at or after ``stamp_s`` needs (keeps the one just before)."""
        i = bisect.bisect_left(self._t, stamp_s) - 1
        if i > 256:
            del self._t[:i]
            del self._a[:i]

    def at(self, t: float) -> tuple[np.ndarray, float]:
        """``(rpy, f)``: the interpolated attitude and the factor ``f = (1 - w)^2 + w^2`` by which the
        interpolation (weight ``w``) of two samples with independent white errors scales their variance."""
        ts, a = self._t, self._a
        if not ts:
            raise SlamError("The filter needs an attitude sample before any other measurement.")
        i = bisect.bisect_left(ts, t)
        if i == 0:
            return a[0].copy(), 1.0
        if i >= len(ts):
            return a[-1].copy(), 1.0
        t0, t1 = ts[i - 1], ts[i]
        if t1 <= t0:
            return a[i].copy(), 1.0
        w = (t - t0) / (t1 - t0)
        return a[i - 1] + w * (a[i] - a[i - 1]), (1.0 - w) ** 2 + w * w

    def cov_world(self, rpy: np.ndarray, var_factor: float = 1.0) -> np.ndarray | None:
        """World-frame rotation covariance (rad^2) of the attitude ``rpy`` (its white noise, scaled by
        ``var_factor`` for an interpolated attitude); None when attitude noise is not propagated."""
        if not self.propagate_noise:
            return None
        E = kern.rpy_to_world_rate(rpy)
        return E @ (self._var * var_factor) @ E.T


class SensorGate:
    """Chi-square gate of the navigation sensors with a lock-out guard: after ``max_rejections`` rejections
    in a row the filter, not the sensor, is wrong (an unmodelled acceleration), and the next one is accepted."""

    def __init__(self, cfg: SlamConfig) -> None:
        self.max_rejections = cfg.gating.sensor_gate_max_rejections
        self.threshold = {d: GateThresholds(cfg.gating.sensor_gate_probability).threshold(d) for d in (1, 2, 3)}
        self.rejections: dict[str, int] = {}


class DepthModel:
    """Pressure depth = world z, white noise from the vehicle description."""

    def __init__(self, vehicle: VehicleDescription) -> None:
        self.var = vehicle.depth.noise_m ** 2

    def update(self, ekf: SemanticEkf, gate: SensorGate, depth_m: float) -> dict:
        i = int(ekf.indices("position")[2])
        nu = np.array([depth_m - ekf.position_ned_m[2]])
        s = ekf.position_cov_m2[2, 2] + self.var
        d2 = float(nu[0] * nu[0] / s) if s > 0 else float("inf")
        thr = gate.threshold[1]
        ok = d2 <= thr
        n_rej = gate.rejections.get("depth", 0)
        forced = (not ok) and n_rej >= gate.max_rejections
        if ok or forced:
            ekf.update(np.array([i]), np.ones((1, 1)), nu, np.array([[self.var]]))
            gate.rejections["depth"] = 0
        else:
            gate.rejections["depth"] = n_rej + 1
        return dict(kind="depth", nis=d2, dof=1, threshold=thr, accepted=bool(ok or forced),
                    **({"reason": "gate_reset"} if forced else {}))


class PositionFixModel:
    """A horizontal position fix (GPS at the surface, USBL) = world north and east, with the fix's own stated
    covariance. Gated like the other navigation sensors, but never forced through after rejections in a row: a
    fix that jumps (a multipath GPS, a USBL outlier, a wrong origin) is rejected for as long as it disagrees, and
    the run's health verdict counts it."""

    def update(self, ekf: SemanticEkf, gate: SensorGate, position_ne_m: np.ndarray, cov_ne_m2: np.ndarray) -> dict:
        idx = ekf.indices("position")[0:2]
        nu = np.asarray(position_ne_m, dtype=float) - ekf.position_ned_m[0:2]
        S = ekf.position_cov_m2[0:2, 0:2] + cov_ne_m2
        try:
            d2 = float(nu @ np.linalg.solve(S, nu))
        except np.linalg.LinAlgError:
            d2 = float("inf")
        thr = gate.threshold[2]
        ok = bool(np.isfinite(d2) and d2 <= thr)
        if ok:
            ekf.update(np.asarray(idx), np.eye(2), nu, np.asarray(cov_ne_m2, dtype=float))
        return dict(kind="fix", nis=d2, dof=2, threshold=thr, accepted=ok)


class DvlModel:
    """DVL body velocity ``z = (1 + k) Rz(delta) v + b + s + n`` (calibration states when estimated).

    The white noise is ``noise_abs + noise_rel |v|``, times ``degraded_noise_factor`` while the bottom is not
    flat. Whether it is comes from the DVL's own beams: their bottom points (slant ranges along the beam
    directions, levelled with the attitude) must agree in depth within ``flat_bottom_tolerance_m``. Without
    beam ranges both hypotheses are tried (nominal, then degraded). The degraded-bottom bias is driven while the
    last beams said "not flat".
    """

    def __init__(self, vehicle: VehicleDescription, use_beam_ranges: bool = True) -> None:
        d = vehicle.dvl
        self.spec = d
        self.use_beams = use_beam_ranges
        self.R_vehicle_dvl = d.T_vehicle_dvl.rotation
        az = np.asarray(d.beam_azimuth_rad, dtype=float)
        sb, cb = math.sin(d.beam_angle_rad), math.cos(d.beam_angle_rad)
        beams_dvl = np.column_stack([sb * np.cos(az), sb * np.sin(az), np.full(len(az), cb)])
        self.beams_vehicle = beams_dvl @ self.R_vehicle_dvl.T  # (B, 3) unit directions in the vehicle frame
        #: the bottom under the beams is not flat (from the last DVL sample with every beam's range)
        self.degraded = False

    def bottom_flat(self, ranges_m: np.ndarray, R_world_vehicle: np.ndarray) -> bool | None:
        """Do the beams' bottom points lie on a level plane? None when a beam has no range."""
        r = np.asarray(ranges_m, dtype=float)
        if not self.use_beams or len(r) < 3 or not np.isfinite(r).all():
            return None
        z = (self.beams_vehicle * r[:, None]) @ R_world_vehicle[2]  # vertical drop to each bottom point
        return bool(np.max(np.abs(z - np.median(z))) <= self.spec.flat_bottom_tolerance_m)

    def body_velocity(self, v_dvl: np.ndarray) -> np.ndarray:
        return self.R_vehicle_dvl @ v_dvl

    def update(self, ekf: SemanticEkf, gate: SensorGate, z: np.ndarray, flat: bool | None) -> dict:
        d = self.spec
        speed = float(np.linalg.norm(z))
        if speed > d.max_speed_mps:
            return dict(kind="dvl", nis=float("nan"), dof=3, accepted=False, reason="max_speed")
        sigma = d.noise_abs_mps + d.noise_rel * speed
        if ekf.dvl_calibration:  # z = (1 + k) Rz(delta) v + b
            idx = np.concatenate([ekf.indices("velocity"), ekf.indices("dvl_calibration")])
            x = ekf.mean(idx)
            v, b, k, dl = x[0:3], x[3:6] + x[6:9], x[9], x[10]
            c, s_ = np.cos(dl), np.sin(dl)
            Rz = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
            dRz = np.array([[-s_, -c, 0.0], [c, -s_, 0.0], [0.0, 0.0, 0.0]])
            Hc = np.column_stack([(1.0 + k) * Rz, np.eye(3), np.eye(3), Rz @ v, (1.0 + k) * dRz @ v])
            nu = z - ((1.0 + k) * Rz @ v + b)
        else:
            idx, Hc = ekf.indices("velocity"), np.eye(3)
            nu = z - ekf.mean(idx)
        thr = gate.threshold[3]
        # two hypotheses, as the sensor is specified: nominal noise, or degraded (bottom not flat: noise x factor);
        # neither: an outlier, rejected. Several rejections in a row mean the *prediction* is wrong (an
        # unmodelled acceleration): inflate the velocity covariance by the innovation, then update (no lock-out)
        reason = ""
        hyps = (1.0, d.degraded_noise_factor ** 2)
        if flat is not None:  # the beams said which
            hyps = hyps[:1] if flat else hyps[1:]
        for f2 in hyps:
            Rn = np.eye(3) * sigma ** 2 * f2
            d2 = kern.mahalanobis2(nu, ekf.innovation_cov(idx, Hc, Rn))
            if d2 <= thr:
                reason = "nominal" if f2 == 1.0 else "degraded"
                break
        n_rej = gate.rejections.get("dvl", 0)
        if not reason and n_rej >= gate.max_rejections:
            ekf.inflate(ekf.indices("velocity"), np.diag(nu ** 2))
            Rn = np.eye(3) * sigma ** 2
            reason = "maneuver"
        if reason:
            ekf.update(idx, Hc, nu, Rn)
            gate.rejections["dvl"] = 0
        else:
            gate.rejections["dvl"] = n_rej + 1
        return dict(kind="dvl", nis=d2, dof=3, threshold=thr, accepted=bool(reason), reason=reason or "outlier")


def rotation_at(attitude: AttitudeInput, t: float) -> np.ndarray:
    return rotation_from_rpy(*attitude.at(t)[0])
