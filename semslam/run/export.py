"""Standard results out: a :class:`~semslam.slam.SlamResult` in the formats other tools read.

* ``write_tum``: TUM RGB-D trajectory (``stamp tx ty tz qx qy qz qw``: evo, rpg_trajectory_evaluation, most SLAM
  benchmarks). TUM has no covariance: use the run directory's ``trajectory.csv`` or the mcap for it.
* ``write_kitti``: KITTI odometry poses (12 numbers a line: the first 3 rows of the 4x4 pose, row-major) and, as
  KITTI keeps stamps apart, a times file beside it (one stamp in seconds a line).
* ``write_landmarks_json`` / ``write_landmarks_csv`` / ``write_landmarks_ply``: the map with its full 6x6
  covariances (x y z roll pitch yaw, world NED), ids, labels, first/last seen and update counts.
* ``write_mcap`` (:mod:`semslam.run.export_mcap`): a ROS 2 bag for Foxglove / RViz, in ROS frames (REP-103/105).
* ``export_run``: all of them with conventional names.

Poses are ``T_world_vehicle``. ``frame="ned"`` (default) keeps semslam's frames (world NED, body FRD: x forward,
y starboard, z down); ``frame="enu"`` writes ROS frames (world ENU, body FLU) through :mod:`semslam.io.ros.frames`.
Orientation is the result's ``attitude_rpy_rad`` (the AHRS attitude, yaw-bias corrected), at every epoch, with the
online or the smoothed (RTS) position. Every file is written atomically (temporary sibling, then renamed).
"""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from .._atomic import atomic_open, atomic_write_text
from .._jsonable import to_jsonable
from ..errors import InputError
from ..geometry import quat_wxyz_from_rotation, rotations_from_rpy
from ..slam.results import SlamResult
from .result_views import check_file_path, check_frame, check_result, landmark_class_indices, trajectory_poses

__all__ = ["FORMATS", "export_run", "kitti_times_path", "landmark_class_indices", "trajectory_poses",
           "write_kitti", "write_landmarks_csv", "write_landmarks_json", "write_landmarks_ply", "write_tum"]

#: format names of :func:`export_run`
FORMATS = ("tum", "kitti", "landmarks", "mcap")
_AXES = ("x", "y", "z", "roll", "pitch", "yaw")


def write_tum(result: SlamResult, path: str | os.PathLike, *, smoothed: bool = False, frame: str = "ned") -> Path:
    """Write the trajectory as a TUM file: one line ``stamp tx ty tz qx qy qz qw`` per epoch (seconds as in the
    result, metres, unit quaternion scalar last with ``qw >= 0``), after a ``#`` header (TUM tools skip it).

    ``smoothed``: the RTS-smoothed positions instead of the online filter's. ``frame``: ``"ned"`` or ``"enu"``
    (module doc). TUM has no covariance. Raises :class:`SlamError` when the result has no attitude.
    """
    out = check_file_path(path, "write_tum")
    stamps, pos, R = trajectory_poses(result, smoothed=smoothed, frame=frame, caller="write_tum")
    body = "FLU" if frame == "enu" else "FRD"
    lines = [f"# semslam {'smoothed' if smoothed else 'online'} trajectory ({result.mode}), T_world_vehicle: "
             f"world {frame.upper()}, body {body}", "# timestamp tx ty tz qx qy qz qw"]
    for t, p, rot in zip(stamps, pos, R):
        w, x, y, z = quat_wxyz_from_rotation(rot)
        lines.append(f"{t:.9f} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} {x:.12f} {y:.12f} {z:.12f} {w:.12f}")
    atomic_write_text(out, "\n".join(lines) + "\n")
    return out


def kitti_times_path(path: str | os.PathLike) -> Path:
    """The times file :func:`write_kitti` writes beside ``path``: ``trajectory.kitti`` -> ``trajectory.times.txt``."""
    return Path(path).with_suffix(".times.txt")


def write_kitti(result: SlamResult, path: str | os.PathLike, *, smoothed: bool = False, frame: str = "ned",
                times_path: str | os.PathLike | None = None) -> tuple[Path, Path]:
    """Write the trajectory as KITTI odometry poses: per epoch one line of 12 numbers, the first three rows of
    ``T_world_vehicle`` (4x4) row-major, no header. KITTI keeps stamps in a separate file: ``times_path``
    (default :func:`kitti_times_path`, e.g. ``trajectory.times.txt``) gets one stamp (s) per line.

    Returns ``(poses_path, times_path)``. ``smoothed``, ``frame``: as :func:`write_tum`. No covariance.
    """
    out = check_file_path(path, "write_kitti")
    times = check_file_path(kitti_times_path(out) if times_path is None else times_path, "write_kitti",
                             "times_path")
    if times.resolve() == out.resolve():
        raise InputError(f"The 'times_path' argument of write_kitti must differ from 'path'. Got '{times}' instead.")
    stamps, pos, R = trajectory_poses(result, smoothed=smoothed, frame=frame, caller="write_kitti")
    rows = np.concatenate([R, pos[:, :, None]], axis=2).reshape(-1, 12)
    atomic_write_text(out, "".join(" ".join(f"{v:.12e}" for v in row) + "\n" for row in rows))
    atomic_write_text(times, "".join(f"{t:.9f}\n" for t in stamps))
    return out, times


def _landmark_record(lm: Any) -> dict:
    pose = np.asarray(lm.pose_xyzrpy, dtype=np.float64)
    cov = np.asarray(lm.covariance_6x6, dtype=np.float64)
    R = rotations_from_rpy(pose[3:])[0]
    # the estimate only: the errors against truth live in the run's landmarks.csv and metrics (evaluation), so the
    # same dive with or without ground truth gives byte-identical maps
    return {"landmark_id": int(lm.landmark_id), "label": lm.label, "name": lm.name,
            "position_ned_m": pose[:3], "rpy_rad": pose[3:], "quat_wxyz": quat_wxyz_from_rotation(R),
            "covariance_6x6": cov, "first_seen_s": float(lm.first_seen_s), "last_seen_s": float(lm.last_seen_s),
            "n_updates": int(lm.n_updates)}


def write_landmarks_json(result: SlamResult, path: str | os.PathLike) -> Path:
    """Write the map as JSON: ``{"format": "semslam-map", "format_version": 1, "frame", "covariance_order",
    "mode", "classes": {label: index}, "landmarks": [...]}``; each landmark has ``landmark_id``, ``label``,
    ``name``, ``position_ned_m``, ``rpy_rad``, ``quat_wxyz``, ``covariance_6x6`` (6 rows of 6, order x y z roll
    pitch yaw), ``first_seen_s``, ``last_seen_s``, ``n_updates``. ``world_frame``: ``"world"`` (placed by position
    fixes, local NED about ``geodetic_origin``) or ``"local"`` (the dive's start point): a later dive reuses the map
    (``--survey``) only in the same world frame. ``joint_covariance`` (6L rows of 6L): the landmarks' joint
    covariance (landmarks mapped from one trajectory share its errors: a map reused without their correlation
    would bend the next dive's trajectory). Errors against ground truth are not part of the map (the run's
    ``landmarks.csv`` has them)."""
    out = check_file_path(path, "write_landmarks_json")
    check_result(result, "write_landmarks_json", need_attitude=False)
    start = result.metrics.get("start") or {}
    doc = {"format": "semslam-map", "format_version": 2,
           "frame": "world NED (x north, y east, z down); roll pitch yaw intrinsic Z-Y-X",
           "world_frame": start.get("frame"), "geodetic_origin": result.metrics.get("geodetic_origin"),
           "covariance_order": list(_AXES), "mode": result.mode, "classes": landmark_class_indices(result),
           "landmarks": [_landmark_record(lm) for lm in result.landmarks]}
    J = getattr(result, "landmark_joint_covariance", None)
    if J is not None and np.shape(J) == (6 * len(result.landmarks),) * 2:
        doc["joint_covariance"] = np.asarray(J, dtype=np.float64)  # (6L, 6L), landmarks in order
    atomic_write_text(out, json.dumps(to_jsonable(doc), indent=2) + "\n")
    return out


def write_landmarks_csv(result: SlamResult, path: str | os.PathLike) -> Path:
    """Write the map as CSV, one row per landmark: ids, label, position (NED), rpy, ``qw qx qy qz``, first/last
    seen, updates and the full 6x6 covariance row-major as 36 columns
    ``cov_<a>_<b>`` with a, b in x y z roll pitch yaw (unlike the run directory's ``landmarks.csv``, which keeps
    the upper triangle)."""
    out = check_file_path(path, "write_landmarks_csv")
    check_result(result, "write_landmarks_csv", need_attitude=False)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["landmark_id", "label", "name", "x_m", "y_m", "z_m", "roll_rad", "pitch_rad",
                "yaw_rad", "qw", "qx", "qy", "qz", "first_seen_s", "last_seen_s", "n_updates"]
               + [f"cov_{a}_{b}" for a in _AXES for b in _AXES])
    num = lambda v: f"{v:.17g}" if np.isfinite(v) else ""  # noqa: E731  (17 digits: floats round-trip)
    for lm in result.landmarks:
        r = _landmark_record(lm)
        w.writerow([r["landmark_id"], r["label"], r["name"],
                    *map(num, r["position_ned_m"]), *map(num, r["rpy_rad"]), *map(num, r["quat_wxyz"]),
                    num(r["first_seen_s"]), num(r["last_seen_s"]), r["n_updates"],
                    *map(num, r["covariance_6x6"].reshape(-1))])
    atomic_write_text(out, buf.getvalue())
    return out


def write_landmarks_ply(result: SlamResult, path: str | os.PathLike) -> Path:
    """Write the map as a binary PLY point cloud: one vertex per landmark with ``x y z`` (float64, world NED, m),
    ``class_index``, ``landmark_id`` and ``n_updates`` (int32), and one ``comment class <index> <label>`` line per
    class (:func:`landmark_class_indices`). CloudCompare and MeshLab show the ints as scalar fields;
    :func:`semslam.io.read_point_cloud` reads it back (the ints in ``fields``)."""
    import plyfile

    out = check_file_path(path, "write_landmarks_ply")
    check_result(result, "write_landmarks_ply", need_attitude=False)
    classes = landmark_class_indices(result)
    vertex = np.zeros(len(result.landmarks), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"),
                                                   ("class_index", "<i4"), ("landmark_id", "<i4"),
                                                   ("n_updates", "<i4")])
    for i, lm in enumerate(result.landmarks):
        vertex[i] = (*np.asarray(lm.pose_xyzrpy, dtype=np.float64)[:3], classes[lm.label], lm.landmark_id,
                     lm.n_updates)
    comments = ["semslam map: landmark positions, world NED (x north, y east, z down), metres"]
    comments += [f"class {i} {' '.join(label.split())}" for label, i in classes.items()]
    ply = plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex")], text=False, byte_order="<",
                          comments=comments)
    with atomic_open(out, "wb") as fh:
        ply.write(fh)
    return out


def export_run(result: SlamResult, out_dir: str | os.PathLike, *, formats: Iterable[str] = FORMATS,
               frame: str = "ned", smoothed: bool = True, **mcap_options: Any) -> list[Path]:
    """Write ``result`` into ``out_dir`` in ``formats`` (any of :data:`FORMATS`) and return the written paths.

    * ``"tum"``: ``trajectory.tum`` (and ``trajectory_smoothed.tum`` when the result is smoothed and ``smoothed``);
    * ``"kitti"``: ``trajectory.kitti`` + ``trajectory.times.txt`` (and the ``trajectory_smoothed.*`` pair);
    * ``"landmarks"``: ``map.json``, ``map.csv``, ``map.ply`` (``landmarks.csv`` is the run directory's own);
    * ``"mcap"``: ``run.mcap``, one self-contained mcap file (:func:`semslam.run.export_mcap.write_mcap`, which
      gets ``mcap_options``; ``/semslam/path_smoothed`` follows ``smoothed``).

    ``frame`` applies to TUM and KITTI (the mcap is always in ROS frames, the map files in NED). The formats, the
    frame, the attitude, ``out_dir`` and the names of ``mcap_options`` are checked before the first file is
    written; each file is written atomically.
    """
    if isinstance(formats, str):
        formats = [formats]
    formats = list(formats)
    bad = [f for f in formats if f not in FORMATS]
    if bad or not formats:
        raise InputError(f"The 'formats' argument of export_run must name one or more of {FORMATS}. "
                         f"Got {bad[0] if bad else formats!r} instead.")
    check_frame(frame, "export_run")
    check_result(result, "export_run", need_attitude=any(f != "landmarks" for f in formats))
    if mcap_options:
        import inspect

        from .export_mcap import write_mcap

        known = [k for k, p in inspect.signature(write_mcap).parameters.items() if p.kind is p.KEYWORD_ONLY]
        unknown = sorted(set(mcap_options) - set(known) | ({"smoothed"} & set(mcap_options)))
        if unknown:
            raise InputError(f"The keyword arguments of export_run must be options of write_mcap "
                             f"({', '.join(k for k in known if k != 'smoothed')}). Got {unknown[0]!r} instead.")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"The 'out_dir' argument of export_run must be a directory. Got the file '{out}' instead.")
    out.mkdir(parents=True, exist_ok=True)
    variants = [False] + ([True] if smoothed and result.smoothed_position_ned_m is not None else [])
    written: list[Path] = []
    for fmt in dict.fromkeys(formats):
        if fmt == "tum":
            written += [write_tum(result, out / f"trajectory{'_smoothed' if s else ''}.tum", smoothed=s, frame=frame)
                        for s in variants]
        elif fmt == "kitti":
            for s in variants:
                written += write_kitti(result, out / f"trajectory{'_smoothed' if s else ''}.kitti", smoothed=s,
                                       frame=frame)
        elif fmt == "landmarks":
            written += [write_landmarks_json(result, out / "map.json"), write_landmarks_csv(result, out / "map.csv"),
                        write_landmarks_ply(result, out / "map.ply")]
        else:
            from .export_mcap import write_mcap

            written.append(write_mcap(result, out / "run.mcap", smoothed=smoothed, **mcap_options))
    return written
