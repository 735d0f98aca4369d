"""The view database: partial views of known objects with their global descriptors, in one versioned file.

Each stored view has a class label, a view id, its points in the object's canonical frame (pose
estimation aligns them to a scanned cluster), the sensor viewpoint in that frame, an ESF (640 bins) and a
VFH (308 bins). Each class has a :class:`~semslam.symmetry.Symmetry` and a bounding-box size.

File format (``FORMAT_NAME`` version ``FORMAT_VERSION``): an uncompressed ``.npz`` written with
``np.savez`` (no pickle; loaded with ``allow_pickle=False``) holding

* ``meta``: 0-d str, JSON with format, version, classes, build parameters and checksums;
* ``labels``, ``view_ids``: (V,) str, class label and view id (unique within the class) of every view;
* ``point_offsets``: (V+1,) int64, view ``i`` owns rows ``point_offsets[i]:point_offsets[i+1]`` of ``points_xyz_m``;
* ``points_xyz_m``: (P, 3) float32, all views' points in their object frame, metres;
* ``viewpoints_xyz_m``: (V, 3) float64, sensor origin of every view, object frame, metres;
* ``esf``: (V, 640) float32 and ``vfh``: (V, 308) float32 (VFH variant in ``meta``);
* (version 2) the POSE-MODEL views, optional per class, that pose estimation fuses instead of the
  recognition views (e.g. closer, less noisy views that see more of the sides; no descriptors):
  ``model_labels`` (M,) str, ``model_point_offsets`` (M+1,) int64, ``model_points_xyz_m`` (Q, 3) float32
  and ``model_viewpoints_xyz_m`` (M, 3) float64, laid out like the views (M may be 0).

Version 3 records in ``meta["params"]["preprocessing"]`` what was done to the views before their descriptors
(cleaning, range limits, the views' spacing after the voxel grid; :mod:`~semslam.recognition.preprocessing`),
which :meth:`ViewDatabase.describe` applies to every query. Version-2 files read with an unknown preprocessing
(nothing applied to queries, as before). Version-1 files (no pose-model views) are still read: their classes'
pose models are their views.

This module holds the data model (:class:`ViewDatabase`, :class:`ClassInfo`) and its consistency checks; the
descriptors are computed in :mod:`~semslam.recognition.view_descriptors`, databases built in
:mod:`~semslam.recognition.build` and stored in :mod:`~semslam.recognition.storage` (their public names are
importable from here too).

The checksums are CRC-32 of every array's bytes (on top of the zip's own CRC of every member). Points
are float32 (0.1 micrometre resolution at 1 m) and descriptors float32 (PCL's signatures are float32):
10,000 views of ~1,000 points make a 160 MB file that loads in ~0.5 s (benchmarks/database.py).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._validation import as_float_array, check_int
from ..cloud import PointCloud
from ..errors import DatabaseError, InputError, SemslamError
from ..symmetry import Symmetry
from .preprocessing import ViewPreprocessing
from .view_descriptors import (AUTO, AUTO_RULE, DEFAULT_NORMAL_RADIUS_M, DEFAULT_VOXEL_LEAF_M, DESCRIPTORS, ESF_BINS,
                               VFH_BINS, ViewDescriptors, combine_descriptors, compute_view_descriptors,
                               resolve_descriptor_lengths)

FORMAT_NAME = "semslam-view-database"
FORMAT_VERSION = 3
#: Older format versions :func:`load_database` still reads (their preprocessing reads as unknown).
READABLE_VERSIONS = (1, 2, 3)
_ARRAYS = ("labels", "view_ids", "point_offsets", "points_xyz_m", "viewpoints_xyz_m", "esf", "vfh")
_MODEL_ARRAYS = ("model_labels", "model_point_offsets", "model_points_xyz_m", "model_viewpoints_xyz_m")

__all__ = [
    "AUTO",
    "AUTO_RULE",
    "DEFAULT_NORMAL_RADIUS_M",
    "DEFAULT_VOXEL_LEAF_M",
    "DESCRIPTORS",
    "ESF_BINS",
    "VFH_BINS",
    "combine_descriptors",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "ClassInfo",
    "ViewDatabase",
    "ViewDescriptors",
    "compute_view_descriptors",
    "resolve_descriptor_lengths",
]


@dataclass(frozen=True, eq=False)
class ClassInfo:
    """What the database knows about one object class.

    Attributes
    ----------
    label : str
    symmetry : Symmetry
        In the object's canonical frame.
    size_xyz_m : ndarray of shape (3,)
        Bounding-box extent along the object's x, y, z axes, metres.
    """

    label: str
    symmetry: Symmetry
    size_xyz_m: np.ndarray

    def __post_init__(self) -> None:
        if not isinstance(self.symmetry, Symmetry):
            raise InputError(f"The 'symmetry' of class {self.label!r} must be a semslam.symmetry.Symmetry. "
                             f"Got {type(self.symmetry).__name__} instead.")
        size = as_float_array("size_xyz_m", self.size_xyz_m, (3,), caller=f"class {self.label!r}")
        if (size < 0).any():
            raise InputError(f"The 'size_xyz_m' of class {self.label!r} must be >= 0. Got {size.tolist()} instead.")
        size.setflags(write=False)
        object.__setattr__(self, "size_xyz_m", size)

    def to_dict(self) -> dict:
        return {"symmetry": self.symmetry.to_dict(), "size_xyz_m": self.size_xyz_m.tolist()}


@dataclass(frozen=True, eq=False)
class ViewDatabase:
    """Partial views of known objects with their descriptors (see the module docstring).

    Build with :func:`build_database` / :func:`build_database_from_folder`, store with
    :func:`save_database`, read with :func:`load_database`. Arrays are read-only.

    Attributes
    ----------
    labels : ndarray of str, shape (V,)
    view_ids : ndarray of str, shape (V,)
    point_offsets : ndarray of int64, shape (V + 1,)
    points_xyz_m : ndarray of float32, shape (P, 3)
        All views' points, object frame.
    viewpoints_xyz_m : ndarray of float64, shape (V, 3)
        Sensor origin of every view, object frame.
    esf : ndarray of float32, shape (V, 640)
    vfh : ndarray of float32, shape (V, 308)
    class_infos : dict of str to ClassInfo
    params : dict
        How the descriptors were computed (``vfh_variant``, ``normal_radius_m``, ``esf_n_samples``,
        ``voxel_leaf_m`` -- absent or None in databases built without a voxel grid --, ``seed``); with
        ``"auto"`` lengths also ``spacing_m``, ``vfh_scale``, ``auto`` (which lengths were auto) and ``auto_rule``
        (the lengths themselves are stored resolved, in the views' unit).
    model_labels : ndarray of str, shape (M,)
        Class of every pose-model view (M may be 0; see :meth:`pose_views`).
    model_point_offsets : ndarray of int64, shape (M + 1,)
    model_points_xyz_m : ndarray of float32, shape (Q, 3)
        All pose-model views' points, object frame.
    model_viewpoints_xyz_m : ndarray of float64, shape (M, 3)
        Sensor origin of every pose-model view, object frame.
    """

    labels: np.ndarray
    view_ids: np.ndarray
    point_offsets: np.ndarray
    points_xyz_m: np.ndarray
    viewpoints_xyz_m: np.ndarray
    esf: np.ndarray
    vfh: np.ndarray
    class_infos: Mapping[str, ClassInfo]
    params: Mapping[str, Any] = field(default_factory=dict)
    model_labels: np.ndarray = field(default_factory=lambda: np.zeros(0, "<U1"))
    model_point_offsets: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    model_points_xyz_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    model_viewpoints_xyz_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float64))

    def __post_init__(self) -> None:
        object.__setattr__(self, "class_infos", _class_infos(self.class_infos, "ViewDatabase", allow_empty=True))
        _check_consistency(self, "ViewDatabase", InputError)
        for name in _ARRAYS + _MODEL_ARRAYS:
            getattr(self, name).setflags(write=False)
        object.__setattr__(self, "params", dict(self.params))

    # -- sizes and lookups -------------------------------------------------------------------------
    @property
    def n_views(self) -> int:
        return len(self.labels)

    def __len__(self) -> int:
        return len(self.labels)

    @property
    def classes(self) -> tuple[str, ...]:
        """Class labels, sorted."""
        return tuple(sorted(self.class_infos))

    @property
    def vfh_variant(self) -> str:
        return str(self.params.get("vfh_variant", ""))

    def class_info(self, label: str) -> ClassInfo:
        """Symmetry and size of class ``label``; DatabaseError if the class is not stored."""
        try:
            return self.class_infos[label]
        except KeyError:
            raise DatabaseError(
                f"The class {label!r} is not in the database. Known classes: {', '.join(self.classes)}."
            ) from None

    def symmetries(self) -> dict:
        """``{class: Symmetry}``: what SLAM needs to know of each class (:func:`semslam.run.run_slam`)."""
        return {c: info.symmetry for c, info in self.class_infos.items()}

    def up_object(self, label: str) -> list | None:
        """The class's up direction in its object frame, when the database records it: from its resting pose for
        models (``params["up_object"]``, :func:`semslam.simulation.cad_models.resting_up_objects`) or from fusion
        with an up (``params["fusion"][label]["up_object"]``); else None."""
        up = (self.params.get("up_object") or {}).get(label)
        if up is None:
            up = ((self.params.get("fusion") or {}).get(label) or {}).get("up_object")
        return None if up is None else [float(v) for v in up]

    @property
    def scanner_camera_xyz_m(self) -> tuple | None:
        """The camera of the triangulation laser scanner the views were rendered with (scanner frame, from the
        laser; ``params["scanner_camera_xyz_m"]``, written by a laser database's build), or None (another sensor, or
        not recorded): a query from that scanner has the camera's shadows too
        (``PipelineConfig.verify_camera_shadows``)."""
        cam = self.params.get("scanner_camera_xyz_m")
        if cam is None:
            return None
        vals = np.asarray(cam, dtype=object).ravel()
        try:
            xyz = tuple(float(v) for v in vals) if vals.size == 3 else ()
        except (TypeError, ValueError):
            xyz = ()
        if len(xyz) != 3 or not all(np.isfinite(xyz)):
            raise DatabaseError(f"The view database's 'scanner_camera_xyz_m' must be three finite numbers (metres). "
                                f"Got {cam!r:.80} instead.")
        return xyz

    def up_objects(self, label: str) -> list | None:
        """The class's possible up directions in its object frame: ``[up]`` when :meth:`up_object` records one,
        the up of each of two about equally probable resting poses when the database records them
        (``params["up_object_tied"]``: a part that lies on either face), else None."""
        up = self.up_object(label)
        if up is not None:
            return [up]
        tied = (self.params.get("up_object_tied") or {}).get(label)
        return None if not tied else [[float(v) for v in u] for u in tied]

    def views_of(self, label: str) -> np.ndarray:
        """Indices of the views of class ``label`` (int array)."""
        self.class_info(label)
        return np.flatnonzero(self.labels == label)

    def view_counts(self) -> dict[str, int]:
        """Number of views of every class."""
        return {c: int(np.count_nonzero(self.labels == c)) for c in self.classes}

    def _check_index(self, i: Any) -> int:
        return check_int("i", i, caller="ViewDatabase", minimum=0, maximum=self.n_views - 1)

    def view_points(self, i: int) -> np.ndarray:
        """Points of view ``i`` in the object frame, float64 array of shape (n_i, 3), metres."""
        i = self._check_index(i)
        return self.points_xyz_m[self.point_offsets[i]:self.point_offsets[i + 1]].astype(np.float64)

    def view_cloud(self, i: int) -> PointCloud:
        """View ``i`` as a PointCloud in the object frame (``frame_id="object"``) with its viewpoint."""
        i = self._check_index(i)
        return PointCloud(self.view_points(i), viewpoint_xyz_m=self.viewpoints_xyz_m[i], frame_id="object")

    def view_directions(self) -> np.ndarray:
        """Unit viewing direction of every view (V, 3), object frame: from the view's centroid to its sensor
        origin; NaN where they coincide. Views recorded in their own sensor frames (not fused into one
        object frame) all point the same way, which the rejection's calibration reads as one viewpoint."""
        sums = np.add.reduceat(self.points_xyz_m.astype(np.float64), self.point_offsets[:-1], axis=0)
        centroids = sums / np.diff(self.point_offsets)[:, None]
        d = self.viewpoints_xyz_m - centroids
        n = np.linalg.norm(d, axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n > 1e-12, d / n, np.nan)

    def pose_views(self, label: str) -> list[PointCloud]:
        """The views pose estimation fuses for class ``label``, object frame, with their viewpoints.

        The class's pose-model views when the database stores some (format version 2), else its
        recognition views.
        """
        self.class_info(label)
        idx = np.flatnonzero(self.model_labels == label)
        if idx.size == 0:
            return [self.view_cloud(int(i)) for i in self.views_of(label)]
        off = self.model_point_offsets
        return [PointCloud(self.model_points_xyz_m[off[i]:off[i + 1]].astype(np.float64),
                           viewpoint_xyz_m=self.model_viewpoints_xyz_m[i], frame_id="object") for i in idx]

    def features(self, descriptor: str) -> np.ndarray:
        """Descriptor matrix of every view, float64.

        ``"esf"`` (V, 640) and ``"vfh"`` (V, 308) are the raw histograms; ``"esf+vfh"`` (V, 948) is both,
        each scaled to sum 1 per view first so that neither dominates (see :func:`combine_descriptors`).
        """
        return combine_descriptors(descriptor, self.esf, self.vfh)

    # -- queries --------------------------------------------------------------------------------
    @property
    def preprocessing(self) -> ViewPreprocessing:
        """What was done to the views before their descriptors (``params["preprocessing"]``), and is done to every
        query by :meth:`describe`: see :mod:`~semslam.recognition.preprocessing`. Databases of format versions 1
        and 2 read as unknown (nothing applied); one built in memory without a record as none."""
        return ViewPreprocessing.from_dict(self.params.get("preprocessing"), "The view database")

    def describe(self, cloud: PointCloud, *, seed: int | np.random.Generator = 0,
                 concurrent: bool = True) -> ViewDescriptors:
        """Descriptors of a query cloud computed exactly as the stored views' (same parameters).

        The database's recorded preprocessing (:attr:`preprocessing`: range limits, cleaning of sensor-origin
        points and drawn lines) is applied to the query first, as it was to the views; a query it leaves empty,
        or too sparse for the views' density, is a :class:`~semslam.errors.DescriptorError`.
        The database's voxel grid (``params["voxel_leaf_m"]``, if any) is applied to the query first, so
        that queries and views have the same point density (a cluster already on that grid, as
        :func:`~semslam.segmentation.segment_scene` outputs it, changes little). A database built with
        ``"auto"`` lengths describes queries with its resolved lengths and ``vfh_scale`` (``params``): queries
        must be in the views' unit.
        """
        cloud = self.preprocessing.apply(cloud, name="query")
        return compute_view_descriptors(
            cloud, vfh_variant=self.params.get("vfh_variant"),
            normal_radius_m=self.params.get("normal_radius_m", DEFAULT_NORMAL_RADIUS_M),
            esf_n_samples=self.params.get("esf_n_samples", 20000), voxel_leaf_m=self.params.get("voxel_leaf_m"),
            seed=seed, concurrent=concurrent, vfh_scale=self.params.get("vfh_scale", 1.0))

    def subset(self, indices: Any) -> ViewDatabase:
        """A database with the given views only (order kept); classes without views are dropped."""
        idx = np.asarray(indices, dtype=np.int64).ravel()
        if idx.size and (idx.min() < 0 or idx.max() >= self.n_views):
            raise InputError(f"The 'indices' argument of ViewDatabase.subset must be in [0, {self.n_views}). "
                             f"Got values from {idx.min()} to {idx.max()} instead.")
        counts = np.diff(self.point_offsets)[idx]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        rows = np.concatenate([np.arange(self.point_offsets[i], self.point_offsets[i + 1]) for i in idx]) \
            if idx.size else np.zeros(0, np.int64)
        kept = set(self.labels[idx].tolist())
        midx = np.flatnonzero(np.isin(self.model_labels, sorted(kept)))
        moff = self.model_point_offsets
        mcounts = np.diff(moff)[midx]
        mrows = np.concatenate([np.arange(moff[i], moff[i + 1]) for i in midx]) if midx.size else np.zeros(0, np.int64)
        return ViewDatabase(self.labels[idx].copy(), self.view_ids[idx].copy(), offsets,
                            self.points_xyz_m[rows].copy(), self.viewpoints_xyz_m[idx].copy(),
                            self.esf[idx].copy(), self.vfh[idx].copy(),
                            {k: v for k, v in self.class_infos.items() if k in kept}, self.params,
                            self.model_labels[midx].copy(), np.concatenate([[0], np.cumsum(mcounts)]).astype(np.int64),
                            self.model_points_xyz_m[mrows].copy(), self.model_viewpoints_xyz_m[midx].copy())

    def summary(self) -> dict:
        """A JSON-friendly description: classes, views per class, symmetry, size, descriptor settings."""
        counts = self.view_counts()
        return {
            "format": FORMAT_NAME, "version": FORMAT_VERSION, "n_views": self.n_views,
            "n_points": len(self.points_xyz_m),
            "n_model_views": len(self.model_labels),
            "classes": {c: {"n_views": counts[c], "n_model_views": int(np.count_nonzero(self.model_labels == c)),
                            **self.class_infos[c].to_dict()} for c in self.classes},
            "descriptors": {"esf": {"bins": ESF_BINS, "n_samples": self.params.get("esf_n_samples")},
                            "vfh": {"bins": VFH_BINS, "variant": self.vfh_variant,
                                    "normal_radius_m": self.params.get("normal_radius_m")}},
            "preprocessing": self.preprocessing.describe(),
            "params": dict(self.params),
        }

    def __repr__(self) -> str:
        return f"ViewDatabase(n_views={self.n_views}, classes={list(self.classes)}, vfh_variant={self.vfh_variant!r})"


def _class_infos(classes: Mapping[str, Any], caller: str, allow_empty: bool = False) -> dict[str, ClassInfo]:
    if not isinstance(classes, Mapping) or not (classes or allow_empty):
        raise InputError(f"The 'classes' argument of {caller} must be a non-empty dict label -> "
                         f"{{'symmetry', 'size_xyz_m'}}. Got {classes!r:.60} instead.")
    out = {}
    for label, info in classes.items():
        if isinstance(info, ClassInfo):
            out[str(label)] = ClassInfo(str(label), info.symmetry, info.size_xyz_m)
            continue
        if not isinstance(info, Mapping) or "symmetry" not in info or "size_xyz_m" not in info:
            raise InputError(f"The entry {label!r} of 'classes' of {caller} must have 'symmetry' and 'size_xyz_m'. "
                             f"Got {info!r:.80} instead.")
        sym = info["symmetry"]
        if isinstance(sym, Mapping):
            sym = Symmetry.from_dict(dict(sym))
        out[str(label)] = ClassInfo(str(label), sym, info["size_xyz_m"])
    if "unknown" in out:
        raise InputError(f"The class label 'unknown' of {caller} is reserved for rejected objects.")
    return out


# -- consistency (of a built or a loaded database) ---------------------------------------------------


def _check_consistency(db: ViewDatabase, where: str, error: type[SemslamError]) -> None:
    """Shapes, dtypes, offsets and labels agree; raise ``error`` naming ``where`` otherwise."""
    expected = {"labels": ("U", 1), "view_ids": ("U", 1), "point_offsets": ("i", 1), "points_xyz_m": ("f", 2),
                "viewpoints_xyz_m": ("f", 2), "esf": ("f", 2), "vfh": ("f", 2)}
    for name, (kind, ndim) in expected.items():
        arr = getattr(db, name)
        if not isinstance(arr, np.ndarray) or arr.dtype.kind != kind or arr.ndim != ndim:
            raise error(
                f"{where}: the array {name!r} must be a {ndim}-D array of kind {kind!r}. "
                f"Got {getattr(arr, 'dtype', type(arr))} with {getattr(arr, 'ndim', '?')} dimension(s) instead."
            )
    v = len(db.labels)
    shapes = {"view_ids": (v,), "point_offsets": (v + 1,), "viewpoints_xyz_m": (v, 3),
              "esf": (v, ESF_BINS), "vfh": (v, VFH_BINS)}
    for name, shape in shapes.items():
        if getattr(db, name).shape != shape:
            raise error(f"{where}: the array {name!r} must have shape {shape}. Got {getattr(db, name).shape} instead.")
    off = db.point_offsets
    if db.points_xyz_m.shape[1:] != (3,) or off[0] != 0 or off[-1] != len(db.points_xyz_m) or (np.diff(off) < 0).any():
        raise error(f"{where}: 'point_offsets' must rise from 0 to the number of points "
                    f"({len(db.points_xyz_m)}) and 'points_xyz_m' must have 3 columns.")
    for name in ("points_xyz_m", "viewpoints_xyz_m", "esf", "vfh"):
        if not np.isfinite(getattr(db, name)).all():
            raise error(f"{where}: the array {name!r} holds NaN or infinite values.")
    if (db.esf < 0).any() or (db.vfh < 0).any():
        raise error(f"{where}: descriptors must be histograms (>= 0).")
    unknown = set(db.labels.tolist()) - set(db.class_infos)
    if unknown:
        raise error(f"{where}: the views' classes {', '.join(sorted(unknown))} have no class entry.")
    pairs = np.char.add(np.char.add(db.labels.astype(str), "\x00"), db.view_ids.astype(str))
    if len(np.unique(pairs)) != v:
        raise error(f"{where}: (label, view_id) pairs must be unique.")
    _check_model_arrays(db, where, error)


def _check_model_arrays(db: ViewDatabase, where: str, error: type[SemslamError]) -> None:
    """The pose-model views' arrays agree with each other and with the class table."""
    labels, off, pts, vps = (getattr(db, n) for n in _MODEL_ARRAYS)
    for name, arr, kind, ndim in (("model_labels", labels, "U", 1), ("model_point_offsets", off, "i", 1),
                                  ("model_points_xyz_m", pts, "f", 2), ("model_viewpoints_xyz_m", vps, "f", 2)):
        if not isinstance(arr, np.ndarray) or arr.ndim != ndim or (arr.dtype.kind != kind and arr.size):
            raise error(
                f"{where}: the array {name!r} must be a {ndim}-D array of kind {kind!r}. "
                f"Got {getattr(arr, 'dtype', type(arr))} with {getattr(arr, 'ndim', '?')} dimension(s) instead."
            )
    m = len(labels)
    if off.shape != (m + 1,) or vps.shape != (m, 3) or pts.shape[1:] != (3,):
        raise error(f"{where}: 'model_point_offsets' must have shape ({m + 1},), 'model_viewpoints_xyz_m' ({m}, 3) "
                    f"and 'model_points_xyz_m' 3 columns. Got {off.shape}, {vps.shape} and {pts.shape} instead.")
    if off[0] != 0 or off[-1] != len(pts) or (np.diff(off) < 0).any():
        raise error(f"{where}: 'model_point_offsets' must rise from 0 to the number of model points ({len(pts)}).")
    if not (np.isfinite(pts).all() and np.isfinite(vps).all()):
        raise error(f"{where}: the pose-model views hold NaN or infinite values.")
    unknown = set(labels.tolist()) - set(db.class_infos)
    if unknown:
        raise error(f"{where}: the pose-model views' classes {', '.join(sorted(unknown))} have no class entry.")
