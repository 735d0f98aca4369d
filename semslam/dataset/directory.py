"""Dataset directories: the on-disk form of a :class:`~semslam.dataset.Dataset` (format version 2; version 1,
written by semslam <= 0.1, is refused with a one-line error). Documented in docs/dataset-format.md.

::

    mission.json                 format_version, seed, frames, units, provenance (e.g. the simulator's settings)
    vehicle.toml                 the vehicle description (mounting, sensor figures; see semslam.dataset.vehicle)
    dvl.csv                      stamp_s,vx_mps,vy_mps,vz_mps,valid[,range_0_m,...]  (DVL frame; NaN when not valid)
    ahrs.csv                     stamp_s,roll_rad,pitch_rad,yaw_rad
    depth.csv                    stamp_s,depth_m
    position_fixes.csv           stamp_s,north_m,east_m,var_nn_m2,cov_ne_m2,var_ee_m2,source   (optional: GPS, USBL)
    scans/index.csv              scan_id,start_stamp_s,end_stamp_s,file,n_points
    scans/scan_NNNNN.pcd         binary_compressed PCD (x y z intensity line instance), scanner frame
    ground_truth/vehicle.csv     stamp_s,x_m,y_m,z_m,roll_rad,pitch_rad,yaw_rad,u_mps,v_mps,w_mps
    ground_truth/objects.csv     name,label,in_database,x_m,y_m,z_m,qw,qx,qy,qz    (T_world_object)

``ground_truth/`` is optional (a recorded dive has none); only evaluation reads it. ``mission.json`` may state
the world frame's ``geodetic_origin`` (latitude_deg, longitude_deg, height_m): the fixes are NED about it.

The directory is written into a temporary sibling and renamed at the end, so a reader never sees a
half-written mission; files inside are written with :mod:`semslam._atomic`. Numbers are written with
``repr`` (shortest round-trip form): the same mission gives byte-identical files.
"""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path

import numpy as np

from .._atomic import atomic_write_text
from .._outdir import staged_output_dir
from ..errors import DatasetError, SemslamError
from ..geometry import RigidTransform
from .dataset import Dataset
from .logs import AttitudeLog, DepthLog, DvlLog, ObjectTruth, PositionFixLog, ScanRecord, VehicleTruth
from .vehicle import VehicleDescription, read_vehicle_toml, write_vehicle_toml

FORMAT_VERSION = 2
SUPPORTED_VERSIONS = (2,)

_DVL = ("stamp_s", "vx_mps", "vy_mps", "vz_mps", "valid")
_AHRS = ("stamp_s", "roll_rad", "pitch_rad", "yaw_rad")
_DEPTH = ("stamp_s", "depth_m")
_FIXES = ("stamp_s", "north_m", "east_m", "var_nn_m2", "cov_ne_m2", "var_ee_m2", "source")
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


def write_dataset(mission: Dataset, out_dir: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write ``mission`` to the directory ``out_dir`` (created; must not exist unless ``overwrite``).

    Scans come from ``mission.load_scan`` (in memory for a simulated mission) and are written with
    :func:`semslam.io.write_point_cloud` (binary_compressed). Returns the directory path.

    Raises
    ------
    DatasetError
        If ``out_dir`` exists (without ``overwrite``) or a scan cannot be written.
    """
    if not isinstance(mission, Dataset):
        raise DatasetError(
            f"The 'mission' argument of write_dataset must be a Dataset. Got {type(mission).__name__} instead."
        )
    out = Path(out_dir)
    # only a mission semslam's marker proves it wrote is replaced (semslam._outdir), never the mission's own source
    if out.exists() and not overwrite:
        raise DatasetError(
            f"The 'out_dir' argument of write_dataset must not exist (use overwrite). Got existing {str(out)!r} "
            f"instead."
        )
    with staged_output_dir(out, overwrite=True, kind="mission", option="out_dir",
                           inputs=(mission.directory,)) as tmp:
        _write_into(mission, tmp)
    return out


def _write_into(m: Dataset, d: Path) -> None:
    from ..io import write_point_cloud

    meta = {k: v for k, v in m.metadata.items() if k not in ("format_version", "seed", "files", "T_vehicle_scanner",
                                                             "geodetic_origin")}
    meta["format_version"] = FORMAT_VERSION
    meta["seed"] = m.seed
    if m.geodetic_origin is not None:
        meta["geodetic_origin"] = m.geodetic_origin.as_dict()
    meta["files"] = {"vehicle": "vehicle.toml", "dvl": "dvl.csv", "ahrs": "ahrs.csv", "depth": "depth.csv",
                     "scans": "scans/index.csv",
                     "position_fixes": "position_fixes.csv" if m.fixes is not None else None,
                     "vehicle_truth": "ground_truth/vehicle.csv" if m.truth is not None else None,
                     "objects_truth": "ground_truth/objects.csv"}
    atomic_write_text(d / "mission.json", json.dumps(meta, indent=2, sort_keys=True) + "\n")
    write_vehicle_toml(m.vehicle, d / "vehicle.toml")
    v = m.dvl.velocity_body_mps
    cols = [m.dvl.stamp_s, v[:, 0], v[:, 1], v[:, 2], m.dvl.valid.astype(int)]
    head = _DVL
    if m.dvl.beam_range_m is not None:
        cols += list(m.dvl.beam_range_m.T)
        head = _DVL + tuple(f"range_{k}_m" for k in range(m.dvl.beam_range_m.shape[1]))
    atomic_write_text(d / "dvl.csv", _table(head, *cols))
    a = m.attitude.rpy_rad
    atomic_write_text(d / "ahrs.csv", _table(_AHRS, m.attitude.stamp_s, a[:, 0], a[:, 1], a[:, 2]))
    atomic_write_text(d / "depth.csv", _table(_DEPTH, m.depth.stamp_s, m.depth.depth_m))
    if m.fixes is not None:
        f, c = m.fixes, m.fixes.covariance_ne_m2
        rows = ([_num(t), _num(p[0]), _num(p[1]), _num(ci[0, 0]), _num(ci[0, 1]), _num(ci[1, 1]), src]
                for t, p, ci, src in zip(f.stamp_s, f.position_ne_m, c, f.source))
        atomic_write_text(d / "position_fixes.csv", _csv_text(_FIXES, rows))
    (d / "scans").mkdir()
    rows = []
    for rec in m.scans:
        cloud = m.load_scan(rec.scan_id)
        try:
            write_point_cloud(d / rec.path, cloud, encoding="binary_compressed")
        except SemslamError as exc:
            raise DatasetError(f"Scan {rec.scan_id} cannot be written to {rec.path!r}: {exc}") from None
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
        orows.append(
            [o.name, o.label, str(int(o.in_database)), *map(_num, o.T_world_object.translation_m), *map(_num, q)]
        )
    atomic_write_text(d / "ground_truth" / "objects.csv", _csv_text(_OBJECTS, orows))


# -- reading --------------------------------------------------------------------------------------
def _read_rows(path: Path, header: tuple[str, ...], extra_prefix: str = "") -> tuple[list[str], list[list[str]]]:
    if not path.is_file():
        raise DatasetError(f"The mission file {str(path)!r} is missing or not a regular file.")
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DatasetError(f"The mission file {str(path)!r} cannot be read: {exc}") from None
    head = tuple(rows[0]) if rows else ()
    extra = head[len(header):]
    if not rows or head[:len(header)] != header or (extra and not (extra_prefix and all(
            c == f"{extra_prefix}{k}_m" for k, c in enumerate(extra)))):
        got = ",".join(head) if rows else "(empty file)"
        want = ",".join(header) + (f"[,{extra_prefix}0_m,...]" if extra_prefix else "")
        raise DatasetError(f"The mission file {str(path)!r} must start with the header {want}. Got {got} instead.")
    for i, r in enumerate(rows[1:], start=2):
        if len(r) != len(head):
            raise DatasetError(
                f"The mission file {str(path)!r} line {i} must have {len(head)} columns. Got {len(r)} instead."
            )
    return list(head), rows[1:]


def _floats(path: Path, header: tuple[str, ...], extra_prefix: str = "") -> np.ndarray:
    head, rows = _read_rows(path, header, extra_prefix)
    try:
        return np.array(rows, dtype=float).reshape(len(rows), len(head))
    except ValueError:
        for i, r in enumerate(rows, start=2):
            for name, v in zip(head, r):
                try:
                    float(v)
                except ValueError:
                    raise DatasetError(
                        f"The mission file {str(path)!r} line {i} column {name!r} must be a number. Got {v!r} instead."
                    ) from None
        raise


def read_dataset(directory: str | os.PathLike) -> Dataset:
    """Read a dataset directory written by :func:`write_dataset` (scans stay on disk; load them with
    ``mission.load_scan(scan_id)``).

    Raises
    ------
    DatasetError
        Missing directory or file, unsupported format version, malformed content (the message names
        the file, and the line and column when relevant).
    """
    d = Path(directory)
    if not d.is_dir():
        raise DatasetError(f"The dataset directory {str(d)!r} does not exist.")
    meta_path = d / "mission.json"
    if not meta_path.is_file():
        raise DatasetError(f"The mission file {str(meta_path)!r} is missing.")
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DatasetError(f"The mission file {str(meta_path)!r} is not valid JSON: {exc}") from None
    if isinstance(meta, dict) and meta.get("format_version") == 1:
        raise DatasetError(f"The mission file {str(meta_path)!r} has format_version 1 (semslam <= 0.1), which this "
                           f"semslam no longer reads: simulate the dive again, or write the dataset again with "
                           f"semslam.dataset.write_dataset.")
    if not isinstance(meta, dict) or meta.get("format_version") not in SUPPORTED_VERSIONS:
        got = meta.get("format_version") if isinstance(meta, dict) else meta
        raise DatasetError(
            f"The mission file {str(meta_path)!r} must have format_version in {SUPPORTED_VERSIONS}. Got {got!r} "
            f"instead."
        )
    try:
        vehicle = read_vehicle_toml(d / "vehicle.toml")
        dv = _floats(d / "dvl.csv", _DVL, extra_prefix="range_")
        dvl = _log(d / "dvl.csv", DvlLog, dv[:, 0], dv[:, 1:4], _valid(dv[:, 4], d / "dvl.csv"),
                   dv[:, 5:] if dv.shape[1] > 5 else None)
        ah = _floats(d / "ahrs.csv", _AHRS)
        attitude = _log(d / "ahrs.csv", AttitudeLog, ah[:, 0], ah[:, 1:4])
        de = _floats(d / "depth.csv", _DEPTH)
        depth = _log(d / "depth.csv", DepthLog, de[:, 0], de[:, 1])
        truth = None
        files = meta.get("files") or {}
        if not isinstance(files, dict):
            raise DatasetError(
                f"The mission file {str(meta_path)!r} key 'files' must be an object. Got {files!r} instead."
            )
        # ground truth is optional (a recorded dive has none; only evaluation reads it): read when present
        if files.get("vehicle_truth") and (d / "ground_truth" / "vehicle.csv").exists():
            ve = _floats(d / "ground_truth" / "vehicle.csv", _VEHICLE)
            truth = _log(
                d / "ground_truth" / "vehicle.csv", VehicleTruth, ve[:, 0], ve[:, 1:4], ve[:, 4:7], ve[:, 7:10]
            )
        objects = (
            _read_objects(d / "ground_truth" / "objects.csv") if (d / "ground_truth" / "objects.csv").exists() else []
        )
        fixes = _read_fixes(d / "position_fixes.csv") if (d / "position_fixes.csv").exists() else None
        origin = None
        if meta.get("geodetic_origin") is not None:
            from ..geodesy import GeodeticOrigin

            origin = GeodeticOrigin.from_dict(meta["geodetic_origin"], source=f"{str(meta_path)!r} geodetic_origin")
        scans = _read_index(d / "scans" / "index.csv") if (d / "scans" / "index.csv").exists() else []
        metadata = {k: v for k, v in meta.items() if k not in ("T_vehicle_scanner", "files", "format_version", "seed",
                                                             "geodetic_origin")}
        seed = meta.get("seed")
        return Dataset(vehicle, dvl, attitude, depth, truth, objects, scans, metadata, d,
                       seed if isinstance(seed, int) and not isinstance(seed, bool) else None, fixes=fixes,
                       geodetic_origin=origin)
    except DatasetError as exc:
        raise DatasetError(f"{exc}" if str(d) in str(exc) else f"The mission in {str(d)!r}: {exc}") from None
    except SemslamError as exc:  # e.g. a non-rotation quaternion
        raise DatasetError(f"The mission in {str(d)!r} is malformed: {exc}") from None


def _log(path: Path, cls, *columns):
    """``cls(*columns)``, its validation error naming the file (a row k of the log is line k + 2 of the file)."""
    try:
        return cls(*columns)
    except DatasetError as exc:
        raise DatasetError(f"The mission file {str(path)!r}: {exc} (row r is line r + 2)") from None


def _valid(col: np.ndarray, path: Path) -> np.ndarray:
    bad = np.flatnonzero((col != 0) & (col != 1))
    if len(bad):
        raise DatasetError(f"The mission file {str(path)!r} line {int(bad[0]) + 2} column 'valid' must be 0 or 1. "
                           f"Got {col[bad[0]]!r} instead.")
    return col == 1


def vehicle_from_simulator_dict(sim: dict, T_vehicle_scanner: RigidTransform, *,
                                source: str = "simulator settings") -> VehicleDescription:
    """The vehicle description implied by semslam's simulator settings (``SimulatorConfig.to_dict()``): the
    noise figures and geometry the simulated sensors were specified with (the simulator's own vehicle file)."""
    def sec(name):
        v = sim.get(name) or {}
        if not isinstance(v, dict):
            raise DatasetError(f"The {source} section {name!r} must be an object. Got {v!r} instead.")
        return v

    dvl, ahrs, depth, sc = sec("dvl"), sec("ahrs"), sec("depth"), sec("scanner")
    d: dict = {"name": "semslam-simulator", "scanner": {"matrix": T_vehicle_scanner.matrix.tolist()},
               "dvl": {}, "attitude": {}, "depth": {}}
    for src, dst in (("noise_abs_mps", "noise_abs_mps"), ("noise_rel", "noise_rel"),
                     ("slope_noise_factor", "degraded_noise_factor"), ("scale_factor_sigma", "scale_factor_sigma"),
                     ("misalignment_sigma_rad", "misalignment_sigma_rad"), ("bias_sigma_mps", "bias_sigma_mps"),
                     ("bias_tau_s", "bias_tau_s"), ("slope_bias_sigma_mps", "degraded_bias_sigma_mps"),
                     ("slope_bias_tau_s", "degraded_bias_tau_s"), ("beam_angle_rad", "beam_angle_rad")):
        if src in dvl:
            # a noiseless simulated DVL is described with the smallest plausible noise (semslam.limits), as depth
            d["dvl"][dst] = max(dvl[src], 1.0) if dst == "degraded_noise_factor" else \
                max(dvl[src], 1e-4) if dst == "noise_abs_mps" else dvl[src]
    if "noise_rpy_rad" in ahrs:
        d["attitude"]["noise_rpy_rad"] = list(ahrs["noise_rpy_rad"])
    if "yaw_bias_walk_rad_per_sqrt_s" in ahrs:
        d["attitude"]["yaw_bias_walk_rad_per_sqrt_s"] = ahrs["yaw_bias_walk_rad_per_sqrt_s"]
    if "noise_m" in depth:
        d["depth"]["noise_m"] = max(depth["noise_m"], 1e-4)
    for src, dst in (("max_range_m", "max_range_m"), ("min_range_m", "min_range_m"), ("scan_rate_hz", "rate_hz"),
                     ("n_lines", "line_count")):
        if src in sc:
            d["scanner"][dst] = sc[src]
    if "sweep_fov_rad" in sc:
        d["scanner"]["fov_rad"] = min(sc["sweep_fov_rad"], sc.get("line_fov_rad", sc["sweep_fov_rad"]))
    if "baseline_m" in sc:  # the simulated triangulation scanner's camera: along the scanner's x axis
        d["scanner"]["camera_xyz_m"] = [float(sc["baseline_m"]), 0.0, 0.0]
    return VehicleDescription.from_dict(d, source=source)


def _read_fixes(path: Path) -> PositionFixLog:
    head, rows = _read_rows(path, _FIXES)
    try:
        v = np.array([r[:6] for r in rows], dtype=float).reshape(len(rows), 6)
    except ValueError:
        raise DatasetError(f"The mission file {str(path)!r} must hold numbers in its first six columns.") from None
    cov = np.stack([v[:, 3], v[:, 4], v[:, 4], v[:, 5]], axis=-1).reshape(-1, 2, 2)
    return _log(path, PositionFixLog, v[:, 0], v[:, 1:3], cov, tuple(r[6] for r in rows))


def _read_objects(path: Path) -> list[ObjectTruth]:
    out = []
    for i, r in enumerate(_read_rows(path, _OBJECTS)[1], start=2):
        try:
            vals = np.array(r[3:], dtype=float)
            if r[2] not in ("0", "1"):
                raise ValueError(f"in_database must be 0 or 1, got {r[2]!r}")
            T = RigidTransform.from_quat_wxyz(vals[3:], vals[:3])
        except (ValueError, SemslamError) as exc:
            raise DatasetError(f"The mission file {str(path)!r} line {i} is malformed: {exc}") from None
        out.append(ObjectTruth(name=r[0], label=r[1], T_world_object=T, in_database=r[2] == "1"))
    return out


def _read_index(path: Path) -> list[ScanRecord]:
    out = []
    for i, r in enumerate(_read_rows(path, _INDEX)[1], start=2):
        try:
            rec = ScanRecord(int(r[0]), float(r[1]), float(r[2]), r[3], int(r[4]))
        except ValueError as exc:
            raise DatasetError(f"The mission file {str(path)!r} line {i} is malformed: {exc}") from None
        if not (path.parent.parent / rec.path).is_file():
            raise DatasetError(f"The scan file {rec.path!r} listed in {str(path)!r} line {i} is missing.")
        out.append(rec)
    return out
