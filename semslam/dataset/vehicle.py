"""The vehicle description: what a navigator knows of its vehicle from the sensor data sheets and the
mounting, never from a particular dive. Read from a small human-written TOML file (units in the key names)::

    format_version = 1
    name = "girona500"

    [scanner]                       # the laser scanner
    xyz_m = [0.6, 0.0, 0.3]         # T_vehicle_scanner: translation (m) and Z-Y-X roll, pitch, yaw (rad) ...
    rpy_rad = [0.0, 0.0, 1.5708]    # ... or matrix = [[...], [...], [...], [...]] (4x4)
    line_count = 100                # lines per sweep: a point's line index gives its stamp
    camera_xyz_m = [0.3, 0.0, 0.0]  # a triangulation laser's camera, from the laser, scanner frame (optional)

    [dvl]
    noise_abs_mps = 0.001           # white noise per axis: noise_abs_mps + noise_rel * speed
    noise_rel = 0.003
    beam_angle_rad = 0.5236         # Janus beams, angle off the DVL's z axis

    [attitude]
    noise_rpy_rad = [0.0035, 0.0035, 0.0175]

    [depth]
    noise_m = 0.02

Every key is optional but the scanner's extrinsic (``scanner.xyz_m`` with ``scanner.rpy_rad``, or
``scanner.matrix``): a missing one was silently the identity, so a file without it (an empty file included) is
an error naming the key; write ``xyz_m = [0, 0, 0]`` for a scanner at the vehicle origin, or use the documented
defaults (:meth:`VehicleDescription.girona500`, ``--vehicle girona500``) instead of a file. An absent key takes
the Girona 500-class default (the values below, with their sources in :mod:`semslam.simulation.config`).
Unknown keys, wrong types, a non-rotation extrinsic, ``min_range_m >= max_range_m`` and values outside their
plausibility range (:data:`semslam.limits.LIMITS`, ``docs/limits.md``: millimetres in a ``_m`` key, degrees in
a ``_rad`` key, a zero DVL noise) raise :class:`~semslam.errors.DatasetError` naming the file and the key.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import atomic_write_text
from .._tables import read_table
from ..errors import DatasetError, SemslamError
from ..geometry import RigidTransform
from ..limits import check as check_limit

VEHICLE_FORMAT_VERSION = 1


@dataclass(frozen=True)
class ScannerSpec:
    """The laser scanner: mounting, line timing and the range it is trusted over."""

    T_vehicle_scanner: RigidTransform = field(default_factory=RigidTransform.identity)
    line_count: int = 0  #: lines per sweep (0: unknown, every point at the scan's end stamp)
    min_range_m: float = 0.3
    max_range_m: float = 4.0
    fov_rad: float = math.radians(50.0)  #: full cone about the optical axis where detections are expected
    rate_hz: float = 3.0
    #: the camera of a triangulation laser scanner, from the laser (the scanner frame's origin), in the scanner frame:
    #: a point is measured only where the camera sees the laser's spot. ``db build --vehicle`` renders the laser
    #: views with it (absent: the simulator's, 0.3 m along x); recognition may model its shadows
    #: (``PoseConfig.camera_offset_m``, opt-in). None: the key absent
    camera_xyz_m: tuple | None = None


@dataclass(frozen=True)
class DvlSpec:
    """The DVL's mounting, noise (white and calibration, data-sheet figures) and beam geometry."""

    T_vehicle_dvl: RigidTransform = field(default_factory=RigidTransform.identity)
    noise_abs_mps: float = 0.001
    noise_rel: float = 0.003
    max_speed_mps: float = 1.5
    #: white noise multiplier when the beams say the bottom is not flat (slopes, structures)
    degraded_noise_factor: float = 5.0
    scale_factor_sigma: float = 0.005
    misalignment_sigma_rad: float = math.radians(0.5)
    bias_sigma_mps: float = 0.003
    bias_tau_s: float = 20.0
    #: Gauss-Markov bias driven while the bottom is not flat
    degraded_bias_sigma_mps: float = 0.015
    degraded_bias_tau_s: float = 5.0
    beam_angle_rad: float = math.radians(30.0)
    beam_azimuth_rad: tuple = tuple(math.radians(a) for a in (45.0, 135.0, 225.0, 315.0))
    #: the beams' bottom points may differ in depth by this much on a flat bottom (range noise, attitude)
    flat_bottom_tolerance_m: float = 0.05


@dataclass(frozen=True)
class AttitudeSpec:
    """The AHRS: white noise per sample and the random walk of its yaw bias."""

    noise_rpy_rad: tuple = (math.radians(0.2), math.radians(0.2), math.radians(1.0))
    yaw_bias_walk_rad_per_sqrt_s: float = 0.0


@dataclass(frozen=True)
class DepthSpec:
    """The pressure sensor: white noise; water density and surface pressure for raw pressure readings."""

    noise_m: float = 0.02
    water_density_kg_m3: float = 1025.0
    atmospheric_pressure_pa: float = 101325.0


_SECTIONS = {"scanner": ScannerSpec, "dvl": DvlSpec, "attitude": AttitudeSpec, "depth": DepthSpec}
_TRANSFORMS = {"scanner": "T_vehicle_scanner", "dvl": "T_vehicle_dvl"}
#: the numbers' plausibility ranges: semslam.limits.LIMITS["vehicle.<section>.<key>"] (one table for all of semslam)
_EXTRINSIC_KEYS = ("xyz_m", "rpy_rad", "matrix")


@dataclass(frozen=True)
class VehicleDescription:
    """Mounting and sensor figures of a vehicle (see the module docstring for the file form)."""

    name: str = "girona500"
    scanner: ScannerSpec = field(default_factory=ScannerSpec)
    dvl: DvlSpec = field(default_factory=DvlSpec)
    attitude: AttitudeSpec = field(default_factory=AttitudeSpec)
    depth: DepthSpec = field(default_factory=DepthSpec)

    @classmethod
    def girona500(cls) -> "VehicleDescription":
        """Documented defaults for a Girona 500-class vehicle: a 1 mm/s + 0.3 % DVL (calibration to 0.5 % and
        0.5 deg, 3 mm/s bias), a 0.2/0.2/1.0 deg AHRS, 2 cm depth, the scanner looking down 0.3-4 m. With the
        scanner at the vehicle origin: give your own ``T_vehicle_scanner``."""
        return cls()

    @property
    def T_vehicle_scanner(self) -> RigidTransform:
        return self.scanner.T_vehicle_scanner

    def replace(self, **sections) -> "VehicleDescription":
        return replace(self, **sections)

    # -- dict / TOML ----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        out: dict = {"format_version": VEHICLE_FORMAT_VERSION, "name": self.name}
        for sec, cls in _SECTIONS.items():
            spec = getattr(self, sec)
            d: dict = {}
            for f in fields(cls):
                v = getattr(spec, f.name)
                if v is None:  # an optional key left out (TOML has no null)
                    continue
                if isinstance(v, RigidTransform):
                    d[f.name] = {"matrix": [[float(x) for x in row] for row in v.matrix]}
                elif isinstance(v, tuple):
                    d[f.name] = [float(x) for x in v]
                else:
                    d[f.name] = v
            out[sec] = d
        return out

    @classmethod
    def from_dict(cls, d: Any, *, source: str = "vehicle description") -> "VehicleDescription":
        """Build from a dict as :meth:`to_dict` gives (every key optional but the scanner extrinsic, see the module
        docstring); errors name ``source`` and the key."""
        if not isinstance(d, dict):
            raise DatasetError(f"The {source} must be a table of sections. Got {type(d).__name__} instead.")
        known = {"format_version", "name", *_SECTIONS}
        _unknown(d, known, source, "")
        ver = d.get("format_version", VEHICLE_FORMAT_VERSION)
        if ver != VEHICLE_FORMAT_VERSION or isinstance(ver, bool):
            raise DatasetError(
                f"The {source} key 'format_version' must be {VEHICLE_FORMAT_VERSION}. Got {ver!r} instead."
            )
        name = d.get("name", "vehicle")
        if not isinstance(name, str):
            raise DatasetError(f"The {source} key 'name' must be a string. Got {name!r} instead.")
        kw = {"name": name}
        for sec, spec_cls in _SECTIONS.items():
            kw[sec] = _section(d.get(sec, {}), spec_cls, sec, source)
        sc = kw["scanner"]
        if sc.min_range_m >= sc.max_range_m:
            raise DatasetError(f"The {source} key 'scanner.min_range_m' must be below 'scanner.max_range_m'. Got "
                               f"{sc.min_range_m!r} >= {sc.max_range_m!r} instead.")
        scanner = d.get("scanner", {})
        if not any(k in scanner for k in ("matrix", "xyz_m", "T_vehicle_scanner")):
            what = "is empty" if not set(d) - {"format_version", "name"} else "has no scanner extrinsic"
            raise DatasetError(f"The {source} {what}: the key 'scanner.xyz_m' (with 'scanner.rpy_rad') or "
                               "'scanner.matrix' (T_vehicle_scanner) is required; write xyz_m = [0, 0, 0] for a "
                               "scanner at the vehicle origin, or use the documented defaults (--vehicle girona500) "
                               "instead of a file.")
        return cls(**kw)


def _unknown(d: dict, known, source: str, prefix: str) -> None:
    extra = sorted(set(d) - set(known))
    if extra:
        raise DatasetError(f"The {source} has unknown key(s) {[prefix + k for k in extra]}. Expected some of "
                           f"{sorted(prefix + k for k in known)} (SI units, named in the key).")


def _section(raw: Any, spec_cls, sec: str, source: str):
    if not isinstance(raw, dict):
        raise DatasetError(f"The {source} key {sec!r} must be a table. Got {raw!r} instead.")
    names = {f.name: f for f in fields(spec_cls)}
    tkey = _TRANSFORMS.get(sec)
    known = set(names) | ({"xyz_m", "rpy_rad", "matrix"} if tkey else set())
    _unknown(raw, known, source, f"{sec}.")
    kw: dict = {}
    if tkey:
        T = _transform(raw, raw.get(tkey), sec, tkey, source)
        if T is not None:
            kw[tkey] = T
    default = spec_cls()
    for key, value in raw.items():
        if key in ("xyz_m", "rpy_rad", "matrix") or key == tkey:
            continue
        kw[key] = _value(value, getattr(default, key), f"{sec}.{key}", source)
    return spec_cls(**kw)


def _value(value: Any, default: Any, key: str, source: str):
    name = f"vehicle.{key}"
    where = f"The {source} key {key!r}"

    def num(v):
        return float(check_limit(name, v, where, error=DatasetError))

    if default is None and key == "scanner.camera_xyz_m":  # optional 3-vector
        default = (0.0, 0.0, 0.0)
    if isinstance(default, tuple):
        if not isinstance(value, list) or (len(default) and len(value) != len(default) and "azimuth" not in key):
            raise DatasetError(
                f"The {source} key {key!r} must be a list of {len(default)} numbers. Got {value!r} instead."
            )
        if not value:
            raise DatasetError(f"The {source} key {key!r} must not be empty.")
        return tuple(num(v) for v in value)
    if isinstance(default, int) and not isinstance(default, bool):
        return int(check_limit(name, value, where, error=DatasetError))
    return num(value)


def _transform(raw: dict, nested: Any, sec: str, tkey: str, source: str) -> RigidTransform | None:
    """The section's extrinsic, None when the section gives none."""
    spec = nested if isinstance(nested, dict) else {k: raw[k] for k in _EXTRINSIC_KEYS if k in raw}
    if nested is not None and not isinstance(nested, dict):
        raise DatasetError(f"The {source} key '{sec}.{tkey}' must be a table with 'matrix' or 'xyz_m'/'rpy_rad'. "
                           f"Got {nested!r} instead.")
    _unknown(spec, set(_EXTRINSIC_KEYS), source, f"{sec}.")
    if not spec:
        return None
    try:
        if "matrix" in spec:
            if "xyz_m" in spec or "rpy_rad" in spec:
                raise DatasetError("give either 'matrix' or 'xyz_m'/'rpy_rad', not both")
            T = RigidTransform(np.asarray(spec["matrix"], dtype=float))
        else:
            xyz = spec.get("xyz_m", [0.0, 0.0, 0.0])
            rpy = spec.get("rpy_rad", [0.0, 0.0, 0.0])
            for k, v in (("xyz_m", xyz), ("rpy_rad", rpy)):
                if not isinstance(v, list) or len(v) != 3 or not all(isinstance(x, (int, float)) and
                                                                     not isinstance(x, bool) for x in v):
                    raise DatasetError(f"'{sec}.{k}' must be a list of 3 numbers, got {v!r}")
            T = None
    except (SemslamError, TypeError, ValueError) as exc:
        raise DatasetError(f"The {source} extrinsic {sec}.{tkey} is invalid: {exc}") from None
    if T is not None:  # the matrix: its translation in range (its rotation was checked by RigidTransform)
        for i, x in enumerate(T.matrix[:3, 3]):
            check_limit("vehicle.extrinsic.xyz_m", float(x), f"The {source} key '{sec}.matrix' translation [{i}]",
                        error=DatasetError)
        return T
    for i, x in enumerate(xyz):
        check_limit("vehicle.extrinsic.xyz_m", x, f"The {source} key '{sec}.xyz_m[{i}]'", error=DatasetError)
    for i, a in enumerate(rpy):
        check_limit("vehicle.extrinsic.rpy_rad", a, f"The {source} key '{sec}.rpy_rad[{i}]'", error=DatasetError)
    try:
        return RigidTransform.from_xyz_rpy(np.asarray(xyz, dtype=float), np.asarray(rpy, dtype=float))
    except (SemslamError, TypeError, ValueError) as exc:  # pragma: no cover - finite, in range: always a rotation
        raise DatasetError(f"The {source} extrinsic {sec}.{tkey} is invalid: {exc}") from None


def read_vehicle_toml(path: str | os.PathLike) -> VehicleDescription:
    """Read and validate a vehicle file (see the module docstring)."""
    d = read_table(path, "vehicle file", DatasetError)
    return VehicleDescription.from_dict(d, source=f"vehicle file {str(Path(path))!r}")


def write_vehicle_toml(vehicle: VehicleDescription, path: str | os.PathLike) -> Path:
    """Write ``vehicle`` as a TOML file (atomically); :func:`read_vehicle_toml` reads it back exactly."""
    import tomli_w

    text = "# semslam vehicle description: SI units, named in the keys; frames: vehicle x fwd, y stbd, z down\n"
    text += tomli_w.dumps(vehicle.to_dict())
    atomic_write_text(Path(path), text)
    return Path(path)
