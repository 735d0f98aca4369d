"""Object models from a user's own scans: align each class's views into one object frame.

``semslam db build VIEWS_DIR --fuse`` reads ``VIEWS_DIR/CLASS/*.pcd`` recorded in their own sensor frames
(a camera on a tripod or a vehicle, the object still) and brings every class's views into one object frame,
so that the poses of later detections mean the same thing from scan to scan and the pose estimator has a
fused model to align to.

Sensor poses come from ``CLASS/poses.csv`` when present (:func:`read_poses_csv`: one row per view, the
sensor pose ``T_object_sensor`` in any frame fixed to the object -- a rig, a world frame), or are estimated:
the views are taken in name order and each is registered onto the union of those already placed, with the
gravity-aligned registration (:func:`~semslam.registration.align_upright`) when the sensors' up direction
is given (``up_sensor``: one direction for every view, or one per view -- a camera pitched differently from
view to view, a vehicle's attitude -- from ``CLASS/up.csv``, :func:`read_up_csv`), else the 6-DoF feature
registration. Either way each view is then refined onto the union of the others by point-to-plane ICP (4-DoF
about up when it is known), ``refine_rounds`` times.

The object frame is the first view's sensor frame (or the poses' frame), moved to the centre of the fused
model's bounding box. Every fused view keeps its sensor origin as ``viewpoint_xyz_m``.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.spatial import cKDTree

from ..cloud import PointCloud
from ..errors import DatabaseError, RegistrationError
from ..geometry import RigidTransform, rotation_from_quat_wxyz
from ..registration import UprightConfig, align_icp, align_upright, register
from ..registration._upright_kernels import point_to_plane_4dof, target_normals

__all__ = ["FusionReport", "fuse_class_views", "read_poses_csv", "read_up_csv"]

_QUAT_COLUMNS = ("view", "x_m", "y_m", "z_m", "qw", "qx", "qy", "qz")
_MATRIX_COLUMNS = ("view",) + tuple(f"t{r}{c}" for r in range(4) for c in range(4))
_UP_COLUMNS = ("view", "x", "y", "z")
#: size cap of a poses.csv / up.csv (a row per view: far more than any class has)
MAX_CSV_BYTES = 16 << 20
#: rotation tolerance of a poses.csv matrix (max |R^T R - I|, |det R - 1|)
ROTATION_TOLERANCE = 1e-3
#: a view is registered onto the union of the views before it in one direction: the union shows what the view
#: does not, so scoring the union's points too (the symmetric registration between two views) would penalise it
_ONE_WAY = UprightConfig(symmetric=False)


@dataclass
class FusionReport:
    """How one class was fused: the source of the poses, each view's residual onto the others (RMS of
    the inlier distances, metres) and fitness, and the views whose alignment is doubtful."""

    label: str
    poses: str
    up_object: list | None = None
    rms_m: dict = field(default_factory=dict)
    fitness: dict = field(default_factory=dict)
    doubtful: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"label": self.label, "poses": self.poses, "up_object": self.up_object, "rms_m": self.rms_m,
                "fitness": self.fitness, "doubtful": self.doubtful}


def read_poses_csv(path: str | Path, view_ids: Sequence[str]) -> dict[str, np.ndarray]:
    """``T_object_sensor`` (4x4) of every view in ``view_ids`` from a CSV file.

    Two layouts, chosen by the header: ``view,x_m,y_m,z_m,qw,qx,qy,qz`` (translation and unit quaternion)
    or ``view,t00,t01,...,t33`` (the 4x4 matrix row by row). ``view`` is the file's stem. Raises
    :class:`~semslam.errors.DatabaseError` naming the file and the row for a missing or unknown view, a
    non-number, a quaternion that is not unit length, or a matrix that is not a rigid transform.
    """
    where = str(path)
    header, rows = _read_view_rows(path, "poses", (_QUAT_COLUMNS, _MATRIX_COLUMNS),
                                   f"{','.join(_QUAT_COLUMNS)} or view,t00,...,t33", view_ids, "its sensor pose")
    return {view: _pose_from_values(values, header == _QUAT_COLUMNS, f"line {lineno} of the poses file {where!r} "
                                    f"(view {view!r})") for view, (lineno, values) in rows.items()}


def read_up_csv(path: str | Path, view_ids: Sequence[str]) -> dict[str, np.ndarray]:
    """The up direction of every view in its own sensor frame (unit vector) from a CSV file with the header
    ``view,x,y,z`` (any length; ``view`` is the file's stem): for views whose sensors were not all held the same
    way (a camera pitched differently from view to view, a vehicle's attitude). Raises
    :class:`~semslam.errors.DatabaseError` naming the file and the row for a missing or unknown view, a
    non-number, or a zero direction."""
    where = str(path)
    _, rows = _read_view_rows(path, "up", (_UP_COLUMNS,), ",".join(_UP_COLUMNS), view_ids, "its up direction")
    ups = {}
    for view, (lineno, values) in rows.items():
        scale = np.abs(values).max()
        if not scale > 0:
            raise DatabaseError(f"Line {lineno} of the up file {where!r} (view {view!r}) gives a zero direction; "
                                f"expected the sensor's up, e.g. 0,-1,0 for a level camera with y down.")
        u = values / scale
        ups[view] = u / np.linalg.norm(u)
    return ups


def _read_view_rows(path: str | Path, what: str, headers: tuple, expected: str, view_ids: Sequence[str],
                    needs: str) -> tuple[tuple, dict[str, tuple[int, np.ndarray]]]:
    """``(header, {view: (line number, finite float values)})`` of a per-view CSV file, one row for every view
    in ``view_ids`` and no other; a regular file of at most :data:`MAX_CSV_BYTES`."""
    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise DatabaseError(f"The {what} file {where!r} is not a regular file.")
    if path.stat().st_size > MAX_CSV_BYTES:
        raise DatabaseError(f"The {what} file {where!r} must be at most {MAX_CSV_BYTES} bytes. "
                            f"Got {path.stat().st_size} instead.")
    try:
        with path.open(newline="", encoding="utf-8") as f:
            lines = list(csv.reader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DatabaseError(f"Cannot read the {what} file {where!r}: {exc}.") from None
    if not lines:
        raise DatabaseError(f"The {what} file {where!r} is empty; expected a header {expected}.")
    header = tuple(c.strip() for c in lines[0])
    if header not in headers:
        raise DatabaseError(f"The {what} file {where!r} must start with the header {expected}. "
                            f"Got {','.join(header)!r} instead.")
    rows: dict[str, tuple[int, np.ndarray]] = {}
    for lineno, row in enumerate(lines[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise DatabaseError(
                f"Line {lineno} of the {what} file {where!r} has {len(row)} fields; expected {len(header)}."
            )
        view = row[0].strip()
        try:
            values = np.array([float(v) for v in row[1:]])
        except ValueError:
            raise DatabaseError(f"Line {lineno} of the {what} file {where!r} (view {view!r}) holds a value that is "
                                f"not a number: {row[1:]}.") from None
        if not np.all(np.isfinite(values)):
            raise DatabaseError(f"Line {lineno} of the {what} file {where!r} (view {view!r}) holds NaN or infinity.")
        if view in rows:
            raise DatabaseError(f"The {what} file {where!r} gives view {view!r} twice (line {lineno}).")
        rows[view] = (lineno, values)
    missing = [v for v in view_ids if v not in rows]
    if missing:
        raise DatabaseError(f"The {what} file {where!r} has no row for the view(s) {', '.join(missing)}; "
                            f"every view of the class needs {needs}.")
    unknown = sorted(set(rows) - set(view_ids))
    if unknown:
        raise DatabaseError(f"The {what} file {where!r} names view(s) {', '.join(unknown)} that are not in its folder.")
    return header, rows


def _pose_from_values(values: np.ndarray, quaternion: bool, where: str) -> np.ndarray:
    T = np.eye(4)
    if quaternion:
        q = values[3:]
        if abs(np.linalg.norm(q) - 1.0) > ROTATION_TOLERANCE:
            raise DatabaseError(
                f"The quaternion on {where} must have unit length. Got norm {np.linalg.norm(q):.6g} instead."
            )
        T[:3, :3], T[:3, 3] = rotation_from_quat_wxyz(q / np.linalg.norm(q)), values[:3]
        return T
    T = values.reshape(4, 4)
    R = T[:3, :3]
    if (np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-9 or np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOLERANCE
            or abs(np.linalg.det(R) - 1.0) > ROTATION_TOLERANCE):
        raise DatabaseError(f"The matrix on {where} is not a rigid transform (an orthonormal rotation with "
                            f"determinant +1 and last row 0 0 0 1). Got rotation {np.round(R, 4).tolist()}, "
                            f"last row {T[3].tolist()}.")
    return T.copy()


def fuse_class_views(label: str, clouds: Sequence[tuple[str, PointCloud]], *, poses: dict | None = None,
                     up_sensor: Any = None, refine_rounds: int = 2, seed: int = 0) -> tuple[list, FusionReport]:
    """Bring one class's views ``[(view_id, cloud in its sensor frame), ...]`` into one object frame.

    Returns ``[(view_id, cloud in the object frame with its viewpoint), ...]`` in the input order and a
    :class:`FusionReport`. ``poses``: ``{view_id: T_object_sensor}`` for every view, else estimated.
    ``up_sensor``: the up direction in the sensors' frame, one (3,) for every view or ``{view_id: (3,)}``.
    """
    ids = [v for v, _ in clouds]
    pts = [np.asarray(c.points_xyz_m, dtype=float) for _, c in clouds]
    ups = _view_ups(up_sensor, ids, label)
    if poses is not None:
        Ts = [np.asarray(poses[v], dtype=float) for v in ids]
        source = "poses.csv"
    else:
        Ts = _estimate(pts, ups, seed, label, ids)
        source = "estimated (upright registration)" if ups is not None else "estimated (feature registration)"
    report = FusionReport(label, source)
    up_object = None if ups is None else _mean_direction([T[:3, :3] @ u for T, u in zip(Ts, ups)])
    for _ in range(refine_rounds if len(pts) > 1 else 0):
        for i in range(len(pts)):
            others = np.concatenate([_apply(Ts[j], pts[j]) for j in range(len(pts)) if j != i])
            Ts[i] = _refine(pts[i], others, Ts[i], up_object)
    for i in range(len(pts)):
        if len(pts) == 1:
            break
        others = np.concatenate([_apply(Ts[j], pts[j]) for j in range(len(pts)) if j != i])
        d = cKDTree(others).query(_apply(Ts[i], pts[i]))[0]
        mc = 3.0 * _spacing(others)
        inl = d < mc
        report.fitness[ids[i]] = float(inl.mean())
        report.rms_m[ids[i]] = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("nan")
        if inl.mean() < 0.3:
            report.doubtful.append(ids[i])
    if ups is not None:  # the up direction in the object frame: the sensors' up turned by their poses, averaged
        report.up_object = _mean_direction([T[:3, :3] @ u for T, u in zip(Ts, ups)]).tolist()
    fused = np.concatenate([_apply(T, p) for T, p in zip(Ts, pts)])
    centre = 0.5 * (fused.min(axis=0) + fused.max(axis=0))
    out = []
    for (view_id, cloud), T, p in zip(clouds, Ts, pts):
        T_obj = T.copy()
        T_obj[:3, 3] -= centre
        vp = T_obj[:3, :3] @ np.asarray(cloud.viewpoint_xyz_m, dtype=float) + T_obj[:3, 3]
        out.append((view_id, PointCloud(_apply(T_obj, p), viewpoint_xyz_m=vp, frame_id="object")))
    return out, report


def _apply(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ T[:3, :3].T + T[:3, 3]


def _spacing(p: np.ndarray) -> float:
    return float(np.median(cKDTree(p).query(p, 2)[0][:, 1]))


def _view_ups(up_sensor: Any, ids: list, label: str) -> list | None:
    """One unit up direction per view (sensor frame), or None."""
    if up_sensor is None:
        return None
    if isinstance(up_sensor, dict):
        missing = [v for v in ids if v not in up_sensor]
        if missing:
            raise DatabaseError(f"No up direction for the view(s) {', '.join(missing)} of class {label!r}.")
        raw = [np.asarray(up_sensor[v], dtype=float) for v in ids]
    else:
        raw = [np.asarray(up_sensor, dtype=float)] * len(ids)
    out = []
    for v, u in zip(ids, raw):
        if u.shape != (3,) or not np.all(np.isfinite(u)) or not np.abs(u).max() > 0:
            raise DatabaseError(f"The up direction of view {v!r} of class {label!r} must be 3 finite numbers, not all "
                                f"zero. Got {u.tolist()} instead.")
        u = u / np.abs(u).max()
        out.append(u / np.linalg.norm(u))
    return out


def _mean_direction(vectors: list) -> np.ndarray:
    m = np.mean(vectors, axis=0)
    return m / np.linalg.norm(m)


def _estimate(pts: list, ups: list | None, seed: int, label: str, ids: list) -> list:
    """Sensor poses in the first view's frame: each view registered onto the union of those before it (about
    the first view's up when the ups are known: each view's own up is turned onto it)."""
    Ts = [np.eye(4)]
    for i in range(1, len(pts)):
        model = np.concatenate([_apply(T, p) for T, p in zip(Ts, pts[:i])])
        try:
            if ups is not None:
                # one direction: a view onto the union of the views before it (that shows what it does not)
                res = align_upright(pts[i], model, up_source=ups[i], up_target=ups[0], config=_ONE_WAY)
            else:
                res = register(pts[i], model, seed=seed)
        except RegistrationError as exc:
            raise DatabaseError(
                f"Cannot align view {ids[i]!r} of class {label!r} onto the views before it: {exc}"
            ) from None
        Ts.append(np.asarray(res.T_target_source.matrix))
    return Ts


def _refine(p: np.ndarray, model: np.ndarray, T: np.ndarray, up: np.ndarray | None) -> np.ndarray:
    """``T`` refined by point-to-plane ICP of ``p`` onto ``model`` (yaw about ``up``, a direction in the object
    frame, + translation if given)."""
    mc = 3.0 * _spacing(model)
    if up is None:
        res = align_icp(p, model, init_T=RigidTransform(T), method="plane", max_correspondence_m=mc, max_iterations=30)
        return np.asarray(res.T_target_source.matrix)
    tree = cKDTree(model)
    R, t, _, _ = point_to_plane_4dof(p, tree, model, target_normals(model, tree), T[:3, :3], T[:3, 3], up, mc, 30)
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, t
    return out


def build_fused_database(views_dir: str | Path, *, up_sensor: Any = None, clean: bool = True, refine_rounds: int = 2,
                         seed: int = 0, progress: Any = None, **kwargs: Any):
    """``semslam db build VIEWS_DIR --fuse``: read the folder (views in their sensor frames), fuse every class
    (``CLASS/poses.csv`` when present, else estimated; see the module docstring) and build the database of
    the fused views, which are also the pose model. ``classes.json`` works as without fusion; sizes not given
    there are the fused model's bounding box. The database's ``params["fusion"]`` records, per class, where
    the poses came from, the up direction in the object frame (``up_object``, with ``up_sensor``: it lets the
    pipeline keep the object upright, :class:`~semslam.pipeline.PipelineConfig` ``up_scanner``) and the views whose
    alignment is doubtful (under 30 % of their points within three
    point spacings of the other views). Keyword arguments go to :func:`~semslam.recognition.build_database`.
    """
    from .build import build_database, folder_classes, read_view_folder

    views, declared, meta_path = read_view_folder(views_dir, clean=clean)
    root = Path(views_dir)
    fused: list = []
    reports = {}
    for label in sorted({v[0] for v in views}):
        items = [(vid, c) for lab, vid, c in views if lab == label]
        poses_path = root / label / "poses.csv"
        poses = read_poses_csv(poses_path, [vid for vid, _ in items]) if poses_path.exists() else None
        up_path = root / label / "up.csv"
        ups = read_up_csv(up_path, [vid for vid, _ in items]) if up_path.exists() else up_sensor
        out, rep = fuse_class_views(label, items, poses=poses, up_sensor=ups, refine_rounds=refine_rounds, seed=seed)
        fused += [(label, vid, c) for vid, c in out]
        reports[label] = {"poses": rep.poses, "doubtful": rep.doubtful, "up_object": rep.up_object,
                          "median_rms_m": float(np.nanmedian(list(rep.rms_m.values()))) if rep.rms_m else None}
    from .preprocessing import ViewPreprocessing  # the cleaning is recorded, applied to queries

    db = build_database(fused, folder_classes(fused, declared, meta_path), seed=seed, progress=progress,
                        preprocessing=ViewPreprocessing(clean=bool(clean)), views_preprocessed=True, **kwargs)
    object.__setattr__(db, "params", {**db.params, "fusion": reports})
    return db
