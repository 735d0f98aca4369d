"""Per-class quantities of a view database that the recogniser's plausibility tests compare clusters with: the
size test's limit of a class and the surface of its views. Pure functions of the database and the settings;
:class:`~semslam.pipeline.scan.ScanRecognizer` caches them (``class_size_limit_m``, ``class_view_area_m2``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..recognition.plausibility import max_plausible_extent_m, principal_extent

__all__ = ["class_size_limit_m", "grid_area_m2", "median_view_area_m2"]


def class_size_limit_m(db: Any, config: Any, label: str) -> float:
    """The size test's limit for class ``label`` of ``db`` under ``config`` (a
    :class:`~semslam.pipeline.config.PipelineConfig`): :func:`~semslam.recognition.plausibility.max_plausible_extent_m`
    of the class's longest dimension: its bounding box's longest side, or with ``size_reference="principal"`` the
    larger of that and the largest principal extent of its pose-model views fused in the object frame (at most the
    box's diagonal). The clusters are measured along their principal axes: an L-shaped part (the butterfly valve:
    box 0.232 m, principal 0.299 m) seen whole is longer that way than its box's longest side, and a box-side limit
    rejects it."""
    size = np.asarray(db.class_info(label).size_xyz_m, dtype=np.float64)
    longest = float(size.max())
    pts = [v.points_xyz_m for v in db.pose_views(label) if v.n_points] if config.size_reference == "principal" \
        else []
    if pts:
        fused = np.ascontiguousarray(np.vstack(pts), dtype=np.float64)
        longest = max(longest, min(float(principal_extent(fused)[0]), float(np.linalg.norm(size))))
    return max_plausible_extent_m(np.full(3, longest), tolerance=config.size_tolerance, slack_m=config.size_slack_m)


def grid_area_m2(points: np.ndarray, leaf_m: float) -> float:
    """Surface of ``points`` as the occupied cells of a ``leaf_m`` grid times the cell's face (m^2)."""
    if not len(points):
        return 0.0
    keys = np.floor(points / leaf_m).astype(np.int64)
    return float(len(np.unique(keys, axis=0))) * leaf_m * leaf_m


def median_view_area_m2(db: Any, label: str, leaf_m: float) -> float:
    """Median surface (:func:`grid_area_m2`) of the views of class ``label`` of ``db`` on a ``leaf_m`` grid."""
    areas = [grid_area_m2(db.view_cloud(int(i)).points_xyz_m, leaf_m) for i in db.views_of(label)]
    return float(np.median(areas)) if areas else 0.0
