"""The global descriptors of a view as the view database stores them (ESF 640 bins, VFH 308 bins), the lengths
they are computed with (fixed, or ``"auto"`` from the measured point spacing) and the one place where
:mod:`semslam.descriptors` is called for database views and queries alike.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor, wait
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from .._validation import check_choice, check_positive
from ..cloud import PointCloud
from ..errors import DatabaseError, InputError, SemslamError

ESF_BINS = 640


VFH_BINS = 308


DESCRIPTORS = ("esf", "vfh", "esf+vfh")


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


#: ``normal_radius_m=None`` (the default): this many voxels of a fixed voxel grid (the default 5 mm grid: 15 mm,
#: :data:`DEFAULT_NORMAL_RADIUS_M`), else ``"auto"``, from the clouds' own measured spacing (issue #29, item 6: VFH
#: on views of any size and unit, raw or on an "auto" grid).
NORMAL_RADIUS_VOXELS = 3.0


#: Without a fixed grid and without a given radius, the normal radius is at least this fraction of the median
#: bounding-box diagonal of the views (dense real views: a radius of a few point spacings follows the sensor's
#: noise, not the object's shape; measured with benchmarks/vfh_scale.py).
NORMAL_EXTENT_FRACTION = 0.25


SCALE_RULE = (f"normal radius not given and no fixed grid: normal_radius_m = max(the auto radius, "
              f"{NORMAL_EXTENT_FRACTION} x the views' median bounding-box diagonal)")


def default_normal_radius(voxel_leaf_m: Any) -> float | str:
    """The normal radius used when none is given: :data:`NORMAL_RADIUS_VOXELS` voxels of a fixed ``voxel_leaf_m``
    (a number), else ``"auto"`` (no grid, or an ``"auto"`` one: from the clouds' measured spacing)."""
    if isinstance(voxel_leaf_m, (int, float, np.integer, np.floating)) and not isinstance(voxel_leaf_m, bool) \
            and voxel_leaf_m > 0:
        return NORMAL_RADIUS_VOXELS * float(voxel_leaf_m)
    return AUTO


AUTO_RULE = (f"spacing_m = median over views of point_spacing_m(k={AUTO_SPACING_K}); voxel_leaf_m = "
             f"{AUTO_VOXEL_FACTOR} x spacing_m; normal_radius_m = {AUTO_NORMAL_FACTOR} x max({AUTO_VOXEL_FACTOR} x "
             f"spacing_m, voxel_leaf_m); vfh_scale = {AUTO_REFERENCE_SPACING_M} / spacing_m (auto normal radius)")



@dataclass(frozen=True)
class ViewDescriptors:
    """Global descriptors of one view: ``esf`` (640,) and ``vfh`` (308,), float32."""

    esf: np.ndarray
    vfh: np.ndarray



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



def _vfh_default_variant() -> str:
    import inspect

    from .. import descriptors

    p = inspect.signature(descriptors.compute_vfh).parameters.get("variant")
    return str(p.default) if p is not None and p.default is not inspect.Parameter.empty else "default"



def _is_auto(value: Any) -> bool:
    return isinstance(value, str) and value == AUTO



def resolve_descriptor_lengths(clouds: Sequence[PointCloud] | PointCloud, *,
                               normal_radius_m: float | str | None = AUTO, voxel_leaf_m: float | str | None = AUTO,
                               caller: str = "resolve_descriptor_lengths") -> dict[str, Any]:
    """The normal radius and voxel leaf the descriptors of ``clouds`` use, with ``"auto"`` resolved.

    ``"auto"`` lengths come from the measured spacing of the clouds (see :data:`AUTO_RULE`): ``spacing_m``
    is the median over the clouds of :func:`~semslam.descriptors.point_spacing_m` (k = 4, seed 0, on the
    raw points; clouds with fewer than 5 points are left out), ``voxel_leaf_m = 0.9 x spacing_m`` and
    ``normal_radius_m = 3 x max(0.9 x spacing_m, voxel_leaf_m)`` (3 voxels). Both scale with the data, so a
    database in millimetres, or from a sparser sensor, gets the same descriptors as one in metres. With an
    ``"auto"`` normal radius the VFH is also computed in a unit where the spacing is
    :data:`AUTO_REFERENCE_SPACING_M` (``vfh_scale``): PCL's VFH viewpoint part depends on the unit.
    ``normal_radius_m=None`` is :func:`default_normal_radius`: 3 voxels of a fixed grid; without one, the
    ``"auto"`` radius raised to at least :data:`NORMAL_EXTENT_FRACTION` of the clouds' median bounding-box diagonal
    (then also ``extent_m`` is returned).

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

    scale_radius = normal_radius_m is None and _is_auto(default_normal_radius(voxel_leaf_m))
    if normal_radius_m is None:
        normal_radius_m = default_normal_radius(voxel_leaf_m)
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
    out = {"normal_radius_m": float(radius), "voxel_leaf_m": None if leaf is None else float(leaf),
           "vfh_scale": AUTO_REFERENCE_SPACING_M / spacing if auto_radius else 1.0,
           "spacing_m": spacing, "auto_rule": AUTO_RULE}
    if scale_radius:  # no radius given, no fixed grid: at least a fraction of the views' size (item 6 of issue #29)
        diagonals = [float(np.linalg.norm(np.ptp(c.points_xyz_m, axis=0))) for c in clouds if c.n_points > 1]
        size = float(np.median(diagonals)) if diagonals else 0.0
        out["normal_radius_m"] = float(max(radius, NORMAL_EXTENT_FRACTION * size))
        out["extent_m"] = size
        out["auto_rule"] = AUTO_RULE + "; " + SCALE_RULE
    return out



def _check_length(name: str, value: Any, caller: str) -> float:
    if isinstance(value, str):
        raise InputError(f"The {name!r} argument of {caller} must be a number of metres > 0 or {AUTO!r}. "
                         f"Got {value!r} instead.")
    return check_positive(name, value, caller=caller)



def compute_view_descriptors(cloud: PointCloud, *, vfh_variant: str | None = None,
                             normal_radius_m: float | str | None = None,
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
    normals depend on it. Normals are estimated within ``normal_radius_m`` and flipped towards
    ``cloud.viewpoint_xyz_m``; points
    without a normal (fewer than 3 neighbours) are left out of the VFH. The VFH viewpoint is the cloud's.

    Parameters
    ----------
    cloud : PointCloud
        The view, in any frame (the object frame for database views, the scanner frame for queries:
        ESF and VFH do not depend on the frame, VFH's viewpoint part only on the viewpoint relative to it).
    vfh_variant : str, optional
        Passed to ``compute_vfh(variant=...)``; None uses its default.
    normal_radius_m : float, "auto" or None
        Metres; ``"auto"``: from this cloud's measured spacing (:func:`resolve_descriptor_lengths`). None (default):
        3 voxels of a fixed ``voxel_leaf_m``, else the "auto" radius but at least :data:`NORMAL_EXTENT_FRACTION` of
        the cloud's bounding-box diagonal.
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
    pts = _grid_points(cloud.points_xyz_m, leaf)
    kwargs = {} if vfh_variant is None else {"variant": vfh_variant}

    normals_and_vfh = partial(_normals_and_vfh, pts, cloud.viewpoint_xyz_m, radius, scale, kwargs)

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



def _grid_points(pts: np.ndarray, leaf: float | None) -> np.ndarray:
    """The points on the ``leaf`` voxel grid (their centroids), or as they are without a grid."""
    if leaf is not None:
        from ..segmentation.voxel import voxel_downsample

        pts = voxel_downsample(pts, leaf)
        if len(pts) < 3:
            raise DatabaseError(f"The cloud has {len(pts)} point(s) left after the {leaf} m voxel grid: "
                                f"ESF and VFH need at least 3. Use a smaller 'voxel_leaf_m'.")
    return pts


def _normals_and_vfh(pts: np.ndarray, viewpoint_xyz_m: np.ndarray, radius: float, scale: float,
                     kwargs: dict) -> np.ndarray:
    """Normals within ``radius`` (flipped towards the viewpoint) and the VFH of the points that have one."""
    from .. import descriptors

    normals = descriptors.estimate_normals(pts, radius_m=radius, viewpoint_xyz_m=viewpoint_xyz_m).normals_xyz
    ok = np.isfinite(normals).all(axis=1)
    if np.count_nonzero(ok) < 2:
        from ..errors import DescriptorError

        raise DescriptorError(f"Only {np.count_nonzero(ok)} of the {len(pts)} points have a normal within "
                              f"normal_radius_m={radius:g} (3 neighbours needed): the radius is too small for "
                              f"the points' spacing (are they in metres?). Use normal_radius_m='auto'.")
    if scale == 1.0:
        return descriptors.compute_vfh(pts[ok], normals[ok], viewpoint_xyz_m=viewpoint_xyz_m, **kwargs)
    return descriptors.compute_vfh(pts[ok] * scale, normals[ok], viewpoint_xyz_m=viewpoint_xyz_m * scale,
                                   **kwargs)


_HELPER: tuple[int, ThreadPoolExecutor] | None = None



def _helper_thread() -> ThreadPoolExecutor:
    """One worker thread for the VFH half of :func:`compute_view_descriptors` (created per process: a forked
    child gets its own, since threads do not survive a fork)."""
    global _HELPER
    if _HELPER is None or _HELPER[0] != os.getpid():
        _HELPER = (os.getpid(), ThreadPoolExecutor(max_workers=1, thread_name_prefix="semslam-vfh"))
    return _HELPER[1]
