"""The vehicle description: what a navigator knows of its vehicle from the sensor data sheets and the
mounting, never from a particular dive. Read from a small human-written TOML file (units in the key names)::

    format_version = 1
    name = "girona500"

    [scanner]                       # the laser scanner
    xyz_m = [0.6, 0.0, 0.3]         # T_vehicle_scanner: translation (m) and Z-Y-X roll, pitch, yaw (rad) ...
    rpy_rad = [0.0, 0.0, 1.5708]    # ... or matrix = [[...], [...], [...], [...]] (4x4)
    line_count = 100                # lines per sweep: a point's line index gives its stamp

    [dvl]
    noise_abs_mps = 0.001           # white noise per axis: noise_abs_mps + noise_rel * speed
    noise_rel = 0.003
    beam_angle_rad = 0.5236         # Janus beams, angle off the DVL's z axis

    [attitude]
    noise_rpy_rad = [0.0035, 0.0035, 0.0175]

    [depth]
    noise_m = 0.02

Every key is optional; an absent one takes the Girona 500-class default of :meth:`VehicleDescription.girona500`
(the values below, with their sources in :mod:`semslam.simulation.config`). Unknown keys, wrong types, a
non-rotation extrinsic and out-of-range values raise :class:`~semslam.errors.DatasetError` naming the file
and the key.
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
#: (lower, upper) of each number, for a clear error on wrong units (degrees in a _rad key, mm in a _m key)
_RANGES = {
    "line_count": (0, 1e6), "min_range_m": (0, 1e3), "max_range_m": (1e-3, 1e3), "fov_rad": (1e-3, math.pi),
    "rate_hz": (1e-3, 1e4), "noise_abs_mps": (0, 1.0), "noise_rel": (0, 0.5), "max_speed_mps": (1e-3, 50),
    "degraded_noise_factor": (1, 1e3), "scale_factor_sigma": (0, 0.5), "misalignment_sigma_rad": (0, 0.5),
    "bias_sigma_mps": (0, 1), "bias_tau_s": (1e-3, 1e7), "degraded_bias_sigma_mps": (0, 1),
    "degraded_bias_tau_s": (1e-3, 1e7), "beam_angle_rad": (0, 1.2), "beam_azimuth_rad": (-2 * math.pi, 2 * math.pi),
    "flat_bottom_tolerance_m": (1e-4, 10), "noise_rpy_rad": (0, 0.5), "yaw_bias_walk_rad_per_sqrt_s": (0, 0.1),
    "noise_m": (1e-5, 10), "water_density_kg_m3": (900, 1100), "atmospheric_pressure_pa": (5e4, 2e5),
}


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
        """Build from a dict as :meth:`to_dict` gives (every key optional); errors name ``source`` and the key."""
        if not isinstance(d, dict):
            raise DatasetError(f"The {source} must be a table of sections. Got {type(d).__name__} instead.")
        known = {"format_version", "name", *_SECTIONS}
        _unknown(d, known, source, "")
        ver = d.get("format_version", VEHICLE_FORMAT_VERSION)
        if ver != VEHICLE_FORMAT_VERSION or isinstance(ver, bool):
            raise DatasetError(f"The {source} key 'format_version' must be {VEHICLE_FORMAT_VERSION}. Got {ver!r} instead.")
        name = d.get("name", "vehicle")
        if not isinstance(name, str):
            raise DatasetError(f"The {source} key 'name' must be a string. Got {name!r} instead.")
        kw = {"name": name}
        for sec, spec_cls in _SECTIONS.items():
            kw[sec] = _section(d.get(sec, {}), spec_cls, sec, source)
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
        kw[tkey] = _transform(raw, raw.get(tkey), sec, tkey, source)
    default = spec_cls()
    for key, value in raw.items():
        if key in ("xyz_m", "rpy_rad", "matrix") or key == tkey:
            continue
        kw[key] = _value(value, getattr(default, key), f"{sec}.{key}", source)
    return spec_cls(**kw)


def _value(value: Any, default: Any, key: str, source: str):
    lo, hi = _RANGES.get(key.split(".")[-1], (-math.inf, math.inf))
    unit = key.rsplit("_", 1)[-1] if "_" in key else ""

    def num(v):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise DatasetError(f"The {source} key {key!r} must be a number. Got {v!r} instead.")
        v = float(v)
        if not (math.isfinite(v) and lo <= v <= hi):
            hint = " (degrees given for radians?)" if unit == "rad" and abs(v) > hi else ""
            raise DatasetError(f"The {source} key {key!r} must be in [{lo:g}, {hi:g}] {unit}{hint}. Got {v!r} instead.")
        return v

    if isinstance(default, tuple):
        if not isinstance(value, list) or (len(default) and len(value) != len(default) and "azimuth" not in key):
            raise DatasetError(f"The {source} key {key!r} must be a list of {len(default)} numbers. Got {value!r} instead.")
        if not value:
            raise DatasetError(f"The {source} key {key!r} must not be empty.")
        return tuple(num(v) for v in value)
    if isinstance(default, int) and not isinstance(default, bool):
        v = num(value)
        if v != int(v):
            raise DatasetError(f"The {source} key {key!r} must be a whole number. Got {value!r} instead.")
        return int(v)
    return num(value)


def _transform(raw: dict, nested: Any, sec: str, tkey: str, source: str) -> RigidTransform:
    spec = nested if isinstance(nested, dict) else {k: raw[k] for k in ("xyz_m", "rpy_rad", "matrix") if k in raw}
    if nested is not None and not isinstance(nested, dict):
        raise DatasetError(f"The {source} key '{sec}.{tkey}' must be a table with 'matrix' or 'xyz_m'/'rpy_rad'. "
                           f"Got {nested!r} instead.")
    _unknown(spec, {"xyz_m", "rpy_rad", "matrix"}, source, f"{sec}.")
    try:
        if "matrix" in spec:
            if "xyz_m" in spec or "rpy_rad" in spec:
                raise DatasetError("give either 'matrix' or 'xyz_m'/'rpy_rad', not both")
            return RigidTransform(np.asarray(spec["matrix"], dtype=float))
        xyz = spec.get("xyz_m", [0.0, 0.0, 0.0])
        rpy = spec.get("rpy_rad", [0.0, 0.0, 0.0])
        for k, v in (("xyz_m", xyz), ("rpy_rad", rpy)):
            if not isinstance(v, list) or len(v) != 3 or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                                 for x in v):
                raise DatasetError(f"'{sec}.{k}' must be a list of 3 numbers, got {v!r}")
        if max(abs(float(a)) for a in rpy) > 2 * math.pi:
            raise DatasetError(f"'{sec}.rpy_rad' must be radians in [-2 pi, 2 pi] (degrees given?), got {rpy!r}")
        return RigidTransform.from_xyz_rpy(np.asarray(xyz, dtype=float), np.asarray(rpy, dtype=float))
    except (SemslamError, TypeError, ValueError) as exc:
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
