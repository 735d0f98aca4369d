"""Geodetic positions (WGS-84 latitude, longitude, ellipsoidal height) to a local NED frame and back.

A dive's world frame is a local tangent plane: north, east, down about a stated geodetic origin (the site's
surveyed mark, or the dive's first position fix). The conversion goes through Earth-centred Earth-fixed (ECEF)
coordinates, exactly (no flat-Earth approximation), so a fix 10 km from the origin is placed to the millimetre;
the inverse uses Bowring's closed form. Angles in radians inside; the ``*_deg`` functions take degrees, as
``sensor_msgs/NavSatFix`` gives them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import InputError

#: WGS-84 semi-major axis (m) and flattening
WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
_E2 = WGS84_F * (2.0 - WGS84_F)


def _ecef(lat_rad: np.ndarray, lon_rad: np.ndarray, h_m: np.ndarray) -> np.ndarray:
    s, c = np.sin(lat_rad), np.cos(lat_rad)
    n = WGS84_A_M / np.sqrt(1.0 - _E2 * s * s)
    return np.stack([(n + h_m) * c * np.cos(lon_rad), (n + h_m) * c * np.sin(lon_rad), (n * (1.0 - _E2) + h_m) * s],
                    axis=-1)


def _R_ecef_ned(lat_rad: float, lon_rad: float) -> np.ndarray:
    """Columns: the north, east and down unit vectors at (lat, lon) in ECEF."""
    sl, cl, so, co = math.sin(lat_rad), math.cos(lat_rad), math.sin(lon_rad), math.cos(lon_rad)
    return np.array([[-sl * co, -so, -cl * co],
                     [-sl * so, co, -cl * so],
                     [cl, 0.0, -sl]])


@dataclass(frozen=True)
class GeodeticOrigin:
    """The geodetic origin of a local NED world frame (degrees, metres above the WGS-84 ellipsoid)."""

    latitude_deg: float
    longitude_deg: float
    height_m: float = 0.0

    def __post_init__(self) -> None:
        for name, lo, hi in (("latitude_deg", -90.0, 90.0), ("longitude_deg", -180.0, 180.0),
                             ("height_m", -11000.0, 9000.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
                raise InputError(f"The {name!r} of a geodetic origin must be a number in [{lo:g}, {hi:g}]. Got "
                                 f"{v!r} instead.")
            object.__setattr__(self, name, float(v))

    def as_dict(self) -> dict:
        return {"latitude_deg": self.latitude_deg, "longitude_deg": self.longitude_deg, "height_m": self.height_m}

    @classmethod
    def from_dict(cls, d: Any, *, source: str = "geodetic origin") -> "GeodeticOrigin":
        if not isinstance(d, dict) or set(d) - {"latitude_deg", "longitude_deg", "height_m"} or \
                not {"latitude_deg", "longitude_deg"} <= set(d):
            raise InputError(f"The {source} must be a table with latitude_deg, longitude_deg and optional height_m. "
                             f"Got {d!r} instead.")
        return cls(d["latitude_deg"], d["longitude_deg"], d.get("height_m", 0.0))

    def ned_from_geodetic_deg(self, latitude_deg: Any, longitude_deg: Any, height_m: Any = 0.0) -> np.ndarray:
        """(N, 3) NED positions (m) of geodetic points (degrees, ellipsoidal height in metres)."""
        lat = np.radians(np.atleast_1d(np.asarray(latitude_deg, dtype=float)))
        lon = np.radians(np.atleast_1d(np.asarray(longitude_deg, dtype=float)))
        h = np.broadcast_to(np.asarray(height_m, dtype=float), lat.shape)
        lat0, lon0 = math.radians(self.latitude_deg), math.radians(self.longitude_deg)
        d = _ecef(lat, lon, h) - _ecef(np.array([lat0]), np.array([lon0]), np.array([self.height_m]))
        return d @ _R_ecef_ned(lat0, lon0)

    def geodetic_deg_from_ned(self, position_ned_m: Any) -> np.ndarray:
        """(N, 3) latitude (deg), longitude (deg), ellipsoidal height (m) of NED points: the inverse of
        :meth:`ned_from_geodetic_deg` (Bowring's closed form, sub-millimetre near the Earth's surface)."""
        p = np.atleast_2d(np.asarray(position_ned_m, dtype=float))
        lat0, lon0 = math.radians(self.latitude_deg), math.radians(self.longitude_deg)
        x = _ecef(np.array([lat0]), np.array([lon0]), np.array([self.height_m])) + p @ _R_ecef_ned(lat0, lon0).T
        lon = np.arctan2(x[:, 1], x[:, 0])
        r = np.hypot(x[:, 0], x[:, 1])
        b = WGS84_A_M * (1.0 - WGS84_F)
        ep2 = (WGS84_A_M ** 2 - b ** 2) / b ** 2
        th = np.arctan2(x[:, 2] * WGS84_A_M, r * b)
        lat = np.arctan2(x[:, 2] + ep2 * b * np.sin(th) ** 3, r - _E2 * WGS84_A_M * np.cos(th) ** 3)
        s = np.sin(lat)
        n = WGS84_A_M / np.sqrt(1.0 - _E2 * s * s)
        with np.errstate(divide="ignore", invalid="ignore"):
            h = np.where(np.abs(np.cos(lat)) > 1e-9, r / np.cos(lat) - n, np.abs(x[:, 2]) - b)
        return np.stack([np.degrees(lat), np.degrees(lon), h], axis=-1)
