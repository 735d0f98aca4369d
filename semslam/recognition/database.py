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

Version-1 files (no pose-model views) are still read: their classes' pose models are their views.

The checksums are CRC-32 of every array's bytes (on top of the zip's own CRC of every member). Points
are float32 (0.1 micrometre resolution at 1 m) and descriptors float32 (PCL's signatures are float32):
10,000 views of ~1,000 points make a 160 MB file that loads in ~0.5 s (benchmarks/database.py).
"""

from __future__ import annotations

import json
import os
import zipfile
import zlib
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from .._progress import progress_steps
from .._atomic import atomic_open
from .._validation import as_float_array, as_rng, check_choice, check_int, check_positive
from ..cloud import PointCloud
from ..errors import DatabaseError, InputError, SemslamError
from ..symmetry import Symmetry

FORMAT_NAME = "semslam-view-database"
FORMAT_VERSION = 2
#: Older format versions :func:`load_database` still reads.
READABLE_VERSIONS = (1, 2)
ESF_BINS = 640
VFH_BINS = 308
DESCRIPTORS = ("esf", "vfh", "esf+vfh")
_ARRAYS = ("labels", "view_ids", "point_offsets", "points_xyz_m", "viewpoints_xyz_m", "esf", "vfh")
_MODEL_ARRAYS = ("model_labels", "model_point_offsets", "model_points_xyz_m", "model_viewpoints_xyz_m")
POINT_FILE_SUFFIXES = (".pcd", ".ply", ".npy")
#: Voxel grid applied to views and queries before their descriptors (the segmentation's default grid).
DEFAULT_VOXEL_LEAF_M = 0.005
#: Normal radius of the VFH: 3 voxels of the default grid (0.01 leaves edge points with too few neighbours).
DEFAULT_NORMAL_RADIUS_M = 0.015
#: ``normal_radius_m="auto"`` / ``voxel_leaf_m="auto"``: lengths measured on the views instead of fixed ones.
AUTO = "auto"
#: The "auto" lengths in units of the measured spacing ``s`` (the median over views of each view's
#: :func:`~semslam.descriptors.point_spacing_m`, median distance to the 4th nearest neighbour, raw points):
#: ``voxel_leaf_m = AUTO_VOXEL_FACTOR * s`` and ``normal_radius_m = AUTO_NORMAL_FACTOR * max(AUTO_VOXEL_FACTOR * s,
#: voxel_leaf_m)`` (3 voxels of the grid, as the fixed defaults). On the built-in Kinect views (survey
#: geometry) s = 5.59 mm, which gives a 5.03 mm grid and a 15.1 mm normal radius (fixed: 5 mm and 15 mm).
AUTO_SPACING_K = 4
AUTO_VOXEL_FACTOR = 0.9
AUTO_NORMAL_FACTOR = 3.0
#: With ``normal_radius_m="auto"`` the VFH is computed on points and viewpoint scaled by ``vfh_scale =
#: AUTO_REFERENCE_SPACING_M / s``: PCL's VFH (variants ``pcl-1.13``, ``pcl-1.8``) normalises its view direction
#: as the 4-vector ``(vp - c, -1)``, so its viewpoint part depends on the length unit (a view in millimetres
#: would get another histogram). The reference is the built-in views' spacing, whose ``vfh_scale`` is ~1.
AUTO_REFERENCE_SPACING_M = 0.0056
AUTO_RULE = (f"spacing_m = median over views of point_spacing_m(k={AUTO_SPACING_K}); voxel_leaf_m = "
             f"{AUTO_VOXEL_FACTOR} x spacing_m; normal_radius_m = {AUTO_NORMAL_FACTOR} x max({AUTO_VOXEL_FACTOR} x "
             f"spacing_m, voxel_leaf_m); vfh_scale = {AUTO_REFERENCE_SPACING_M} / spacing_m (auto normal radius)")

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "ClassInfo",
    "ViewDatabase",
    "ViewDescriptors",
    "build_database",
    "build_database_from_folder",
    "compute_view_descriptors",
    "load_database",
    "resolve_descriptor_lengths",
    "save_database",
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


@dataclass(frozen=True)
class ViewDescriptors:
    """Global descriptors of one view: ``esf`` (640,) and ``vfh`` (308,), float32."""

    esf: np.ndarray
    vfh: np.ndarray


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
            raise DatabaseError(f"The class {label!r} is not in the database. Known classes: {', '.join(self.classes)}.") from None

    def symmetries(self) -> dict:
        """``{class: Symmetry}``: what SLAM needs to know of each class (:func:`semslam.slam.run_slam`)."""
        return {c: info.symmetry for c, info in self.class_infos.items()}

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
    def describe(self, cloud: PointCloud, *, seed: int | np.random.Generator = 0,
                 concurrent: bool = True) -> ViewDescriptors:
        """Descriptors of a query cloud computed exactly as the stored views' (same parameters).

        The database's voxel grid (``params["voxel_leaf_m"]``, if any) is applied to the query first, so
        that queries and views have the same point density (a cluster already on that grid, as
        :func:`~semslam.segmentation.segment_scene` outputs it, changes little). A database built with
        ``"auto"`` lengths describes queries with its resolved lengths and ``vfh_scale`` (``params``): queries
        must be in the views' unit.
        """
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
            "params": dict(self.params),
        }

    def __repr__(self) -> str:
        return f"ViewDatabase(n_views={self.n_views}, classes={list(self.classes)}, vfh_variant={self.vfh_variant!r})"


def combine_descriptors(descriptor: str, esf: np.ndarray, vfh: np.ndarray) -> np.ndarray:
    """Feature matrix for ``descriptor`` in ``{"esf", "vfh", "esf+vfh"}`` from ESF (n, 640) and VFH (n, 308).

    For ``"esf+vfh"`` every histogram is divided by its sum (when > 0) before concatenation.
    """
    check_choice("descriptor", descriptor, DESCRIPTORS)
    esf = np.atleast_2d(np.asarray(esf, dtype=np.float64))
    vfh = np.atleast_2d(np.asarray(vfh, dtype=np.float64))
    if descriptor == "esf":
        return np.ascontiguousarray(esf)
    if descriptor == "vfh":
        return np.ascontiguousarray(vfh)

    def unit_sum(h: np.ndarray) -> np.ndarray:
        s = h.sum(axis=1, keepdims=True)
        return h / np.where(s > 0, s, 1.0)

    return np.ascontiguousarray(np.hstack([unit_sum(esf), unit_sum(vfh)]))


# -- descriptors: the one place where semslam.descriptors is called -----------------------------------

def _vfh_default_variant() -> str:
    import inspect

    from .. import descriptors

    p = inspect.signature(descriptors.compute_vfh).parameters.get("variant")
    return str(p.default) if p is not None and p.default is not inspect.Parameter.empty else "default"


def _is_auto(value: Any) -> bool:
    return isinstance(value, str) and value == AUTO


def resolve_descriptor_lengths(clouds: Sequence[PointCloud] | PointCloud, *,
                               normal_radius_m: float | str = AUTO, voxel_leaf_m: float | str | None = AUTO,
                               caller: str = "resolve_descriptor_lengths") -> dict[str, Any]:
    """The normal radius and voxel leaf the descriptors of ``clouds`` use, with ``"auto"`` resolved.

    ``"auto"`` lengths come from the measured spacing of the clouds (see :data:`AUTO_RULE`): ``spacing_m``
    is the median over the clouds of :func:`~semslam.descriptors.point_spacing_m` (k = 4, seed 0, on the
    raw points; clouds with fewer than 5 points are left out), ``voxel_leaf_m = 0.9 x spacing_m`` and
    ``normal_radius_m = 3 x max(0.9 x spacing_m, voxel_leaf_m)`` (3 voxels). Both scale with the data, so a
    database in millimetres, or from a sparser sensor, gets the same descriptors as one in metres. With an
    ``"auto"`` normal radius the VFH is also computed in a unit where the spacing is
    :data:`AUTO_REFERENCE_SPACING_M` (``vfh_scale``): PCL's VFH viewpoint part depends on the unit.

    Returns
    -------
    dict
        ``normal_radius_m`` (float), ``voxel_leaf_m`` (float or None), ``vfh_scale`` (float, 1.0 unless the
        normal radius is "auto") and, when a length was ``"auto"``, ``spacing_m`` (float) and ``auto_rule``
        (str): what :func:`build_database` records.

    Raises
    ------
    InputError
        A length that is neither a positive number nor ``"auto"`` (``voxel_leaf_m`` may also be None).
    DatabaseError
        ``"auto"`` but no cloud with at least 5 distinct points to measure a spacing on.
    """
    from ..descriptors import point_spacing_m

    auto_radius, auto_leaf = _is_auto(normal_radius_m), _is_auto(voxel_leaf_m)
    radius = None if auto_radius else _check_length("normal_radius_m", normal_radius_m, caller)
    leaf = None if auto_leaf or voxel_leaf_m is None else _check_length("voxel_leaf_m", voxel_leaf_m, caller)
    if not (auto_radius or auto_leaf):
        return {"normal_radius_m": radius, "voxel_leaf_m": leaf, "vfh_scale": 1.0}
    clouds = [clouds] if isinstance(clouds, PointCloud) else list(clouds)
    spacings = []
    for cloud in clouds:
        if cloud.n_points > AUTO_SPACING_K:
            try:
                spacings.append(point_spacing_m(cloud.points_xyz_m, k=AUTO_SPACING_K, seed=0))
            except SemslamError:
                pass  # a view of duplicated points has no spacing: the others decide
    if not spacings:
        raise DatabaseError(f"{caller} cannot measure a point spacing for the 'auto' lengths: no view has at "
                            f"least {AUTO_SPACING_K + 1} distinct points. Give 'normal_radius_m' and "
                            f"'voxel_leaf_m' as lengths.")
    spacing = float(np.median(spacings))
    if auto_leaf:
        leaf = AUTO_VOXEL_FACTOR * spacing
    if auto_radius:
        radius = AUTO_NORMAL_FACTOR * max(AUTO_VOXEL_FACTOR * spacing, leaf or 0.0)
    return {"normal_radius_m": float(radius), "voxel_leaf_m": None if leaf is None else float(leaf),
            "vfh_scale": AUTO_REFERENCE_SPACING_M / spacing if auto_radius else 1.0,
            "spacing_m": spacing, "auto_rule": AUTO_RULE}


def _check_length(name: str, value: Any, caller: str) -> float:
    if isinstance(value, str):
        raise InputError(f"The {name!r} argument of {caller} must be a number of metres > 0 or {AUTO!r}. "
                         f"Got {value!r} instead.")
    return check_positive(name, value, caller=caller)


def compute_view_descriptors(cloud: PointCloud, *, vfh_variant: str | None = None,
                             normal_radius_m: float | str = DEFAULT_NORMAL_RADIUS_M,
                             esf_n_samples: int = 20000, voxel_leaf_m: float | str | None = None,
                             seed: int | np.random.Generator = 0, concurrent: bool = True,
                             vfh_scale: float | None = None) -> ViewDescriptors:
    """ESF and VFH of one view, as stored in the database.

    ``concurrent``: normals + VFH on a helper thread while this one computes ESF (~5 % less per cluster on a
    lightly loaded 2-core machine, ``benchmarks/descriptors.py --describe-ab``: 1.01-1.08x in 6 of 6 runs; neutral
    on a saturated one). The results are identical either way. Only ESF's kernel is parallel, so the helper never
    launches a parallel region (safe with any numba threading layer).

    With ``voxel_leaf_m`` the cloud is first reduced to its voxel-grid centroids (PCL ``VoxelGrid``), so
    that dense views (a Kinect at 0.7 m, ~1.3 mm spacing) and sparse queries (laser-scan clusters after
    the segmentation's 5 mm grid) are described at the same density: ESF's occupancy grid and the
    normals depend on it. Normals are estimated within ``normal_radius_m`` and flipped towards ``cloud.viewpoint_xyz_m``; points
    without a normal (fewer than 3 neighbours) are left out of the VFH. The VFH viewpoint is the cloud's.

    Parameters
    ----------
    cloud : PointCloud
        The view, in any frame (the object frame for database views, the scanner frame for queries:
        ESF and VFH do not depend on the frame, VFH's viewpoint part only on the viewpoint relative to it).
    vfh_variant : str, optional
        Passed to ``compute_vfh(variant=...)``; None uses its default.
    normal_radius_m : float or "auto"
        Metres; ``"auto"``: from this cloud's measured spacing (:func:`resolve_descriptor_lengths`).
    esf_n_samples : int
    voxel_leaf_m : float or "auto", optional
        Voxel edge (metres) of the grid applied before both descriptors; None keeps every point;
        ``"auto"``: from this cloud's measured spacing. (A database query must use the database's
        resolved values instead: :meth:`ViewDatabase.describe` does.)
    seed : int or Generator
        Seeds ESF's random sampling.
    vfh_scale : float, optional
        Points and viewpoint are multiplied by it before the VFH (after the normals): the unit of PCL's
        VFH viewpoint part, the one length-dependent part of ESF and VFH. None: 1 with a length normal
        radius, the measured one with ``"auto"`` (:data:`AUTO_REFERENCE_SPACING_M`).
    """
    from .. import descriptors

    if not isinstance(cloud, PointCloud):
        raise InputError(f"The 'cloud' argument of compute_view_descriptors must be a PointCloud. "
                         f"Got {type(cloud).__name__} instead.")
    lengths = resolve_descriptor_lengths(cloud, normal_radius_m=normal_radius_m, voxel_leaf_m=voxel_leaf_m,
                                         caller="compute_view_descriptors")
    radius, leaf = lengths["normal_radius_m"], lengths["voxel_leaf_m"]
    scale = lengths["vfh_scale"] if vfh_scale is None else check_positive("vfh_scale", vfh_scale,
                                                                           caller="compute_view_descriptors")
    pts = cloud.points_xyz_m
    if leaf is not None:
        from ..segmentation.voxel import voxel_downsample

        pts = voxel_downsample(pts, leaf)
        if len(pts) < 3:
            raise DatabaseError(f"The cloud has {len(pts)} point(s) left after the {leaf} m voxel grid: "
                                f"ESF and VFH need at least 3. Use a smaller 'voxel_leaf_m'.")
    kwargs = {} if vfh_variant is None else {"variant": vfh_variant}

    def normals_and_vfh() -> np.ndarray:
        normals = descriptors.estimate_normals(pts, radius_m=radius, viewpoint_xyz_m=cloud.viewpoint_xyz_m).normals_xyz
        ok = np.isfinite(normals).all(axis=1)
        if np.count_nonzero(ok) < 2:
            from ..errors import DescriptorError

            raise DescriptorError(f"Only {np.count_nonzero(ok)} of the {len(pts)} points have a normal within "
                                  f"normal_radius_m={radius:g} (3 neighbours needed): the radius is too small for "
                                  f"the points' spacing (are they in metres?). Use normal_radius_m='auto'.")
        if scale == 1.0:
            return descriptors.compute_vfh(pts[ok], normals[ok], viewpoint_xyz_m=cloud.viewpoint_xyz_m, **kwargs)
        return descriptors.compute_vfh(pts[ok] * scale, normals[ok], viewpoint_xyz_m=cloud.viewpoint_xyz_m * scale,
                                       **kwargs)

    if not concurrent:
        esf = descriptors.compute_esf(pts, n_samples=int(esf_n_samples), seed=seed)
        vfh = normals_and_vfh()
    else:
        # Normals + VFH on a helper thread while this one computes ESF: their kernels release the GIL, so they
        # fill the cores during ESF's serial steps (sampling, histogram). Same results; ESF's errors first.
        job = _helper_thread().submit(normals_and_vfh)
        try:
            esf = descriptors.compute_esf(pts, n_samples=int(esf_n_samples), seed=seed)
        except BaseException:
            wait([job])
            raise
        vfh = job.result()
    esf = np.asarray(esf, dtype=np.float32).reshape(-1)
    vfh = np.asarray(vfh, dtype=np.float32).reshape(-1)
    if esf.shape != (ESF_BINS,) or vfh.shape != (VFH_BINS,):
        raise DatabaseError(f"The descriptors must have {ESF_BINS} (ESF) and {VFH_BINS} (VFH) bins. "
                            f"Got {esf.shape} and {vfh.shape} instead.")
    return ViewDescriptors(esf, vfh)


_HELPER: tuple[int, ThreadPoolExecutor] | None = None


def _helper_thread() -> ThreadPoolExecutor:
    """One worker thread for the VFH half of :func:`compute_view_descriptors` (created per process: a forked
    child gets its own, since threads do not survive a fork)."""
    global _HELPER
    if _HELPER is None or _HELPER[0] != os.getpid():
        _HELPER = (os.getpid(), ThreadPoolExecutor(max_workers=1, thread_name_prefix="semslam-vfh"))
    return _HELPER[1]


# -- building ------------------------------------------------------------------------------------

def build_database(views: Sequence[tuple[str, str, PointCloud]], classes: Mapping[str, Mapping[str, Any]], *,
                   vfh_variant: str | None = None, normal_radius_m: float | str = DEFAULT_NORMAL_RADIUS_M,
                   esf_n_samples: int = 20000, voxel_leaf_m: float | str | None = DEFAULT_VOXEL_LEAF_M,
                   seed: int | np.random.Generator = 0, progress: bool = False,
                   model_views: Sequence[tuple[str, str, PointCloud]] | None = None,
                   mapper: Any = None) -> ViewDatabase:
    """Compute the descriptors of partial views and gather them in a :class:`ViewDatabase`.

    Parameters
    ----------
    views : sequence of (label, view_id, PointCloud)
        Each cloud in its object's canonical frame (``viewpoint_xyz_m`` = sensor origin in that frame).
        ``(label, view_id)`` pairs must be unique.
    classes : dict of label to {"symmetry": Symmetry, "size_xyz_m": (3,)}
        One entry for every label in ``views`` (extra entries are an error too).
    vfh_variant : str, optional
        VFH binning variant passed to ``compute_vfh``; None = its default (the name is recorded).
    normal_radius_m : float or "auto", default DEFAULT_NORMAL_RADIUS_M (0.015)
        Radius of the normal estimation for the VFH, metres (3 voxels of the default grid). ``"auto"``:
        3 voxels of the auto grid (2.7 x the views' measured point spacing, or 3 x a larger fixed
        ``voxel_leaf_m``), and the VFH computed in a spacing-based unit (``vfh_scale``), see
        :func:`resolve_descriptor_lengths`: for views in another unit or from another sensor.
    esf_n_samples : int, default 20000
        Point triplets sampled by ESF (PCL's value).
    voxel_leaf_m : float, "auto" or None, default DEFAULT_VOXEL_LEAF_M (0.005)
        Voxel grid applied to every view before its descriptors, and recorded so that
        :meth:`ViewDatabase.describe` applies it to queries: the segmentation's default grid, so that
        laser clusters and Kinect views have the same density. None keeps the raw views (the papers).
        ``"auto"``: 0.9 x the views' measured point spacing. The resolved lengths are recorded in
        ``params`` (floats, with ``spacing_m``, ``vfh_scale``, ``auto`` and ``auto_rule``), so queries are described the same way;
        queries must then come at the views' scale and density (a laser cluster on the segmentation's
        5 mm grid matches a database built with the fixed 5 mm grid, not with "auto" on dense views).
    seed : int or Generator, default 0
        Every view's ESF gets its own seed drawn from it: the database is reproducible.
    progress : bool or callable
        A bar, or ``progress(done, total)`` after every view (:mod:`semslam._progress`).
    model_views : sequence of (label, view_id, PointCloud), optional
        Pose-model views (object frame, with viewpoints), stored without descriptors: pose estimation
        fuses them instead of the recognition views of their class (:meth:`ViewDatabase.pose_views`).
        Classes without any keep their recognition views as pose model.
    mapper : callable, optional
        ``mapper(fn, items, progress) -> [fn(item) for item in items]`` in order: runs the views' descriptors
        elsewhere (e.g. :func:`semslam.experiments._dask.map_tasks` on a Dask cluster); every view carries its own
        seed, so the database does not depend on it. Default: in this process.
    """
    caller = "build_database"
    if not _is_auto(normal_radius_m):  # lengths checked before the views; "auto" is measured once they are
        _check_length("normal_radius_m", normal_radius_m, caller)
    if not (_is_auto(voxel_leaf_m) or voxel_leaf_m is None):
        _check_length("voxel_leaf_m", voxel_leaf_m, caller)
    n_samples = check_int("esf_n_samples", esf_n_samples, caller=caller, minimum=1)
    rng = as_rng(seed, caller=caller)
    views = list(views)
    if not views:
        raise InputError(f"The 'views' argument of {caller} must hold at least one view. Got an empty sequence.")
    class_infos = _class_infos(classes, caller)
    views = _check_view_items(views, class_infos, caller, "views", "view")
    seen = {(label, view_id) for label, view_id, _ in views}
    unused = set(class_infos) - {lab for lab, _ in seen}
    if unused:
        raise InputError(f"The 'classes' argument of {caller} describes classes without views: {', '.join(sorted(unused))}.")
    models = _check_model_views(model_views, class_infos, caller)
    lengths = resolve_descriptor_lengths([v[2] for v in views], normal_radius_m=normal_radius_m,
                                         voxel_leaf_m=voxel_leaf_m, caller=caller)
    radius, leaf = lengths["normal_radius_m"], lengths["voxel_leaf_m"]
    variant = vfh_variant if vfh_variant is not None else _vfh_default_variant()
    view_seeds = rng.integers(0, 2**31 - 1, size=len(views))
    esf = np.empty((len(views), ESF_BINS), np.float32)
    vfh = np.empty((len(views), VFH_BINS), np.float32)
    task = partial(_describe_view, vfh_variant=variant, normal_radius_m=radius, esf_n_samples=n_samples,
                   voxel_leaf_m=leaf, vfh_scale=lengths["vfh_scale"])
    items = [(label, view_id, cloud, int(view_seeds[k])) for k, (label, view_id, cloud) in enumerate(views)]
    for k, d in enumerate((mapper or _map_here)(task, items, progress)):
        esf[k], vfh[k] = d.esf, d.vfh
    counts = np.array([v[2].n_points for v in views], dtype=np.int64)
    params = {"vfh_variant": variant, "normal_radius_m": radius, "esf_n_samples": n_samples, "voxel_leaf_m": leaf,
              "seed": seed if isinstance(seed, int) else None}
    if "spacing_m" in lengths:  # "auto": how the lengths were chosen
        params["spacing_m"] = lengths["spacing_m"]
        params["vfh_scale"] = lengths["vfh_scale"]
        params["auto"] = [name for name, value in (("normal_radius_m", normal_radius_m), ("voxel_leaf_m", voxel_leaf_m))
                          if _is_auto(value)]
        params["auto_rule"] = lengths["auto_rule"]
    return ViewDatabase(
        labels=np.array([str(v[0]) for v in views]),
        view_ids=np.array([str(v[1]) for v in views]),
        point_offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        points_xyz_m=np.concatenate([v[2].points_xyz_m for v in views]).astype(np.float32),
        viewpoints_xyz_m=np.array([v[2].viewpoint_xyz_m for v in views], dtype=np.float64),
        esf=esf, vfh=vfh, class_infos=class_infos, params=params,
        model_labels=np.array([m[0] for m in models], dtype=str) if models else np.zeros(0, "<U1"),
        model_point_offsets=np.concatenate([[0], np.cumsum([m[2].n_points for m in models])]).astype(np.int64),
        model_points_xyz_m=(np.concatenate([m[2].points_xyz_m for m in models]) if models
                            else np.zeros((0, 3))).astype(np.float32),
        model_viewpoints_xyz_m=np.array([m[2].viewpoint_xyz_m for m in models], dtype=np.float64).reshape(-1, 3),
    )


def _describe_view(item: tuple, **kwargs: Any) -> ViewDescriptors:
    """The descriptors of one ``(label, view_id, cloud, seed)`` view of :func:`build_database` (a picklable task)."""
    label, view_id, cloud, seed = item
    try:
        return compute_view_descriptors(cloud, seed=seed, **kwargs)
    except SemslamError as exc:
        raise type(exc)(f"View ({label!r}, {view_id!r}): {exc}") from exc


def _map_here(fn: Any, items: list, progress: Any) -> list:
    out = []
    with progress_steps(progress, len(items), "descriptors", "view") as step:
        for item in items:
            out.append(fn(item))
            step()
    return out


def _check_model_views(model_views: Any, class_infos: Mapping[str, ClassInfo], caller: str) -> list:
    """``model_views`` as a list of (label, view_id, PointCloud), checked (None: empty)."""
    return [] if model_views is None else _check_view_items(model_views, class_infos, caller, "model_views",
                                                            "model view")


def _check_view_items(items: Any, class_infos: Mapping[str, ClassInfo], caller: str, name: str, what: str) -> list:
    """Check a sequence of (label, view_id, PointCloud): known class, unique (label, view_id), >= 3 points.

    Returns the items as a list with labels and ids as str; ``name`` / ``what`` word the errors
    (``"views"`` / ``"view"`` or ``"model_views"`` / ``"model view"``).
    """
    out, seen = [], set()
    for k, item in enumerate(items):
        if not (isinstance(item, tuple) and len(item) == 3 and isinstance(item[2], PointCloud)):
            raise InputError(f"Every item of {name!r} of {caller} must be (label, view_id, PointCloud). "
                             f"Item {k} is {type(item).__name__} instead.")
        label, view_id, cloud = str(item[0]), str(item[1]), item[2]
        if label not in class_infos:
            raise InputError(f"{what.capitalize()} {k} of {caller} has class {label!r}, which 'classes' does not "
                             f"describe. Known: {', '.join(sorted(class_infos))}.")
        if (label, view_id) in seen:
            raise InputError(f"The {what} ({label!r}, {view_id!r}) appears twice in the {name!r} of {caller}.")
        if cloud.n_points < 3:
            raise InputError(f"{what.capitalize()} ({label!r}, {view_id!r}) of {caller} must have at least 3 points. "
                             f"Got {cloud.n_points}.")
        seen.add((label, view_id))
        out.append((label, view_id, cloud))
    return out


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


def build_database_from_folder(views_dir: str | Path, *, clean: bool = True, **kwargs: Any) -> ViewDatabase:
    """Build a database from a folder ``views_dir/CLASS/VIEW.{pcd,ply,npy}`` of views in the object frame.

    An optional ``views_dir/classes.json`` maps labels to ``{"symmetry": {...Symmetry.to_dict()},
    "size_xyz_m": [x, y, z]}``; a class it does not describe gets symmetry ``none`` and the bounding box
    of all its views' points as size. Each file's ``VIEWPOINT`` is the view's sensor origin. Views are
    taken in sorted order. ``clean`` (default) drops points at the sensor origin (invalid depth) and drawn
    lines (:func:`semslam.segmentation.clean.clean_view`). Keyword arguments go to :func:`build_database`.
    Views recorded in their own sensor frames are fused into one object frame by
    :func:`semslam.pipeline.fuse.build_fused_database` (``semslam db build --fuse``).
    """
    views, declared, meta_path = read_view_folder(views_dir, clean=clean)
    return build_database(views, folder_classes(views, declared, meta_path), **kwargs)


def read_view_folder(views_dir: str | Path, *, clean: bool = True) -> tuple[list, dict, Path]:
    """The views ``[(label, view_id, PointCloud)]`` of a folder ``CLASS/VIEW.{pcd,ply,npy}`` in sorted order,
    the content of its optional ``classes.json`` and that file's path (see :func:`build_database_from_folder`)."""
    from ..io import read_point_cloud
    from ..segmentation.clean import clean_view

    root = Path(views_dir)
    if not root.is_dir():
        raise DatabaseError(f"The views folder {str(root)!r} does not exist or is not a folder.")
    declared: dict[str, Any] = {}
    meta_path = root / "classes.json"
    if meta_path.exists():
        try:
            declared = json.loads(meta_path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise DatabaseError(f"The file {str(meta_path)!r} is not valid JSON: {exc}.") from None
        if not isinstance(declared, dict):
            raise DatabaseError(f"The file {str(meta_path)!r} must hold a JSON object label -> class info.")
    views: list[tuple[str, str, PointCloud]] = []
    for class_dir in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        for f in sorted(class_dir.iterdir()):
            if f.suffix.lower() in POINT_FILE_SUFFIXES:
                cloud = read_point_cloud(f, frame_id="object")
                if clean:
                    try:
                        cloud = clean_view(cloud, name=repr(str(f)))[0]
                    except InputError as exc:
                        raise DatabaseError(str(exc)) from None
                views.append((class_dir.name, f.stem, cloud))
    if not views:
        raise DatabaseError(f"The views folder {str(root)!r} holds no CLASS/VIEW{{{','.join(POINT_FILE_SUFFIXES)}}} files.")
    return views, declared, meta_path


def folder_classes(views: Sequence[tuple[str, str, PointCloud]], declared: Mapping[str, Any],
                   meta_path: Path) -> dict[str, Any]:
    """Class infos of a view folder: ``classes.json``'s entries, else symmetry none and the views' bounding box."""
    classes: dict[str, Any] = {}
    for label in sorted({v[0] for v in views}):
        if label in declared:
            info = declared[label]
            try:
                classes[label] = {"symmetry": Symmetry.from_dict(info.get("symmetry", {"kind": "none"})),
                                  "size_xyz_m": info.get("size_xyz_m") or _bbox_size(views, label)}
            except (AttributeError, SemslamError) as exc:
                raise DatabaseError(f"The entry {label!r} of {str(meta_path)!r} is invalid: {exc}") from None
        else:
            classes[label] = {"symmetry": Symmetry(), "size_xyz_m": _bbox_size(views, label)}
    return classes


def _bbox_size(views: Sequence[tuple[str, str, PointCloud]], label: str) -> np.ndarray:
    pts = np.concatenate([c.points_xyz_m for lab, _, c in views if lab == label])
    return pts.max(axis=0) - pts.min(axis=0)


# -- file I/O ------------------------------------------------------------------------------------

def _checksum(arr: np.ndarray) -> str:
    """CRC-32 of an array's bytes, 8 hex digits (integrity, not security: 1.4 GB/s where SHA-256 does 0.2)."""
    return f"{zlib.crc32(np.ascontiguousarray(arr).data):08x}"


def save_database(db: ViewDatabase, path: str | Path) -> Path:
    """Write ``db`` to ``path`` (an ``.npz``, written atomically). Returns the path."""
    if not isinstance(db, ViewDatabase):
        raise InputError(f"The 'db' argument of save_database must be a ViewDatabase. Got {type(db).__name__} instead.")
    path = Path(path)
    arrays = {name: getattr(db, name) for name in _ARRAYS + _MODEL_ARRAYS}
    meta = {
        "format": FORMAT_NAME, "version": FORMAT_VERSION, "n_views": db.n_views,
        "classes": {c: db.class_infos[c].to_dict() for c in db.classes},
        "params": dict(db.params),
        "checksums": {name: _checksum(arr) for name, arr in arrays.items()},
    }
    try:
        with atomic_open(path, "wb") as fh:
            np.savez(fh, meta=np.array(json.dumps(meta)), **arrays)
    except OSError as exc:
        raise DatabaseError(f"Cannot write the database file {str(path)!r}: {exc.strerror or exc}.") from None
    return path


def load_database(path: str | Path, *, verify: bool = True) -> ViewDatabase:
    """Read a database written by :func:`save_database`.

    Raises DatabaseError naming the file when it is missing, not a database, truncated or corrupted
    (zip CRC or array checksum mismatch, with ``verify``), of another format version, or inconsistent.
    """
    path = Path(path)
    where = f"The database file {str(path)!r}"
    if not path.is_file():
        raise DatabaseError(f"{where} does not exist or is not a regular file.")
    _inspect_archive(path, where)
    try:
        with np.load(path, allow_pickle=False) as npz:
            if "meta" not in npz.files:
                raise DatabaseError(f"{where} is not a semslam view database: it has no 'meta' entry.")
            meta = json.loads(str(npz["meta"][()]))
            if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
                raise DatabaseError(f"{where} is not a semslam view database: format is "
                                    f"{meta.get('format') if isinstance(meta, dict) else meta!r}, expected {FORMAT_NAME!r}.")
            version = meta.get("version")
            if version not in READABLE_VERSIONS:
                raise DatabaseError(f"{where} has format version {version!r}; this semslam reads versions "
                                    f"{', '.join(map(str, READABLE_VERSIONS))}. Rebuild it with 'semslam db build'.")
            names = _ARRAYS + (_MODEL_ARRAYS if version >= 2 else ())
            missing = [n for n in names if n not in npz.files]
            if missing:
                raise DatabaseError(f"{where} is missing the arrays {', '.join(missing)}.")
            arrays = {name: npz[name] for name in names}
    except DatabaseError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile) as exc:
        raise DatabaseError(f"{where} is truncated or corrupted (bad zip archive: {exc}).") from None
    except (ValueError, OSError, EOFError, KeyError, json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise DatabaseError(f"{where} is truncated or corrupted ({type(exc).__name__}: {exc}).") from None
    params = meta.get("params", {})
    if not isinstance(params, dict) or not all(v is None or isinstance(v, (str, int, float, bool, dict, list))
                                               for v in params.values()):
        raise DatabaseError(f"{where} has invalid descriptor parameters: expected a table, got {params!r:.80}.")
    if verify:
        checksums = meta.get("checksums", {})
        for name, arr in arrays.items():
            if checksums.get(name) != _checksum(arr):
                raise DatabaseError(f"{where} is corrupted: the checksum of the array {name!r} does not match.")
    try:
        classes = {c: ClassInfo(c, Symmetry.from_dict(info["symmetry"]), info["size_xyz_m"])
                   for c, info in meta["classes"].items()}
    except (KeyError, TypeError, AttributeError, SemslamError) as exc:
        raise DatabaseError(f"{where} has an invalid class table: {exc}.") from None
    db = object.__new__(ViewDatabase)
    for name, arr in arrays.items():
        object.__setattr__(db, name, arr)
    object.__setattr__(db, "class_infos", classes)
    object.__setattr__(db, "params", dict(params))
    if "model_labels" not in arrays:  # version 1: no pose-model views
        for name, value in zip(_MODEL_ARRAYS, (np.zeros(0, "<U1"), np.zeros(1, np.int64), np.zeros((0, 3), np.float32),
                                               np.zeros((0, 3)))):
            object.__setattr__(db, name, value)
    _check_consistency(db, where, DatabaseError)
    for name in _ARRAYS + _MODEL_ARRAYS:
        getattr(db, name).setflags(write=False)
    return db


#: the most a database may hold once decompressed: far above any real one, far below what a crafted file could ask
MAX_DECOMPRESSED_BYTES = 4 << 30


def _inspect_archive(path: Path, where: str) -> None:
    """Before numpy allocates anything: the file is a zip archive, its entries decompress to at most
    :data:`MAX_DECOMPRESSED_BYTES` in all, and no ``.npy`` entry declares more data than it holds (a crafted
    header could ask for terabytes)."""
    if not zipfile.is_zipfile(path):
        raise DatabaseError(f"{where} is truncated or corrupted, or not a semslam view database (.npz): it is not a "
                            "readable zip archive.")
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
            total = sum(i.file_size for i in infos)
            if total > MAX_DECOMPRESSED_BYTES:
                raise DatabaseError(f"{where} would decompress to {total} bytes, more than the "
                                    f"{MAX_DECOMPRESSED_BYTES} a view database may hold.")
            for info in infos:
                if not info.filename.endswith(".npy"):
                    continue
                with zf.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                                   else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = read_header(fh)
                    if dtype.hasobject:
                        raise DatabaseError(f"{where}: the array {info.filename!r} holds Python objects.")
                    declared = int(np.prod(shape, dtype=object)) * dtype.itemsize
                    if declared > info.file_size:
                        raise DatabaseError(f"{where}: the array {info.filename!r} declares {declared} bytes but "
                                            f"holds {info.file_size}: truncated or crafted.")
    except DatabaseError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, OSError, EOFError, SyntaxError) as exc:
        raise DatabaseError(f"{where} is truncated or corrupted ({type(exc).__name__}: {exc}).") from None


def _check_consistency(db: ViewDatabase, where: str, error: type[SemslamError]) -> None:
    """Shapes, dtypes, offsets and labels agree; raise ``error`` naming ``where`` otherwise."""
    expected = {"labels": ("U", 1), "view_ids": ("U", 1), "point_offsets": ("i", 1), "points_xyz_m": ("f", 2),
                "viewpoints_xyz_m": ("f", 2), "esf": ("f", 2), "vfh": ("f", 2)}
    for name, (kind, ndim) in expected.items():
        arr = getattr(db, name)
        if not isinstance(arr, np.ndarray) or arr.dtype.kind != kind or arr.ndim != ndim:
            raise error(f"{where}: the array {name!r} must be a {ndim}-D array of kind {kind!r}. "
                        f"Got {getattr(arr, 'dtype', type(arr))} with {getattr(arr, 'ndim', '?')} dimension(s) instead.")
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
            raise error(f"{where}: the array {name!r} must be a {ndim}-D array of kind {kind!r}. "
                        f"Got {getattr(arr, 'dtype', type(arr))} with {getattr(arr, 'ndim', '?')} dimension(s) instead.")
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
