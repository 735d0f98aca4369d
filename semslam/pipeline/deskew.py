"""Motion compensation ("deskewing") of a scan taken while the vehicle moves.

A line or sweeping laser scanner takes each line at its own time; the vehicle moves between the first line and the
last (0.3 m/s over a 1/3 s scan: 10 cm), so a scan expressed in "the scanner frame" is in the frame of no single
moment: an object is stretched or squeezed along the track and no rigid model fits it (a 32 cm flange lost 11 % of
its points beyond the 6 mm verification radius). Deskewing carries every point into the scanner frame at one
reference stamp (the scan's end, when it is published) with the vehicle's own motion over the scan:

- rotation from the attitude (AHRS roll, pitch and yaw, interpolated; a constant heading bias cancels),
- translation from the DVL's bottom velocity, turned into the world by that attitude and integrated.

Both are the navigation sensors' raw data over a third of a second (dead reckoning over 0.33 s drifts by well under
a millimetre), never the SLAM estimate, so the detections stay independent of the filter they feed. A scan without
per-point stamps, or without attitude and a valid DVL velocity within :data:`MAX_NAV_GAP_S` of its span, is used
as it is (the caller counts it).

:class:`NavigationHistory` keeps the recent samples of a stream (:mod:`semslam.run`, the live node);
:func:`scan_motion` builds the motion over one scan from arrays (a dataset's logs); :func:`deskew_points` applies it.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..cloud import PointCloud
from ..geometry import RigidTransform, rotation_from_rpy, rpy_from_rotation

__all__ = ["MAX_NAV_GAP_S", "NavigationHistory", "ScanMotion", "deskew_points", "deskew_scan", "deskews",
           "reexpressed", "scan_motion", "scan_span", "sensor_motion_between"]

#: largest gap (s) between a scan's span and the nearest attitude / valid DVL sample for the scan to be deskewed
MAX_NAV_GAP_S = 1.0
#: the motion is sampled at least this often (s) over a scan
_STEP_S = 0.01
#: attitude and DVL samples within this time (s) of a scan's span are smoothed by a least-squares cubic in time: an
#: AHRS's sample-to-sample noise (the simulator's: 1 degree of yaw at 20 Hz) would otherwise turn a point at 2 m by
#: centimetres. Chosen on the seed-0 mission (26 scans, points against the truth's deskewing): interpolated samples
#: 11.1 mm median / 25.7 mm p90 error, 0.3 s quadratic 2.9 / 12.4, 0.5 s cubic 3.5 / 9.9 (the corners' 50 deg/s turns
#: are the rest), 1 s quadratic 6.6 / 28.6; not deskewed: 51 / 102 mm
SMOOTHING_WINDOW_S = 0.5
#: a turn starting or ending within the window (the rate steps: the simulator's corners go from 0 to ~54 deg/s at
#: once) is no cubic: a line with one kink, ``a + b t + c max(t - tau, 0)`` (as many parameters, tau on a grid), is
#: taken instead for a series where it leaves less than this share of the cubic's squared residuals. Chosen on the
#: unseen parts' seed-0 mission (70 scans, the largest rotation error over each scan against the truth's motion):
#: cubic 0.52 / 2.43 / 4.13 deg median / p90 / max, with the kink at 0.8: 0.43 / 0.79 / 1.47 (0.6: 0.48 / 0.86 /
#: 3.84); the demo's mission, held out: 0.48 / 1.72 / 4.28 -> 0.42 / 0.84 / 1.47
KINK_RSS_RATIO = 0.8
_KINK_KNOTS = 41  # candidate knots, evenly between the third sample and the third from last
_KINK_MIN_SAMPLES = 10


def _smooth(t: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Least-squares polynomial in time (cubic; lower with fewer than 8 samples) through ``values`` (n, k) at ``t``
    (n,), evaluated at ``at`` (m,); a column where a line with one kink fits far better takes that
    (:data:`KINK_RSS_RATIO`)."""
    deg = 3 if len(t) >= 8 else 2 if len(t) >= 6 else min(1, len(t) - 1)
    if deg == 0:
        return np.repeat(values[:1], len(at), axis=0)
    coef = np.polyfit(t, values, deg)
    out = np.stack([np.polyval(coef[:, k], at) for k in range(values.shape[1])], axis=1)
    if deg == 3 and len(t) >= _KINK_MIN_SAMPLES:
        fit = np.stack([np.polyval(coef[:, k], t) for k in range(values.shape[1])], axis=1)
        _kinked(t, values, at, ((fit - values) ** 2).sum(axis=0), out)
    return out


def _kinked(t: np.ndarray, values: np.ndarray, at: np.ndarray, rss_cubic: np.ndarray, out: np.ndarray) -> None:
    """Columns of ``out`` (the cubic at ``at``) replaced by the best line with one kink through ``values`` (n, k) at
    ``t`` where its squared residuals are below :data:`KINK_RSS_RATIO` times ``rss_cubic`` (k,). All knots at once:
    the 3x3 normal equations of every knot solved together."""
    ts = np.sort(t)
    taus = np.linspace(ts[2], ts[-3], _KINK_KNOTS)
    X = np.stack([np.ones((len(taus), len(t))), np.broadcast_to(t, (len(taus), len(t))),
                  np.maximum(t[None, :] - taus[:, None], 0.0)], axis=2)  # (K, n, 3)
    try:
        coef = np.linalg.solve(np.einsum("kni,knj->kij", X, X), np.einsum("kni,nc->kic", X, values))  # (K, 3, c)
    except np.linalg.LinAlgError:  # (samples at a few distinct stamps)
        return
    rss = ((np.einsum("kni,kic->knc", X, coef) - values[None]) ** 2).sum(axis=1)  # (K, c)
    best = np.argmin(rss, axis=0)
    for c in np.flatnonzero(rss[best, np.arange(values.shape[1])] < KINK_RSS_RATIO * rss_cubic):
        a, b, k = coef[best[c], :, c]
        out[:, c] = a + b * at + k * np.maximum(at - taus[best[c]], 0.0)


@dataclass(frozen=True)
class ScanMotion:
    """The vehicle's motion over a time window: at ``stamps_s`` (n,), increasing, its attitude
    ``R_world_vehicle`` (n, 3, 3) and position ``p_world_vehicle_m`` (n, 3) relative to the first sample (NED)."""

    stamps_s: np.ndarray
    R_world_vehicle: np.ndarray
    p_world_vehicle_m: np.ndarray


def _rotations_from_rpy(rpy: np.ndarray) -> np.ndarray:
    """(n, 3) roll, pitch, yaw -> (n, 3, 3) rotations (:func:`semslam.geometry.rotation_from_rpy`, vectorised)."""
    return np.moveaxis(rotation_from_rpy(rpy[:, 0], rpy[:, 1], rpy[:, 2]), -1, 0)


def scan_span(point_stamps_s: Any, end_stamp_s: float) -> tuple[float, float] | None:
    """``(first stamp, end stamp)`` of a scan with per-point stamps (None without a finite one)."""
    if point_stamps_s is None:
        return None
    st = np.asarray(point_stamps_s, dtype=float)
    finite = st[np.isfinite(st)]
    return (min(float(finite.min()), float(end_stamp_s)), float(end_stamp_s)) if len(finite) else None


def scan_motion(attitude_stamps_s: Any, rpy_rad: Any, dvl_stamps_s: Any, velocity_dvl_mps: Any, dvl_valid: Any,
                R_vehicle_dvl: Any, t0_s: float, t1_s: float, *, max_gap_s: float = MAX_NAV_GAP_S,
                lookahead_s: float = SMOOTHING_WINDOW_S) -> ScanMotion | None:
    """The vehicle's motion over ``[t0_s, t1_s]`` from attitude samples (stamps (n,), roll-pitch-yaw (n, 3)) and DVL
    samples (stamps (m,), velocities in the DVL frame (m, 3), validity (m,)): None when either has no sample within
    ``max_gap_s`` of both ends (valid DVL samples only). No sample later than ``t1_s + lookahead_s`` is used
    (``PipelineConfig.deskew_lookahead_s``: what a stream waits for after a scan's end)."""
    t0, t1 = float(t0_s), float(t1_s)
    if not (math.isfinite(t0) and math.isfinite(t1)) or t1 < t0:
        return None
    ta = np.asarray(attitude_stamps_s, dtype=float).reshape(-1)
    td = np.asarray(dvl_stamps_s, dtype=float).reshape(-1)
    valid = np.asarray(dvl_valid, dtype=bool).reshape(-1)
    v = np.asarray(velocity_dvl_mps, dtype=float).reshape(-1, 3)
    rpy = np.asarray(rpy_rad, dtype=float).reshape(-1, 3)
    ok_d = valid & np.isfinite(v).all(axis=1)
    ok_a = np.isfinite(rpy).all(axis=1)

    def window(t: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """The samples within the smoothing window of the span, on both sides (within the largest gap when it holds
        fewer than 4), never beyond ``lookahead_s`` after the end. A stream's runner and the live node wait for the
        navigation up to ``lookahead_s`` after a scan's end before they recognise it, so that they and a dataset's
        logs deskew a scan alike (a window ending at the scan's end was measured 3x worse: 11.5 mm median, 27 mm
        p90)."""
        sel = ok & (t >= t0 - SMOOTHING_WINDOW_S) & (t <= t1 + min(SMOOTHING_WINDOW_S, lookahead_s))
        if sel.sum() >= 4:
            return sel
        return ok & (t >= t0 - max_gap_s) & (t <= t1 + min(max_gap_s, lookahead_s))

    keep, near = window(td, ok_d), window(ta, ok_a)
    td, v, ta, rpy = td[keep], v[keep], ta[near], rpy[near]

    def covers(t: np.ndarray) -> bool:
        return bool(len(t)) and np.min(np.abs(t - t0)) <= max_gap_s and np.min(np.abs(t - t1)) <= max_gap_s

    if not covers(ta) or not covers(td):
        return None
    order = np.argsort(ta, kind="stable")
    ta, rpy = ta[order], np.unwrap(rpy[order], axis=0)
    n = max(2, int(math.ceil((t1 - t0) / _STEP_S)) + 1)
    grid = np.linspace(t0, t1, n)
    tm = 0.5 * (t0 + t1)
    R = _rotations_from_rpy(_smooth(ta - tm, rpy, grid - tm))
    od = np.argsort(td, kind="stable")
    v_body = v[od] @ np.asarray(R_vehicle_dvl, dtype=float).T
    v_world = np.einsum("nij,nj->ni", R, _smooth(td[od] - tm, v_body, grid - tm))
    dt = np.diff(grid)[:, None]
    p = np.vstack([np.zeros((1, 3)), np.cumsum(0.5 * (v_world[1:] + v_world[:-1]) * dt, axis=0)])
    return ScanMotion(grid, R, p)


def _vehicle_pose(motion: ScanMotion, t: float) -> np.ndarray:
    """T_world_vehicle (4x4, relative to the motion's first sample) at ``t`` (clamped), interpolated as the kernel
    interpolates it (rotation orthonormalised)."""
    st = motion.stamps_s
    t = float(np.clip(t, st[0], st[-1]))
    k = int(np.clip(np.searchsorted(st, t) - 1, 0, len(st) - 2))
    w = (t - st[k]) / (st[k + 1] - st[k])
    U, _, Vt = np.linalg.svd((1 - w) * motion.R_world_vehicle[k] + w * motion.R_world_vehicle[k + 1])
    T = np.eye(4)
    T[:3, :3] = U @ Vt
    T[:3, 3] = (1 - w) * motion.p_world_vehicle_m[k] + w * motion.p_world_vehicle_m[k + 1]
    return T


def sensor_motion_between(motion: ScanMotion, T_vehicle_sensor: Any, from_stamp_s: float,
                          to_stamp_s: float) -> np.ndarray:
    """``T_sensor(to)_sensor(from)`` (4x4): a point in the sensor frame at ``from_stamp_s`` into the sensor frame at
    ``to_stamp_s``, by the vehicle's motion."""
    T_vs = np.asarray(getattr(T_vehicle_sensor, "matrix", T_vehicle_sensor), dtype=float)
    T_w_from = _vehicle_pose(motion, from_stamp_s) @ T_vs
    T_w_to = _vehicle_pose(motion, to_stamp_s) @ T_vs
    return np.linalg.inv(T_w_to) @ T_w_from


def reexpressed(T_new_old: np.ndarray, T_old_object: np.ndarray,
                covariance_6x6: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An object pose and its covariance (x y z roll pitch yaw) carried from one sensor frame into another by the
    known ``T_new_old``: ``(T_new_object, covariance)``, the roll-pitch-yaw Jacobian by central differences."""
    T = T_new_old @ T_old_object
    R_a = T_new_old[:3, :3]
    rpy0 = rpy_from_rotation(T_old_object[:3, :3])
    J = np.zeros((3, 3))
    h = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        a = rpy_from_rotation(R_a @ _rot(rpy0 + d))
        b = rpy_from_rotation(R_a @ _rot(rpy0 - d))
        J[:, k] = (np.angle(np.exp(1j * (a - b)))) / (2 * h)
    G = np.zeros((6, 6))
    G[:3, :3], G[3:, 3:] = R_a, J
    out = G @ np.asarray(covariance_6x6, dtype=float) @ G.T
    return T, 0.5 * (out + out.T)


def _rot(rpy: np.ndarray) -> np.ndarray:
    return _rotations_from_rpy(np.asarray(rpy, dtype=float).reshape(1, 3))[0]


def deskew_points(points_xyz_m: Any, point_stamps_s: Any, motion: ScanMotion, T_vehicle_sensor: Any,
                  ref_stamp_s: float) -> np.ndarray:
    """Points (N, 3) taken in the sensor frame at their own stamps (N,), carried into the sensor frame at
    ``ref_stamp_s`` with ``motion`` (stamps outside it are clamped to its ends)."""
    from ._deskew_kernels import deskew_kernel

    T = np.asarray(getattr(T_vehicle_sensor, "matrix", T_vehicle_sensor), dtype=float)
    pts = np.ascontiguousarray(points_xyz_m, dtype=np.float64)
    st = np.ascontiguousarray(point_stamps_s, dtype=np.float64).reshape(-1)
    t = float(np.clip(ref_stamp_s, motion.stamps_s[0], motion.stamps_s[-1]))
    k = int(np.clip(np.searchsorted(motion.stamps_s, t) - 1, 0, len(motion.stamps_s) - 2))
    w = (t - motion.stamps_s[k]) / (motion.stamps_s[k + 1] - motion.stamps_s[k])
    R_ref = (1 - w) * motion.R_world_vehicle[k] + w * motion.R_world_vehicle[k + 1]
    U, _, Vt = np.linalg.svd(R_ref)
    p_ref = (1 - w) * motion.p_world_vehicle_m[k] + w * motion.p_world_vehicle_m[k + 1]
    out = np.empty_like(pts)
    deskew_kernel(pts, st, np.ascontiguousarray(motion.stamps_s), np.ascontiguousarray(motion.R_world_vehicle),
                  np.ascontiguousarray(motion.p_world_vehicle_m), np.ascontiguousarray(T[:3, :3]),
                  np.ascontiguousarray(T[:3, 3]), np.ascontiguousarray(U @ Vt), p_ref, out)
    return out


def deskew_scan(cloud: PointCloud, point_stamps_s: Any, motion: ScanMotion, T_vehicle_sensor: RigidTransform,
                ref_stamp_s: float) -> PointCloud:
    """``cloud`` (its per-point fields kept) with its points deskewed to ``ref_stamp_s`` (:func:`deskew_points`)."""
    pts = deskew_points(cloud.points_xyz_m, point_stamps_s, motion, T_vehicle_sensor, ref_stamp_s)
    return PointCloud(pts, intensity=cloud.intensity, viewpoint_xyz_m=cloud.viewpoint_xyz_m, frame_id=cloud.frame_id,
                      fields=cloud.fields)


def deskew_lookahead_s(recognizer: Any) -> float:
    """The navigation a stream waits for after a scan's end before ``recognizer`` deskews it
    (``PipelineConfig.deskew_lookahead_s``; the smoothing window's half for an object without that setting)."""
    return float(getattr(getattr(recognizer, "config", None), "deskew_lookahead_s", SMOOTHING_WINDOW_S))


def deskews(recognizer: Any, point_stamps_s: Any) -> bool:
    """Is a scan with these per-point stamps deskewed by ``recognizer`` (a :class:`~semslam.pipeline.ScanRecognizer`,
    or any object with a ``config``)? It needs stamps and ``PipelineConfig.deskew``."""
    return point_stamps_s is not None and len(point_stamps_s) > 0 and \
        bool(getattr(getattr(recognizer, "config", None), "deskew", False))


class NavigationHistory:
    """The recent attitude and DVL samples of a stream (kept ``memory_s``), for the scans' up and their deskewing."""

    def __init__(self, memory_s: float = 5.0) -> None:
        self.memory_s = float(memory_s)
        self.attitude: deque = deque()  # (stamp, rpy (3,))
        self.dvl: deque = deque()       # (stamp, velocity (3,), valid)

    def add_attitude(self, stamp_s: float, rpy_rad: Any) -> None:
        self.attitude.append((float(stamp_s), rpy_rad))
        while self.attitude and self.attitude[0][0] < stamp_s - self.memory_s:
            self.attitude.popleft()

    def add_dvl(self, stamp_s: float, velocity_mps: Any, valid: bool) -> None:
        self.dvl.append((float(stamp_s), velocity_mps, bool(valid)))
        while self.dvl and self.dvl[0][0] < stamp_s - self.memory_s:
            self.dvl.popleft()

    def copy(self) -> "NavigationHistory":
        """The samples held now, apart from those that come later (another thread's, :mod:`semslam.run.ros1`)."""
        out = NavigationHistory(self.memory_s)
        out.attitude, out.dvl = deque(self.attitude), deque(self.dvl)
        return out

    def attitude_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.attitude:
            return np.zeros(0), np.zeros((0, 3))
        ts, rpy = zip(*self.attitude)
        return np.array(ts), np.array(rpy, dtype=float).reshape(-1, 3)

    def scan_motion(self, R_vehicle_dvl: Any, point_stamps_s: Any, end_stamp_s: float, *,
                    lookahead_s: float = SMOOTHING_WINDOW_S) -> ScanMotion | None:
        """The motion over a scan (:func:`scan_span`) from the samples held; None without stamps or navigation."""
        span = scan_span(point_stamps_s, end_stamp_s)
        return None if span is None else self.motion(R_vehicle_dvl, *span, lookahead_s=lookahead_s)

    def motion(self, R_vehicle_dvl: Any, t0_s: float, t1_s: float, *,
               lookahead_s: float = SMOOTHING_WINDOW_S) -> ScanMotion | None:
        """:func:`scan_motion` over ``[t0_s, t1_s]`` from the samples held."""
        if not self.attitude or not self.dvl:
            return None
        ta, rpy = self.attitude_arrays()
        td, v, ok = zip(*self.dvl)
        return scan_motion(ta, rpy, np.array(td), np.array(v, dtype=float).reshape(-1, 3), np.array(ok),
                           R_vehicle_dvl, t0_s, t1_s, lookahead_s=lookahead_s)
