"""Mission directories (format version 1, documented in docs/mission-format.md).

::

    mission.json                 every parameter, the seed, frames, units, format_version, T_vehicle_scanner
    dvl.csv                      stamp_s,vx_mps,vy_mps,vz_mps,valid       (body frame; NaN when not valid)
    ahrs.csv                     stamp_s,roll_rad,pitch_rad,yaw_rad
    depth.csv                    stamp_s,depth_m
    scans/index.csv              scan_id,start_stamp_s,end_stamp_s,file,n_points
    scans/scan_NNNNN.pcd         binary_compressed PCD (x y z intensity line instance), scanner frame
    ground_truth/vehicle.csv     stamp_s,x_m,y_m,z_m,roll_rad,pitch_rad,yaw_rad,u_mps,v_mps,w_mps
    ground_truth/objects.csv     name,label,in_database,x_m,y_m,z_m,qw,qx,qy,qz    (T_world_object)

The directory is written into a temporary sibling and renamed at the end, so a reader never sees a
half-written mission; files inside are written with :mod:`semslam._atomic`. Numbers are written with
``repr`` (shortest round-trip form): the same mission gives byte-identical files.
"""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from .._atomic import atomic_write_text
from ..errors import MissionError, SemslamError
from ..geometry import RigidTransform
from .mission import AhrsLog, DepthLog, DvlLog, Mission, ObjectTruth, ScanRecord, VehicleTruth

FORMAT_VERSION = 1
SUPPORTED_VERSIONS = (1,)

_DVL = ("stamp_s", "vx_mps", "vy_mps", "vz_mps", "valid")
_AHRS = ("stamp_s", "roll_rad", "pitch_rad", "yaw_rad")
_DEPTH = ("stamp_s", "depth_m")
_INDEX = ("scan_id", "start_stamp_s", "end_stamp_s", "file", "n_points")
_VEHICLE = ("stamp_s", "x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad", "u_mps", "v_mps", "w_mps")
_OBJECTS = ("name", "label", "in_database", "x_m", "y_m", "z_m", "qw", "qx", "qy", "qz")


def _num(x: float) -> str:
    return repr(float(x))  # shortest round-trip text; 'nan' for NaN


def _csv_text(header: tuple[str, ...], rows) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


def _table(header: tuple[str, ...], *columns: np.ndarray) -> str:
    cols = [np.asarray(c) for c in columns]
    rows = ([_num(v) if c.dtype.kind == "f" else str(int(v)) for c, v in zip(cols, row)] for row in zip(*cols))
    return _csv_text(header, rows)


def write_mission(mission: Mission, out_dir: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write ``mission`` to the directory ``out_dir`` (created; must not exist unless ``overwrite``).

    Scans come from ``mission.load_scan`` (in memory for a simulated mission) and are written with
    :func:`semslam.io.write_point_cloud` (binary_compressed). Returns the directory path.

    Raises
    ------
    MissionError
        If ``out_dir`` exists (without ``overwrite``) or a scan cannot be written.
    """
    if not isinstance(mission, Mission):
        raise MissionError(f"The 'mission' argument of write_mission must be a Mission. Got {type(mission).__name__} instead.")
    out = Path(out_dir)
    if out.exists() and not overwrite:
        raise MissionError(f"The 'out_dir' argument of write_mission must not exist (use overwrite). Got existing {str(out)!r} instead.")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it private; a mission directory is a normal one
        _write_into(mission, tmp)
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
            os.replace(out, old / "previous")
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _write_into(m: Mission, d: Path) -> None:
    from ..io import write_point_cloud

    meta = dict(m.config)
    meta["format_version"] = FORMAT_VERSION
    meta["seed"] = m.seed
    meta["T_vehicle_scanner"] = m.T_vehicle_scanner.to_dict()
    meta["files"] = {"dvl": "dvl.csv", "ahrs": "ahrs.csv", "depth": "depth.csv", "scans": "scans/index.csv",
                     "vehicle_truth": "ground_truth/vehicle.csv" if m.truth is not None else None,
                     "objects_truth": "ground_truth/objects.csv"}
    atomic_write_text(d / "mission.json", json.dumps(meta, indent=2, sort_keys=True) + "\n")
    v = m.dvl.velocity_body_mps
    atomic_write_text(d / "dvl.csv", _table(_DVL, m.dvl.stamp_s, v[:, 0], v[:, 1], v[:, 2], m.dvl.valid.astype(int)))
    a = m.ahrs.rpy_rad
    atomic_write_text(d / "ahrs.csv", _table(_AHRS, m.ahrs.stamp_s, a[:, 0], a[:, 1], a[:, 2]))
    atomic_write_text(d / "depth.csv", _table(_DEPTH, m.depth.stamp_s, m.depth.depth_m))
    (d / "scans").mkdir()
    rows = []
    for rec in m.scans:
        cloud = m.load_scan(rec.scan_id)
        try:
            write_point_cloud(d / rec.path, cloud, encoding="binary_compressed")
        except SemslamError as exc:
            raise MissionError(f"Scan {rec.scan_id} cannot be written to {rec.path!r}: {exc}") from None
        rows.append([str(rec.scan_id), _num(rec.start_stamp_s), _num(rec.end_stamp_s), rec.path, str(cloud.n_points)])
    atomic_write_text(d / "scans" / "index.csv", _csv_text(_INDEX, rows))
    (d / "ground_truth").mkdir()
    if m.truth is not None:
        t = m.truth
        cols = [t.stamp_s, *t.position_ned_m.T, *t.rpy_rad.T, *t.velocity_body_mps.T]
        atomic_write_text(d / "ground_truth" / "vehicle.csv", _table(_VEHICLE, *cols))
    orows = []
    for o in m.objects:
        q = o.T_world_object.as_quat_wxyz()
        orows.append([o.name, o.label, str(int(o.in_database)), *map(_num, o.T_world_object.translation_m), *map(_num, q)])
    atomic_write_text(d / "ground_truth" / "objects.csv", _csv_text(_OBJECTS, orows))


# -- reading --------------------------------------------------------------------------------------
def _read_rows(path: Path, header: tuple[str, ...]) -> list[list[str]]:
    if not path.is_file():
        raise MissionError(f"The mission file {str(path)!r} is missing.")
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise MissionError(f"The mission file {str(path)!r} cannot be read: {exc}") from None
    if not rows or tuple(rows[0]) != header:
        got = ",".join(rows[0]) if rows else "(empty file)"
        raise MissionError(f"The mission file {str(path)!r} must start with the header {','.join(header)}. Got {got} instead.")
    for i, r in enumerate(rows[1:], start=2):
        if len(r) != len(header):
            raise MissionError(f"The mission file {str(path)!r} line {i} must have {len(header)} columns. Got {len(r)} instead.")
    return rows[1:]


def _floats(path: Path, header: tuple[str, ...]) -> np.ndarray:
    rows = _read_rows(path, header)
    try:
        return np.array(rows, dtype=float).reshape(len(rows), len(header))
    except ValueError:
        for i, r in enumerate(rows, start=2):
            for name, v in zip(header, r):
                try:
                    float(v)
                except ValueError:
                    raise MissionError(f"The mission file {str(path)!r} line {i} column {name!r} must be a number. Got {v!r} instead.") from None
        raise


def read_mission(directory: str | os.PathLike) -> Mission:
    """Read a mission directory written by :func:`write_mission` (scans stay on disk; load them with
    ``mission.load_scan(scan_id)``).

    Raises
    ------
    MissionError
        Missing directory or file, unsupported format version, malformed content (the message names
        the file, and the line and column when relevant).
    """
    d = Path(directory)
    if not d.is_dir():
        raise MissionError(f"The mission directory {str(d)!r} does not exist.")
    meta_path = d / "mission.json"
    if not meta_path.is_file():
        raise MissionError(f"The mission file {str(meta_path)!r} is missing.")
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MissionError(f"The mission file {str(meta_path)!r} is not valid JSON: {exc}") from None
    if not isinstance(meta, dict) or meta.get("format_version") not in SUPPORTED_VERSIONS:
        got = meta.get("format_version") if isinstance(meta, dict) else meta
        raise MissionError(f"The mission file {str(meta_path)!r} must have format_version in {SUPPORTED_VERSIONS}. Got {got!r} instead.")
    try:
        T_vs = RigidTransform(np.asarray(meta["T_vehicle_scanner"]["matrix"], dtype=float))
    except (KeyError, TypeError, ValueError, SemslamError) as exc:
        raise MissionError(f"The mission file {str(meta_path)!r} must hold a valid T_vehicle_scanner matrix: {exc}") from None
    try:
        dv = _floats(d / "dvl.csv", _DVL)
        dvl = DvlLog(dv[:, 0], dv[:, 1:4], dv[:, 4] != 0)
        ah = _floats(d / "ahrs.csv", _AHRS)
        ahrs = AhrsLog(ah[:, 0], ah[:, 1:4])
        de = _floats(d / "depth.csv", _DEPTH)
        depth = DepthLog(de[:, 0], de[:, 1])
        truth = None
        if (meta.get("files") or {}).get("vehicle_truth"):
            ve = _floats(d / "ground_truth" / "vehicle.csv", _VEHICLE)
            truth = VehicleTruth(ve[:, 0], ve[:, 1:4], ve[:, 4:7], ve[:, 7:10])
        objects = _read_objects(d / "ground_truth" / "objects.csv")
        scans = _read_index(d / "scans" / "index.csv")
    except MissionError:
        raise
    except SemslamError as exc:  # e.g. a non-rotation quaternion
        raise MissionError(f"The mission in {str(d)!r} is malformed: {exc}") from None
    config = {k: v for k, v in meta.items() if k not in ("T_vehicle_scanner", "files")}
    return Mission(config=config, T_vehicle_scanner=T_vs, dvl=dvl, ahrs=ahrs, depth=depth, truth=truth,
                   objects=objects, scans=scans, directory=d, seed=meta.get("seed"))


def _read_objects(path: Path) -> list[ObjectTruth]:
    out = []
    for i, r in enumerate(_read_rows(path, _OBJECTS), start=2):
        try:
            vals = np.array(r[3:], dtype=float)
            if r[2] not in ("0", "1"):
                raise ValueError(f"in_database must be 0 or 1, got {r[2]!r}")
            T = RigidTransform.from_quat_wxyz(vals[3:], vals[:3])
        except (ValueError, SemslamError) as exc:
            raise MissionError(f"The mission file {str(path)!r} line {i} is malformed: {exc}") from None
        out.append(ObjectTruth(name=r[0], label=r[1], T_world_object=T, in_database=r[2] == "1"))
    return out


def _read_index(path: Path) -> list[ScanRecord]:
    out = []
    for i, r in enumerate(_read_rows(path, _INDEX), start=2):
        try:
            rec = ScanRecord(int(r[0]), float(r[1]), float(r[2]), r[3], int(r[4]))
        except ValueError as exc:
            raise MissionError(f"The mission file {str(path)!r} line {i} is malformed: {exc}") from None
        if not (path.parent.parent / rec.path).is_file():
            raise MissionError(f"The scan file {rec.path!r} listed in {str(path)!r} line {i} is missing.")
        out.append(rec)
    return out
