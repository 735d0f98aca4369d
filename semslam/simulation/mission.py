"""In-memory form of a mission: navigation sensor logs, scans, ground truth.

This is the contract between the simulator (which writes missions), the mission reader (which loads a
mission directory, see :mod:`semslam.simulation.mission_io`) and the filter (which consumes them). All
stamps are seconds (float64) on one mission clock; all arrays are validated on construction.

Frames: world NED; vehicle body x forward / y starboard / z down; ``T_vehicle_scanner`` maps scanner
points into the vehicle frame; roll-pitch-yaw are Z-Y-X (see :mod:`semslam.geometry`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._validation import as_float_array
from ..errors import MissionError
from ..geometry import RigidTransform


def _stamps(name: str, value: Any, caller: str) -> np.ndarray:
    t = as_float_array(name, value, (None,), caller=caller, error=MissionError)
    if len(t) > 1 and np.any(np.diff(t) < 0):
        raise MissionError(f"The {name!r} argument of {caller} must be sorted (non-decreasing). Got a decreasing step instead.")
    return t


def _rows(name: str, value: Any, n: int, width: int | None, caller: str, finite: bool = True) -> np.ndarray:
    shape = (n,) if width is None else (n, width)
    return as_float_array(name, value, shape, caller=caller, error=MissionError, finite=finite)


@dataclass(frozen=True, eq=False)
class DvlLog:
    """DVL bottom-lock velocities in the vehicle body frame. ``valid`` is False for a dropout (no lock);
    the velocity of an invalid row is NaN."""

    stamp_s: np.ndarray
    velocity_body_mps: np.ndarray
    valid: np.ndarray

    def __post_init__(self) -> None:
        t = _stamps("stamp_s", self.stamp_s, "DvlLog")
        object.__setattr__(self, "stamp_s", t)
        object.__setattr__(self, "velocity_body_mps", _rows("velocity_body_mps", self.velocity_body_mps, len(t), 3, "DvlLog", finite=False))
        valid = np.asarray(self.valid, dtype=bool)
        if valid.shape != t.shape:
            raise MissionError(f"The 'valid' argument of DvlLog must have shape {t.shape}. Got {valid.shape} instead.")
        if not np.isfinite(self.velocity_body_mps[valid]).all():
            raise MissionError("The 'velocity_body_mps' argument of DvlLog must be finite on every valid row.")
        object.__setattr__(self, "valid", valid)


@dataclass(frozen=True, eq=False)
class AhrsLog:
    """AHRS attitude (roll, pitch, yaw of the vehicle in the world NED frame), radians."""

    stamp_s: np.ndarray
    rpy_rad: np.ndarray

    def __post_init__(self) -> None:
        t = _stamps("stamp_s", self.stamp_s, "AhrsLog")
        object.__setattr__(self, "stamp_s", t)
        object.__setattr__(self, "rpy_rad", _rows("rpy_rad", self.rpy_rad, len(t), 3, "AhrsLog"))


@dataclass(frozen=True, eq=False)
class DepthLog:
    """Pressure-sensor depth (metres, positive down = world z)."""

    stamp_s: np.ndarray
    depth_m: np.ndarray

    def __post_init__(self) -> None:
        t = _stamps("stamp_s", self.stamp_s, "DepthLog")
        object.__setattr__(self, "stamp_s", t)
        object.__setattr__(self, "depth_m", _rows("depth_m", self.depth_m, len(t), None, "DepthLog"))


@dataclass(frozen=True, eq=False)
class VehicleTruth:
    """Ground-truth vehicle state: position in world NED, attitude, body-frame velocity."""

    stamp_s: np.ndarray
    position_ned_m: np.ndarray
    rpy_rad: np.ndarray
    velocity_body_mps: np.ndarray

    def __post_init__(self) -> None:
        t = _stamps("stamp_s", self.stamp_s, "VehicleTruth")
        n = len(t)
        object.__setattr__(self, "stamp_s", t)
        object.__setattr__(self, "position_ned_m", _rows("position_ned_m", self.position_ned_m, n, 3, "VehicleTruth"))
        object.__setattr__(self, "rpy_rad", _rows("rpy_rad", self.rpy_rad, n, 3, "VehicleTruth"))
        object.__setattr__(self, "velocity_body_mps", _rows("velocity_body_mps", self.velocity_body_mps, n, 3, "VehicleTruth"))

    def interpolate_position(self, stamp_s: Any) -> np.ndarray:
        """Linearly interpolated true position(s) at ``stamp_s`` (clamped to the log's span)."""
        t = np.atleast_1d(np.asarray(stamp_s, dtype=float))
        return np.stack([np.interp(t, self.stamp_s, self.position_ned_m[:, i]) for i in range(3)], axis=-1)


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
    """One laser scan: its id, acquisition span, and its PCD path relative to the mission directory.
    Points are in the scanner frame at ``end_stamp_s`` unless the mission says otherwise."""

    scan_id: int
    start_stamp_s: float
    end_stamp_s: float
    path: str
    n_points: int = -1

    def __post_init__(self) -> None:
        if not (np.isfinite(self.start_stamp_s) and np.isfinite(self.end_stamp_s)) or self.end_stamp_s < self.start_stamp_s:
            raise MissionError(
                f"Scan {self.scan_id}: 'end_stamp_s' must be >= 'start_stamp_s'. Got {self.start_stamp_s} and {self.end_stamp_s} instead."
            )


@dataclass(frozen=True, eq=False)
class Mission:
    """A whole mission. ``directory`` is where it was read from (None for an in-memory mission)."""

    config: dict
    T_vehicle_scanner: RigidTransform
    dvl: DvlLog
    ahrs: AhrsLog
    depth: DepthLog
    truth: VehicleTruth | None
    objects: list[ObjectTruth] = field(default_factory=list)
    scans: list[ScanRecord] = field(default_factory=list)
    directory: Path | None = None
    seed: int | None = None
    #: In-memory scans (scan_id -> PointCloud) of a simulated mission; None for a mission read from disk.
    scan_clouds: dict | None = None

    def load_scan(self, scan_id: int):
        """The cloud of scan ``scan_id``: from memory when the mission was simulated, else read from
        ``directory / record.path`` with :func:`semslam.io.read_point_cloud` (frame ``"scanner"``)."""
        if self.scan_clouds is not None and scan_id in self.scan_clouds:
            return self.scan_clouds[scan_id]
        record = next((s for s in self.scans if s.scan_id == scan_id), None)
        if record is None:
            raise MissionError(f"The 'scan_id' argument of Mission.load_scan must be one of the mission's scan ids. Got {scan_id!r} instead.")
        if self.directory is None:
            raise MissionError(f"Scan {scan_id} is not in memory and the mission has no directory to read it from.")
        from ..errors import PcdError
        from ..io import read_point_cloud

        path = Path(self.directory) / record.path
        try:
            return read_point_cloud(path, frame_id="scanner")
        except PcdError as exc:
            raise MissionError(f"Scan {scan_id} of the mission in {str(self.directory)!r} cannot be read: {exc}") from None

    @property
    def duration_s(self) -> float:
        stamps = [self.dvl.stamp_s, self.ahrs.stamp_s, self.depth.stamp_s]
        lo = min(float(s[0]) for s in stamps if len(s))
        hi = max(float(s[-1]) for s in stamps if len(s))
        return hi - lo
