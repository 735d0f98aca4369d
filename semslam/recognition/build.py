"""Building a view database: from ``(label, view_id, PointCloud)`` views and their classes, or from a folder
``CLASS/VIEW.{pcd,ply,npy}`` (with the optional ``classes.toml``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from .._progress import progress_steps
from .._validation import as_rng, check_int
from ..cloud import PointCloud
from ..errors import DatabaseError, InputError, SemslamError
from ..symmetry import Symmetry
from .database import ClassInfo, ViewDatabase, _class_infos
from .preprocessing import ViewPreprocessing
from .view_descriptors import (DEFAULT_VOXEL_LEAF_M, ESF_BINS, VFH_BINS, ViewDescriptors,
                               _check_length, _is_auto, _vfh_default_variant, compute_view_descriptors,
                               default_normal_radius,
                               resolve_descriptor_lengths)

POINT_FILE_SUFFIXES = (".pcd", ".ply", ".npy")



def build_database(views: Sequence[tuple[str, str, PointCloud]], classes: Mapping[str, Mapping[str, Any]], *,
                   vfh_variant: str | None = None, normal_radius_m: float | str | None = None,
                   esf_n_samples: int = 20000, voxel_leaf_m: float | str | None = DEFAULT_VOXEL_LEAF_M,
                   seed: int | np.random.Generator = 0, progress: bool = False,
                   model_views: Sequence[tuple[str, str, PointCloud]] | None = None,
                   mapper: Any = None, preprocessing: ViewPreprocessing | Mapping[str, Any] | None = None,
                   views_preprocessed: bool = False) -> ViewDatabase:
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
    normal_radius_m : float, "auto" or None
        Radius of the normal estimation for the VFH, metres. None (default): from the views' own scale, 3 voxels
        of a fixed ``voxel_leaf_m`` (the default 5 mm grid: DEFAULT_NORMAL_RADIUS_M, 15 mm); with no grid or an
        "auto" one, the "auto" radius but at least 0.25 x the views' median bounding-box diagonal
        (``NORMAL_EXTENT_FRACTION``; recorded as ``extent_m``): VFH on views of any size and unit. ``"auto"``:
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
        ``params`` (floats, with ``spacing_m``, ``vfh_scale``, ``auto`` and ``auto_rule``), so queries are described
        the same way;
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
        elsewhere (e.g. :func:`semslam.batch.engine.map_tasks` on a Dask cluster); every view carries its own
        seed, so the database does not depend on it. Default: in this process.
    preprocessing : ViewPreprocessing or dict, optional
        What is done to every view before its descriptors (range limits, cleaning of sensor-origin points and
        drawn lines: :class:`~semslam.recognition.preprocessing.ViewPreprocessing`). It is recorded in
        ``params["preprocessing"]``, with the views' point spacing after the voxel grid, and
        :meth:`ViewDatabase.describe` applies it to every query. None: nothing (recorded as such).
    views_preprocessed : bool, default False
        The views were already treated by ``preprocessing`` (e.g. cleaned while read): it is recorded, not
        applied again.
    """
    caller = "build_database"
    normal_radius_m, given_radius, n_samples, rng = _checked_settings(normal_radius_m, voxel_leaf_m, esf_n_samples,
                                                                      seed, caller)
    views, class_infos, models = _checked_views(views, classes, model_views, caller)
    prep = _as_preprocessing(preprocessing, caller).with_view_spacing(None)  # the spacing is measured below
    if not (views_preprocessed or prep.is_identity):
        views = [(label, view_id, _preprocess_view(prep, label, view_id, cloud)) for label, view_id, cloud in views]
    lengths = resolve_descriptor_lengths([v[2] for v in views], normal_radius_m=given_radius,
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
    params = _database_params(variant, radius, n_samples, leaf, seed, prep, views, lengths, normal_radius_m,
                              voxel_leaf_m)
    return _assemble(views, models, esf, vfh, class_infos, params)


def _checked_settings(normal_radius_m, voxel_leaf_m, esf_n_samples, seed, caller: str):
    """``(normal_radius_m, the radius given or None, esf_n_samples, rng)`` of :func:`build_database`, checked."""
    if normal_radius_m is None:  # from the views' own scale (issue #29, item 6): resolved with the views
        normal_radius_m = default_normal_radius(voxel_leaf_m)
        given_radius = None if _is_auto(normal_radius_m) else normal_radius_m
    else:
        given_radius = normal_radius_m
    if not _is_auto(normal_radius_m):  # lengths checked before the views; "auto" is measured once they are
        _check_length("normal_radius_m", normal_radius_m, caller)
    if not (_is_auto(voxel_leaf_m) or voxel_leaf_m is None):
        _check_length("voxel_leaf_m", voxel_leaf_m, caller)
    n_samples = check_int("esf_n_samples", esf_n_samples, caller=caller, minimum=1)
    rng = as_rng(seed, caller=caller)
    return normal_radius_m, given_radius, n_samples, rng


def _checked_views(views, classes, model_views, caller: str):
    """``(views, class_infos, model views)`` of :func:`build_database`, checked against each other."""
    views = list(views)
    if not views:
        raise InputError(f"The 'views' argument of {caller} must hold at least one view. Got an empty sequence.")
    class_infos = _class_infos(classes, caller)
    views = _check_view_items(views, class_infos, caller, "views", "view")
    seen = {(label, view_id) for label, view_id, _ in views}
    unused = set(class_infos) - {lab for lab, _ in seen}
    if unused:
        raise InputError(
            f"The 'classes' argument of {caller} describes classes without views: {', '.join(sorted(unused))}."
        )
    models = _check_model_views(model_views, class_infos, caller)
    return views, class_infos, models


def _database_params(variant, radius, n_samples, leaf, seed, prep, views, lengths, normal_radius_m,
                     voxel_leaf_m) -> dict:
    """The database's ``params``: how its descriptors were computed, so queries are described the same way."""
    params = {"vfh_variant": variant, "normal_radius_m": radius, "esf_n_samples": n_samples, "voxel_leaf_m": leaf,
              "seed": seed if isinstance(seed, int) else None,
              "preprocessing": prep.with_view_spacing(_views_spacing_m([v[2] for v in views], leaf)).to_dict()}
    if "spacing_m" in lengths:  # "auto": how the lengths were chosen
        params["spacing_m"] = lengths["spacing_m"]
        params["vfh_scale"] = lengths["vfh_scale"]
        params["auto"] = [name for name, value in (("normal_radius_m", normal_radius_m), ("voxel_leaf_m", voxel_leaf_m))
                          if _is_auto(value)]
        params["auto_rule"] = lengths["auto_rule"]
        if "extent_m" in lengths:
            params["extent_m"] = lengths["extent_m"]
    return params


def _assemble(views, models, esf, vfh, class_infos, params) -> ViewDatabase:
    """The views' points, viewpoints and descriptors, and the pose-model views, in one :class:`ViewDatabase`."""
    counts = np.array([v[2].n_points for v in views], dtype=np.int64)
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



def _as_preprocessing(preprocessing: Any, caller: str) -> ViewPreprocessing:
    if preprocessing is None:
        return ViewPreprocessing()
    if isinstance(preprocessing, ViewPreprocessing):
        if not preprocessing.known:
            raise InputError(f"The 'preprocessing' argument of {caller} must say what is done to the views: "
                             f"ViewPreprocessing.unknown() only describes old database files.")
        return preprocessing
    if isinstance(preprocessing, Mapping):
        try:
            return ViewPreprocessing(**preprocessing)
        except TypeError as exc:
            raise InputError(f"The 'preprocessing' argument of {caller} has an unknown field: {exc}.") from None
    raise InputError(f"The 'preprocessing' argument of {caller} must be a ViewPreprocessing, a dict of its fields or "
                     f"None. Got {type(preprocessing).__name__} instead.")



def _preprocess_view(prep: ViewPreprocessing, label: str, view_id: str, cloud: PointCloud) -> PointCloud:
    try:
        out = prep.apply(cloud, name=f"view ({label!r}, {view_id!r})")
    except SemslamError as exc:
        raise DatabaseError(str(exc)) from None
    if out.n_points < 3:
        raise DatabaseError(f"The view ({label!r}, {view_id!r}) has {out.n_points} point(s) left after its "
                            f"preprocessing ({prep.describe()}): at least 3 are needed.")
    return out



def _views_spacing_m(clouds: Sequence[PointCloud], leaf: float | None) -> float | None:
    """Median over the views of their point spacing after the voxel grid (None when no view can be measured)."""
    from ..descriptors import point_spacing_m
    from ..segmentation.voxel import voxel_downsample

    spacings = []
    for cloud in clouds:
        pts = cloud.points_xyz_m if leaf is None else voxel_downsample(cloud.points_xyz_m, leaf)
        if len(pts) > 4:
            try:
                spacings.append(point_spacing_m(pts, seed=0, sample=500))
            except SemslamError:
                pass
    return float(np.median(spacings)) if spacings else None



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



def build_database_from_folder(views_dir: str | Path, *, clean: bool = True,
                               preprocessing: ViewPreprocessing | Mapping[str, Any] | None = None,
                               **kwargs: Any) -> ViewDatabase:
    """Build a database from a folder ``views_dir/CLASS/VIEW.{pcd,ply,npy}`` of views in the object frame.

    An optional ``views_dir/classes.json`` maps labels to ``{"symmetry": {...Symmetry.to_dict()},
    "size_xyz_m": [x, y, z]}``; a class it does not describe gets symmetry ``none`` and the bounding box
    of all its views' points as size. Each file's ``VIEWPOINT`` is the view's sensor origin. Views are
    taken in sorted order. ``clean`` (default) drops points at the sensor origin (invalid depth) and drawn
    lines (:func:`semslam.segmentation.clean.clean_view`); the cleaning is recorded in the database and applied
    to every query (:attr:`ViewDatabase.preprocessing`). ``preprocessing`` (a
    :class:`~semslam.recognition.preprocessing.ViewPreprocessing`, e.g. with range limits) replaces ``clean``.
    Other keyword arguments go to :func:`build_database`.
    Views recorded in their own sensor frames are fused into one object frame by
    :func:`semslam.recognition.fuse.build_fused_database` (``semslam db build --fuse``).
    """
    if preprocessing is None:  # cleaned while read (errors name the file), recorded
        views, declared, meta_path = read_view_folder(views_dir, clean=clean)
        return build_database(views, folder_classes(views, declared, meta_path),
                              preprocessing=ViewPreprocessing(clean=bool(clean)), views_preprocessed=True, **kwargs)
    views, declared, meta_path = read_view_folder(views_dir, clean=False)
    return build_database(views, folder_classes(views, declared, meta_path), preprocessing=preprocessing, **kwargs)



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
        raise DatabaseError(
            f"The views folder {str(root)!r} holds no CLASS/VIEW{{{','.join(POINT_FILE_SUFFIXES)}}} files."
        )
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
