"""Landmarks known before a run: a survey of the structure, or an earlier run's map (``map.json``).

A survey CSV has one row per object (angles in radians, Z-Y-X; the two sigmas optional, else
``[slam.initialisation] survey_position_sigma_m`` / ``survey_rotation_sigma_rad``)::

    name,label,x_m,y_m,z_m,roll_rad,pitch_rad,yaw_rad[,position_sigma_m,rotation_sigma_rad]

An earlier run's ``map.json`` (``semslam run``, ``semslam slam --export``) gives every landmark with its full 6x6
covariance. Either is read into a :class:`Survey` and given to the session before its first message
(:meth:`SlamSession.add_surveyed_landmarks`). The poses must be in the run's world frame: a map from a dive
placed by position fixes about the same geodetic origin, or a survey of the site in that frame.
"""

from __future__ import annotations

import csv
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError, SemslamError
from ..geometry import RigidTransform
from . import _ekf_kernels as kern

_HEAD = ("name", "label", "x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
_MAX_BYTES = 64 * 1024 * 1024


@dataclass(frozen=True)
class Survey:
    """Surveyed landmarks: names, class labels, world poses and, per landmark, a 6x6 covariance (x, y, z, roll,
    pitch, yaw) or None (the configuration's survey sigmas)."""

    names: tuple = ()
    labels: tuple = ()
    poses: tuple = ()
    covariances: tuple = ()
    source: str = ""
    geodetic_origin: dict | None = field(default=None)
    #: (6L, 6L) joint covariance of the landmarks (an earlier dive's map), or None
    joint_covariance: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.names)
        covs = tuple(self.covariances) if len(self.covariances) else (None,) * n
        if not (len(self.labels) == len(self.poses) == len(covs) == n):
            raise InputError("A Survey needs as many names, labels, poses and covariances.")
        if len(set(self.names)) != n:
            raise InputError(f"The landmark names of a survey must be unique. Got {list(self.names)} instead.")
        object.__setattr__(self, "covariances", covs)

    def __len__(self) -> int:
        return len(self.names)

    def add_to(self, session) -> None:
        """Give the landmarks to a session (before its first message)."""
        if len(self):
            session.add_surveyed_landmarks(list(self.names), list(self.labels), list(self.poses),
                                           list(self.covariances), joint_covariance=self.joint_covariance)


def read_survey(path: str | os.PathLike) -> Survey:
    """A survey CSV or a run's ``map.json`` (see the module docstring)."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"The survey or map file {str(p)!r} does not exist or is not a regular file.")
    if p.stat().st_size > _MAX_BYTES:
        raise InputError(f"The survey or map file {str(p)!r} is larger than {_MAX_BYTES >> 20} MiB.")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"The survey or map file {str(p)!r} cannot be read: {exc}") from None
    try:
        return _from_map_json(text, p) if p.suffix.lower() == ".json" else _from_csv(text, p)
    except InputError:
        raise
    except (SemslamError, ValueError, KeyError, TypeError, IndexError) as exc:
        raise InputError(f"The survey or map file {str(p)!r} is malformed: {exc}") from None


def _from_csv(text: str, p: Path) -> Survey:
    rows = list(csv.reader(text.splitlines()))
    if not rows or tuple(rows[0][:8]) != _HEAD or tuple(rows[0][8:]) not in ((), ("position_sigma_m",
                                                                              "rotation_sigma_rad")):
        raise InputError(f"The survey file {str(p)!r} must start with the header {','.join(_HEAD)}"
                         f"[,position_sigma_m,rotation_sigma_rad]. Got {','.join(rows[0]) if rows else '(empty)'} "
                         "instead.")
    names, labels, poses, covs = [], [], [], []
    for i, r in enumerate(rows[1:], start=2):
        if len(r) != len(rows[0]):
            raise InputError(f"The survey file {str(p)!r} line {i} must have {len(rows[0])} columns. Got {len(r)}.")
        try:
            v = [float(x) for x in r[2:]]
        except ValueError:
            raise InputError(f"The survey file {str(p)!r} line {i} must hold numbers after name and label.") from None
        if not all(math.isfinite(x) for x in v):
            raise InputError(f"The survey file {str(p)!r} line {i} must hold finite numbers.")
        T = RigidTransform.from_xyz_rpy(v[0:3], v[3:6])
        C = None
        if len(v) == 8:
            if v[6] <= 0 or v[7] <= 0:
                raise InputError(f"The survey file {str(p)!r} line {i}: the sigmas must be > 0.")
            Einv = kern.world_rate_to_rpy(np.asarray(v[3:6]))
            C = np.zeros((6, 6))
            C[0:3, 0:3] = np.eye(3) * v[6] ** 2
            C[3:6, 3:6] = Einv @ Einv.T * v[7] ** 2
            C = 0.5 * (C + C.T)
        names.append(r[0])
        labels.append(r[1])
        poses.append(T)
        covs.append(C)
    return Survey(tuple(names), tuple(labels), tuple(poses), tuple(covs), source=str(p))


def _from_map_json(text: str, p: Path) -> Survey:
    try:
        doc = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"The map file {str(p)!r} is not valid JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != "semslam-map":
        raise InputError(f"The map file {str(p)!r} must be a semslam map (\"format\": \"semslam-map\", written by "
                         "semslam run or semslam slam --export).")
    if doc.get("world_frame") == "local":
        raise InputError(f"The map file {str(p)!r} is in the local frame of its own dive's start point (that dive had "
                         "no position fix): another dive cannot be placed in it. Reuse maps of dives placed by "
                         "position fixes (GPS before the dive, USBL) about the same geodetic origin.")
    names, labels, poses, covs = [], [], [], []
    for k, lm in enumerate(doc.get("landmarks") or []):
        C = np.asarray(lm["covariance_6x6"], dtype=float)
        if C.shape != (6, 6) or not np.isfinite(C).all():
            raise InputError(f"The map file {str(p)!r} landmark {k} must have a finite 6x6 covariance.")
        names.append(str(lm.get("name") or f"landmark_{lm['landmark_id']}"))
        labels.append(str(lm["label"]))
        poses.append(RigidTransform.from_xyz_rpy(lm["position_ned_m"], lm["rpy_rad"]))
        covs.append(0.5 * (C + C.T))
    J = None
    if doc.get("joint_covariance") is not None:
        J = np.asarray(doc["joint_covariance"], dtype=float)
        if J.shape != (6 * len(names), 6 * len(names)) or not np.isfinite(J).all():
            raise InputError(f"The map file {str(p)!r} has a joint_covariance of shape {J.shape}: expected "
                             f"{6 * len(names)} x {6 * len(names)} finite numbers.")
        J = 0.5 * (J + J.T)
    return Survey(tuple(names), tuple(labels), tuple(poses), tuple(covs), source=str(p),
                  geodetic_origin=doc.get("geodetic_origin"), joint_covariance=J)


def check_survey_frame(survey: Survey, geodetic_origin) -> None:
    """A map from another dive must be in this dive's world frame: the same geodetic origin (within 1 cm)."""
    if survey.geodetic_origin is None:
        return
    if geodetic_origin is None:
        raise InputError(f"The map {survey.source!r} is in the world frame about {survey.geodetic_origin}, but this "
                         "dive has no geodetic origin (no position fix, no [origin] in its topic map).")
    from ..geodesy import GeodeticOrigin

    o = GeodeticOrigin.from_dict(survey.geodetic_origin)
    d = np.linalg.norm(geodetic_origin.ned_from_geodetic_deg(o.latitude_deg, o.longitude_deg, o.height_m)[0])
    if d > 0.01:
        raise InputError(f"The map {survey.source!r} is about another geodetic origin ({d:.2f} m from this dive's): "
                         "give the dive's topic map the map's [origin].")
