"""Rendering users' CAD models into view-database inputs (Kinect views around each class in its resting
pose) and recording their resting up direction in a database (see :mod:`semslam.simulation.cad_models`)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from .._progress import Progress, progress_steps
from .._validation import as_rng, check_int
from ..cloud import PointCloud
from ..errors import DatabaseError
from .config import KinectConfig
from .objects import ObjectModel

__all__ = ["TIE_RATIO", "models_view_clouds", "resting_up_objects", "whole_part_config", "with_resting_up"]

#: Resting poses this close in probability (second / first) are both used for the pose-model views.
TIE_RATIO = 0.9


def models_view_clouds(models: dict[str, ObjectModel], *, seed: int | np.random.Generator | None = 0, n_views: int = 8,
                       config: KinectConfig | None = None, progress: Progress = False, tied_rests: bool = False,
                       ) -> tuple[list[tuple[str, str, PointCloud]], dict[str, dict]]:
    """The view-database inputs for ``models`` (as :func:`~semslam.simulation.kinect.builtin_view_clouds`).

    Each object is seen in its most probable resting pose, at azimuths ``360 * k / n_views`` degrees, from
    ``config``'s distance or, for a part too large to fit in the image from there, from farther
    (:func:`whole_part_config`). With
    ``tied_rests``, an object whose second resting pose is about as probable (within :data:`TIE_RATIO`: a
    mirror-symmetric part lies on either face) is seen in both, alternately (even ``k`` in the first, odd
    ``k`` in the second, view id suffixed ``_rest1``): the pose-model views then cover both faces, which
    keeps a near-symmetric part (the elbow, whose legs differ by 13 mm) from being fitted turned over.

    Returns
    -------
    views : list of (label, view_id, PointCloud)
        ``n_views`` Kinect views per class, points in the object's canonical frame (metres), the camera
        centre as ``viewpoint_xyz_m``.
    classes : dict
        Per label ``{"symmetry": Symmetry, "size_xyz_m": ndarray (3,)}``.
    """
    from .kinect import RestScene

    caller = "models_view_clouds"
    if not isinstance(models, dict) or not models or not all(isinstance(m, ObjectModel) for m in models.values()):
        raise DatabaseError(f"The 'models' argument of {caller} must be a non-empty dict label -> ObjectModel. "
                            f"Got {models!r:.60} instead.")
    n = check_int("n_views", n_views, caller=caller, minimum=1, maximum=360)
    cfg = config or KinectConfig()
    rng = as_rng(seed, caller=caller)
    views, classes = [], {}
    with progress_steps(progress, n * len(models), "render views", "view") as step:
        for label, model in models.items():
            rests = _tied_rests(model) if tied_rests else [0]
            scenes = {rest: RestScene(model if rest == 0 else
                                      dataclasses.replace(model, resting_poses=[model.resting_poses[rest]]))
                      for rest in rests}
            seen = whole_part_config(cfg, max(scene.radius_m for scene in scenes.values()))
            for k in range(n):
                az = 2 * np.pi * k / n
                rest = rests[k % len(rests)]
                cloud = scenes[rest].view(az, config=seen, seed=rng)
                if cloud.n_points == 0:
                    raise DatabaseError(f"The Kinect view {k} of the class {label!r} saw no point (distance "
                                        f"{seen.distance_m:g} m, elevation {math.degrees(seen.elevation_rad):g} deg).")
                views.append(
                    (label, f"{label}_az{round(np.degrees(az)):03d}" + (f"_rest{rest}" if rest else ""), cloud)
                )
                step()
            classes[label] = {"symmetry": model.symmetry, "size_xyz_m": np.array(model.size_xyz_m)}
    return views, classes


def whole_part_config(config: KinectConfig, radius_m: float) -> KinectConfig:
    """``config``, its camera moved back when a part of bounding radius ``radius_m`` (about the camera's target)
    would not fit in the image: to ``radius_m / sin(half the narrower field of view)``, so that every view sees the
    whole part (a part larger than about 0.6 m across at the pose-model views' 0.7 m). A part that fits keeps
    ``config`` as it is (its views unchanged)."""
    half_fov = math.atan((min(config.width_px, config.height_px) - 1) / 2 / config.focal_px)
    needed = radius_m / math.sin(half_fov)
    return config if config.distance_m >= needed else dataclasses.replace(config, distance_m=needed)


def resting_up_objects(models: dict) -> dict[str, list]:
    """``{label: up}``: each class's up direction in its object frame when it rests on a level floor in its most
    probable resting pose, ``R_rest_object^T (0, 0, 1)``. Classes whose most probable rest is tied with another
    (a part that lies on either of two faces) are left out: their up is not one direction. Recorded in a
    database as ``params["up_object"]`` (:meth:`~semslam.recognition.ViewDatabase.up_object`), it lets the
    pipeline pose them upright when the scan's up is known (``recognize --up``, ``run --up-from-attitude``)."""
    out = {}
    for label, model in models.items():
        if not model.resting_poses or _tied_rests(model) != [0]:
            continue
        out[label] = _rest_up(model, 0)
    return out


def tied_up_objects(models: dict) -> dict[str, list]:
    """``{label: [up_0, up_1]}`` for the classes that :func:`resting_up_objects` leaves out because two resting poses
    are about equally probable (a part that lies on either face): the up direction of each, in the object frame.
    Recorded as ``params["up_object_tied"]`` (:meth:`~semslam.recognition.ViewDatabase.up_objects`), it lets the
    pose search consider both ways up and no other (and report a near-equal flip between them as ambiguous)."""
    out = {}
    for label, model in models.items():
        rests = _tied_rests(model)
        if len(rests) < 2:
            continue
        out[label] = [_rest_up(model, r) for r in rests]
    return out


def _rest_up(model: ObjectModel, rest: int) -> list[float]:
    """The up direction (unit, object frame) of ``model`` lying in its resting pose ``rest``:
    ``R_rest_object^T (0, 0, 1)``."""
    up = np.asarray(model.resting_poses[rest], dtype=float)[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    return [float(v) for v in up / np.linalg.norm(up)]


def with_resting_up(db: Any, models: dict) -> Any:
    """``db`` with :func:`resting_up_objects` of ``models`` recorded in its ``params["up_object"]`` and
    :func:`tied_up_objects` in ``params["up_object_tied"]``."""
    ups = {k: v for k, v in resting_up_objects(models).items() if k in db.classes}
    tied = {k: v for k, v in tied_up_objects(models).items() if k in db.classes}
    extra = ({"up_object": ups} if ups else {}) | ({"up_object_tied": tied} if tied else {})
    if extra:
        object.__setattr__(db, "params", {**db.params, **extra})
    return db


def _tied_rests(model: ObjectModel) -> list[int]:
    """Indices of the resting poses of ``model`` within TIE_RATIO of the most probable one (at most 2)."""
    p = np.asarray(model.resting_probabilities, dtype=float)
    if len(model.resting_poses) < 2 or len(p) < 2 or p[0] <= 0:
        return [0]
    return [0, 1] if p[1] >= TIE_RATIO * p[0] else [0]
