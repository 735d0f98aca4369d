"""Typed, validated sensor logs of a dive, independent of where they came from (a simulator, a mission
directory, a ROS bag, numpy arrays).

All stamps are seconds (float64) on one clock, finite and non-decreasing within a log; arrays are validated
on construction and a bad one raises :class:`~semslam.errors.DatasetError` naming the log, the argument and
the problem. Frames: world NED; vehicle body x forward / y starboard / z down; roll-pitch-yaw are Z-Y-X
(``R_world_vehicle = Rz(yaw) Ry(pitch) Rx(roll)``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validation import as_float_array
from ..errors import DatasetError
from ..geometry import RigidTransform


def check_stamps(name: str, value: Any, caller: str) -> np.ndarray:
    """``value`` as a float64 (N,) array of finite, non-decreasing stamps (s), else :class:`DatasetError`."""
    t = as_float_array(name, value, (None,), caller=caller, error=DatasetError, finite=False)
    bad = np.flatnonzero(~np.isfinite(t))
    if len(bad):
        raise DatasetError(
            f"The {name!r} argument of {caller} must hold finite stamps (s). Got {float(t[bad[0]])!r} at "
            f"row {int(bad[0])} instead."
        )
    if len(t) > 1:
        step = np.diff(t)
        back = np.flatnonzero(step < 0)
        if len(back):
            k = int(back[0]) + 1
            raise DatasetError(
                f"The {name!r} argument of {caller} must be sorted (non-decreasing). Got {float(t[k])!r} "
                f"after {float(t[k - 1])!r} at row {k} instead."
            )
    return t


def _rows(name: str, value: Any, n: int, width: int | None, caller: str, finite: bool = True) -> np.ndarray:
    shape = (n,) if width is None else (n, width)
    return as_float_array(name, value, shape, caller=caller, error=DatasetError, finite=finite)


@dataclass(frozen=True, eq=False)
class DvlLog:
    """DVL bottom-lock velocities in the DVL frame (the vehicle body frame unless the vehicle description
    gives ``T_vehicle_dvl``). ``valid`` is False for a dropout (no lock); the velocity of an invalid row is
    NaN. ``beam_range_m`` (N, B), optional: the slant range of each beam to the bottom (NaN where a beam has
    no return), in the order of the vehicle description's beam azimuths; the filter uses it to tell a flat
    bottom from a slope, as a real DVL's per-beam data allow."""

    stamp_s: np.ndarray
    velocity_body_mps: np.ndarray
    valid: np.ndarray
    beam_range_m: np.ndarray | None = None

    def __post_init__(self) -> None:
        t = check_stamps("stamp_s", self.stamp_s, "DvlLog")
        object.__setattr__(self, "stamp_s", t)
        v = _rows("velocity_body_mps", self.velocity_body_mps, len(t), 3, "DvlLog", finite=False)
        object.__setattr__(self, "velocity_body_mps", v)
        raw = np.asarray(self.valid)
        if raw.shape != t.shape:
            raise DatasetError(f"The 'valid' argument of DvlLog must have shape {t.shape}. Got {raw.shape} instead.")
        if raw.dtype != bool:
            if raw.dtype.kind not in "iuf" or not np.isin(raw, (0, 1)).all():
                raise DatasetError("The 'valid' argument of DvlLog must hold booleans or 0/1. Got values "
                                   f"{np.unique(raw)[:5].tolist()} instead.")
        valid = raw.astype(bool)
        bad = np.flatnonzero(valid & ~np.isfinite(v).all(axis=1))
        if len(bad):
            raise DatasetError(f"The 'velocity_body_mps' argument of DvlLog must be finite on every valid row. Got "
                               f"{v[bad[0]].tolist()} at row {int(bad[0])} instead.")
        object.__setattr__(self, "valid", valid)
        if self.beam_range_m is not None:
            r = as_float_array("beam_range_m", self.beam_range_m, (len(t), None), caller="DvlLog", error=DatasetError,
                               finite=False)
            if np.any(r[np.isfinite(r)] <= 0) or np.isinf(r).any():
                raise DatasetError("The 'beam_range_m' argument of DvlLog must hold ranges > 0 (m) or NaN.")
            object.__setattr__(self, "beam_range_m", r)

    def __len__(self) -> int:
        return len(self.stamp_s)


@dataclass(frozen=True, eq=False)
class AttitudeLog:
    """Attitude of the vehicle in the world NED frame (AHRS or IMU orientation): roll, pitch, yaw (rad)."""

    stamp_s: np.ndarray
    rpy_rad: np.ndarray

    def __post_init__(self) -> None:
        t = check_stamps("stamp_s", self.stamp_s, "AttitudeLog")
        object.__setattr__(self, "stamp_s", t)
        object.__setattr__(self, "rpy_rad", _rows("rpy_rad", self.rpy_rad, len(t), 3, "AttitudeLog"))

    def __len__(self) -> int:
        return len(self.stamp_s)


#: The AHRS is the attitude source of a Girona 500-class vehicle; the former name of :class:`AttitudeLog`.


@dataclass(frozen=True, eq=False)
class DepthLog:
    """Pressure-sensor depth (metres, positive down = world z)."""

    stamp_s: np.ndarray
    depth_m: np.ndarray

    def __post_init__(self) -> None:
        t = check_stamps("stamp_s", self.stamp_s, "DepthLog")
        object.__setattr__(self, "stamp_s", t)
        object.__setattr__(self, "depth_m", _rows("depth_m", self.depth_m, len(t), None, "DepthLog"))

    def __len__(self) -> int:
        return len(self.stamp_s)


@dataclass(frozen=True, eq=False)
class PositionFixLog:
    """Horizontal position fixes of the vehicle in the world NED frame: GPS at the surface, USBL during the dive.
    ``position_ne_m`` (N, 2) north, east (m) about the dataset's geodetic origin; ``covariance_ne_m2`` (N, 2, 2)
    their stated covariance (what the receiver reports, or the user's figure); ``source`` (N,) a label per fix
    (``"gps"``, ``"usbl"``). The vertical comes from the pressure sensor, never from a fix."""

    stamp_s: np.ndarray
    position_ne_m: np.ndarray
    covariance_ne_m2: np.ndarray
    source: tuple = ()

    def __post_init__(self) -> None:
        t = check_stamps("stamp_s", self.stamp_s, "PositionFixLog")
        n = len(t)
        object.__setattr__(self, "stamp_s", t)
        p = _rows("position_ne_m", self.position_ne_m, n, 2, "PositionFixLog", finite=False)
        object.__setattr__(self, "position_ne_m", p)
        c = as_float_array("covariance_ne_m2", self.covariance_ne_m2, (n, 2, 2), caller="PositionFixLog",
                           error=DatasetError, finite=False)
        object.__setattr__(self, "covariance_ne_m2", c)
        src = tuple(str(x) for x in self.source) if len(self.source) else ("gps",) * n
        if len(src) != n:
            raise DatasetError(f"The 'source' argument of PositionFixLog must have {n} labels. Got {len(src)} instead.")
        object.__setattr__(self, "source", src)

    def __len__(self) -> int:
        return len(self.stamp_s)

    def usable(self) -> np.ndarray:
        """(N,) bool: a finite position and a finite, symmetric positive-definite covariance. A fix that is not
        usable is skipped by the filter and counted (a receiver without a solution reports NaN)."""
        ok = np.isfinite(self.position_ne_m).all(axis=1) & np.isfinite(self.covariance_ne_m2).all(axis=(1, 2))
        c = np.where(ok[:, None, None], self.covariance_ne_m2, np.eye(2))
        sym = np.abs(c[:, 0, 1] - c[:, 1, 0]) <= 1e-9 * (np.abs(c[:, 0, 0]) + np.abs(c[:, 1, 1]) + 1e-300)
        pd = (c[:, 0, 0] > 0) & (c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] * c[:, 1, 0] > 0)
        return ok & sym & pd


@dataclass(frozen=True, eq=False)
class VehicleTruth:
    """Ground-truth vehicle state: position in world NED, attitude, body-frame velocity (at least 2 rows,
    since metrics interpolate it)."""

    stamp_s: np.ndarray
    position_ned_m: np.ndarray
    rpy_rad: np.ndarray
    velocity_body_mps: np.ndarray

    def __post_init__(self) -> None:
        t = check_stamps("stamp_s", self.stamp_s, "VehicleTruth")
        n = len(t)
        if n < 2:
            raise DatasetError(f"The 'stamp_s' argument of VehicleTruth must have at least 2 rows (a trajectory). "
                               f"Got {n} instead.")
        object.__setattr__(self, "stamp_s", t)
        object.__setattr__(self, "position_ned_m", _rows("position_ned_m", self.position_ned_m, n, 3, "VehicleTruth"))
        object.__setattr__(self, "rpy_rad", _rows("rpy_rad", self.rpy_rad, n, 3, "VehicleTruth"))
        object.__setattr__(
            self, "velocity_body_mps", _rows("velocity_body_mps", self.velocity_body_mps, n, 3, "VehicleTruth")
        )

    def interpolate_position(self, stamp_s: Any) -> np.ndarray:
        """Linearly interpolated true position(s) at ``stamp_s`` (clamped to the log's span)."""
        t = np.atleast_1d(np.asarray(stamp_s, dtype=float))
        return np.stack([np.interp(t, self.stamp_s, self.position_ned_m[:, i]) for i in range(3)], axis=-1)

    def T_world_vehicle_at(self, stamp_s: float) -> RigidTransform:
        """True vehicle pose at ``stamp_s``: interpolated position, the nearest sample's attitude."""
        i = int(np.clip(np.searchsorted(self.stamp_s, stamp_s), 0, len(self.stamp_s) - 1))
        return RigidTransform.from_xyz_rpy(self.interpolate_position(stamp_s)[0], self.rpy_rad[i])


@dataclass(frozen=True, eq=False)
class ObjectTruth:
    """A placed object: its name (unique in the world), class label, and true pose in the world frame.
    Clutter (not in the database) has ``in_database = False``."""

    name: str
    label: str
    T_world_object: RigidTransform
    in_database: bool = True


@dataclass(frozen=True, eq=False)
class ScanRecord:
    """One laser scan: its id, acquisition span, and its point-cloud path relative to the dataset directory.
    Each point is in the scanner frame at its own line's stamp (see :meth:`Dataset.point_stamps_s`)."""

    scan_id: int
    start_stamp_s: float
    end_stamp_s: float
    path: str
    n_points: int = -1

    def __post_init__(self) -> None:
        if (
            not (np.isfinite(self.start_stamp_s) and np.isfinite(self.end_stamp_s))
            or self.end_stamp_s < self.start_stamp_s
        ):
            raise DatasetError(f"Scan {self.scan_id}: 'end_stamp_s' must be finite and >= 'start_stamp_s'. Got "
                               f"{self.start_stamp_s} and {self.end_stamp_s} instead.")
