"""What :func:`~semslam.segmentation.scene.segment_scene` does before its voxel grid: keep the valid returns
within the sensor's working range, and resolve the ``"auto"`` lengths from the cloud's measured point spacing.

* **Invalid returns at the sensor origin** (``drop_origin``): depth cameras (RealSense, Kinect through many
  drivers) store a pixel without depth as the point ``(0, 0, 0)`` of the camera frame instead of NaN. No real
  return lies exactly at the sensor origin (the cloud's ``viewpoint_xyz_m``), so such points are always
  invalid; the test is exact (``x == y == z == 0`` relative to the viewpoint), so no laser point moves.
  ``SegmentationConfig(drop_origin=...)`` is False by default (a synthetic cloud may hold the point
  ``(0, 0, 0)``); ``semslam segment`` and ``semslam recognize`` turn it on (``--keep-origin-points``: off).
* **Working range** (``min_range_m``, ``max_range_m``): points nearer or farther than these distances from the
  viewpoint are left out (a depth camera sees the whole room behind the object; a laser scanner its own
  housing). Default: no limit.
* **Scale from the data** (``voxel_leaf_m="auto"``, ``cluster_tolerance_m="auto"``): the defaults (5 mm grid,
  2 cm tolerance) suit a laser at 1-3 m; a depth camera at 30 cm samples every 1.5-2 mm. ``"auto"`` measures
  the point spacing ``s`` of the kept points (:func:`semslam.descriptors.point_spacing_m`: median distance to
  the 4th nearest neighbour, seeded subsample) and uses a leaf of ``AUTO_LEAF_SPACINGS * s`` and a tolerance
  of ``AUTO_TOLERANCE_LEAVES`` leaves (the default's ratio, 20 mm / 5 mm), or ``AUTO_TOLERANCE_LEAVES * s``
  without a voxel grid.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InputError

__all__ = ["AUTO", "AUTO_LEAF_SPACINGS", "AUTO_TOLERANCE_LEAVES", "check_length_or_auto", "resolve_lengths",
           "valid_return_mask"]

#: The value of a length option that is measured from the cloud.
AUTO = "auto"
#: Voxel leaf of ``voxel_leaf_m="auto"`` in measured point spacings.
AUTO_LEAF_SPACINGS = 1.0
#: Cluster tolerance of ``cluster_tolerance_m="auto"`` in voxel leaves (or point spacings without a grid).
AUTO_TOLERANCE_LEAVES = 4.0


def check_length_or_auto(name: str, value: Any, *, caller: str, allow_none: bool = False) -> None:
    """Raise :class:`InputError` naming ``name`` unless ``value`` is a finite length > 0, ``"auto"``
    (or None when ``allow_none``)."""
    if value is None and allow_none:
        return
    if isinstance(value, str):
        if value == AUTO:
            return
        ok = False
    elif isinstance(value, bool):
        ok = False
    else:
        try:
            ok = bool(np.isfinite(float(value)) and float(value) > 0)
        except (TypeError, ValueError):
            ok = False
    if not ok:
        extra = ", None" if allow_none else ""
        raise InputError(f"The {name!r} argument of {caller} must be a finite length > 0 in metres, 'auto'{extra}. "
                         f"Got {value!r} instead.")


def valid_return_mask(points_xyz_m: np.ndarray, viewpoint_xyz_m: np.ndarray, *, drop_origin: bool = True,
                      min_range_m: float = 0.0, max_range_m: float | None = None) -> np.ndarray | None:
    """Boolean mask of the points kept (see the module docstring), or None when every point is kept."""
    if len(points_xyz_m) == 0 or not (drop_origin or min_range_m > 0 or max_range_m is not None):
        return None  # nothing to test: no pass over the points (the laser defaults)
    rel = points_xyz_m - np.asarray(viewpoint_xyz_m, dtype=np.float64)[None, :]
    keep = np.ones(len(points_xyz_m), dtype=bool)
    if drop_origin:
        keep &= (rel != 0.0).any(axis=1)
    if min_range_m > 0 or max_range_m is not None:
        r2 = np.einsum("ij,ij->i", rel, rel)
        if min_range_m > 0:
            keep &= r2 >= min_range_m * min_range_m
        if max_range_m is not None:
            keep &= r2 <= max_range_m * max_range_m
    return None if keep.all() else keep


def resolve_lengths(points_xyz_m: np.ndarray, voxel_leaf_m: Any, cluster_tolerance_m: Any, *,
                    seed: int = 0) -> tuple[float | None, float, float | None]:
    """``(voxel leaf or None, cluster tolerance, measured spacing or None)`` with ``"auto"`` resolved from the
    points' spacing; the spacing is measured only when an ``"auto"`` needs it (and is None otherwise, or when
    fewer than 5 points leave nothing to measure: the laser defaults, 5 mm and 20 mm, are then used)."""
    if voxel_leaf_m != AUTO and cluster_tolerance_m != AUTO:
        return (None if voxel_leaf_m is None else float(voxel_leaf_m)), float(cluster_tolerance_m), None
    from ..descriptors.spacing import point_spacing_m
    from ..errors import DescriptorError

    spacing = None
    if len(points_xyz_m) >= 5:
        try:
            spacing = point_spacing_m(points_xyz_m, seed=seed)
        except DescriptorError:  # all points duplicated: nothing to measure
            spacing = None
    leaf: float | None
    if voxel_leaf_m == AUTO:
        leaf = 0.005 if spacing is None else AUTO_LEAF_SPACINGS * spacing
    else:
        leaf = None if voxel_leaf_m is None else float(voxel_leaf_m)
    if cluster_tolerance_m == AUTO:
        unit = leaf if leaf is not None else spacing
        tol = 0.02 if unit is None else AUTO_TOLERANCE_LEAVES * unit
    else:
        tol = float(cluster_tolerance_m)
    return leaf, tol, spacing
