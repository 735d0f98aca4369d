"""A view database of CAD models seen by the sensor that will look for them (issue 29, item 2).

One function, :func:`sensor_database`, used by ``semslam db build --models/--builtin``, ``semslam demo`` and the
benchmarks, so that a database is rendered the same way on every path:

* ``sensor="laser"``: the recognition views are rendered by the vehicle's laser scanner from route-like viewpoints
  (:mod:`semslam.simulation.laser_views`): ``laser_views`` whole views per class (headings every
  ``360 / laser_views`` degrees) plus ``laser_cut_views`` views that the swath's border may cut, so that a cluster
  cut by the scan border is matched against views cut the same way;
* ``sensor="kinect"``: the Kinect-like survey views (``n_views`` azimuths at ``kinect``'s distance and elevation);
* ``sensor="kinect+laser"``: both.

The pose-model views are Kinect views at 0.7 m / 60 degrees in every case (``n_model_views`` per class, in both
resting poses when two are about equally probable), and the database records each class's resting up direction
(:func:`~semslam.simulation.model_views.with_resting_up`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .._progress import Progress
from .._validation import check_choice, check_int
from .config import KinectConfig, ScannerConfig
from .laser_views import LaserViewConfig, laser_view_clouds
from .model_views import models_view_clouds, with_resting_up
from .objects import ObjectModel

__all__ = ["DB_SENSORS", "scanner_from_vehicle", "sensor_database", "sensor_view_clouds"]

#: The sensors a model database can be rendered with.
DB_SENSORS = ("laser", "kinect", "kinect+laser")
#: Whole laser views per class (a heading every 7.5 degrees) and views the swath's border may cut.
LASER_VIEWS = 48
LASER_CUT_VIEWS = 16


def scanner_from_vehicle(vehicle: Any) -> ScannerConfig:
    """The simulated laser scanner of a vehicle file (:class:`~semslam.dataset.VehicleDescription`, or the path of
    its TOML): its mounting, field of view (the same across and along the sweep), lines per sweep, rate, range and
    camera (``scanner.camera_xyz_m``: the simulator's camera lies along the scanner's x axis); the rest (points per
    line, noise; the camera when the file gives none) the simulator's defaults."""
    import math

    from ..dataset.vehicle import VehicleDescription, read_vehicle_toml
    from ..errors import InputError

    if not isinstance(vehicle, VehicleDescription):
        if not isinstance(vehicle, (str, bytes)) and not hasattr(vehicle, "__fspath__"):
            raise InputError(f"The 'vehicle' argument of scanner_from_vehicle must be a VehicleDescription or the path "
                             f"of a vehicle file. Got {type(vehicle).__name__} instead.")
        vehicle = read_vehicle_toml(vehicle)
    sc = vehicle.scanner
    xyz_rpy = sc.T_vehicle_scanner.as_xyz_rpy()
    default = ScannerConfig()
    fov = float(sc.fov_rad)
    if not (0 < fov < math.pi):
        raise InputError(f"The scanner's 'fov_rad' of the vehicle file must be in (0, pi) to render laser views. "
                         f"Got {fov!r} instead.")
    baseline = default.baseline_m
    if sc.camera_xyz_m is not None:
        cam = [float(v) for v in sc.camera_xyz_m]
        if not (cam[0] > 0 and math.hypot(cam[1], cam[2]) <= 1e-3 * cam[0]):
            raise InputError(f"The scanner's 'camera_xyz_m' of the vehicle file must lie along the scanner's +x axis "
                             f"to render laser views (the simulator's triangulation scanner). Got {cam} instead.")
        baseline = cam[0]
    return dataclasses.replace(default, n_lines=int(sc.line_count) or default.n_lines, sweep_fov_rad=fov,
                               baseline_m=baseline,
                               line_fov_rad=fov, scan_rate_hz=float(sc.rate_hz), min_range_m=float(sc.min_range_m),
                               max_range_m=float(sc.max_range_m),
                               T_vehicle_scanner_xyz_m=tuple(float(v) for v in xyz_rpy[:3]),
                               T_vehicle_scanner_rpy_rad=tuple(float(v) for v in xyz_rpy[3:]))


def sensor_view_clouds(models: dict[str, ObjectModel], *, sensor: str = "laser", seed: int = 0, n_views: int = 8,
                       kinect: KinectConfig | None = None, scanner: ScannerConfig | None = None,
                       laser: LaserViewConfig | None = None, laser_views: int = LASER_VIEWS,
                       laser_cut_views: int = LASER_CUT_VIEWS, progress: Progress = False):
    """The recognition views of ``models`` seen by ``sensor`` (see the module docstring): ``(views, classes)`` as
    :func:`~semslam.simulation.model_views.models_view_clouds` returns them.

    ``scanner`` (the vehicle file's laser scanner) replaces the one of ``laser`` (default :class:`LaserViewConfig`:
    the simulated missions' scanner and route). Seeded by ``seed``; the same arguments give the same views."""
    from .kinect import SURVEY_KINECT

    c = "sensor_view_clouds"
    check_choice("sensor", sensor, DB_SENSORS, caller=c)
    check_int("seed", seed, caller=c, minimum=0)
    n_laser = check_int("laser_views", laser_views, caller=c, minimum=1, maximum=3600)
    n_cut = check_int("laser_cut_views", laser_cut_views, caller=c, minimum=0, maximum=3600)
    views, classes = [], {}
    if "kinect" in sensor:
        views, classes = models_view_clouds(models, seed=seed, n_views=n_views, config=kinect or SURVEY_KINECT,
                                            progress=progress)
    if "laser" in sensor:
        lcfg = laser or LaserViewConfig()
        if scanner is not None:
            lcfg = dataclasses.replace(lcfg, scanner=scanner)
        v, classes = laser_view_clouds(models, seed=np.random.default_rng([seed, 7]), n_views=n_laser, config=lcfg,
                                       progress=progress)
        views += v
        if n_cut:
            cut_cfg = dataclasses.replace(lcfg, along_sweep=1.0, allow_cut=True)
            v, _ = laser_view_clouds(models, seed=np.random.default_rng([seed, 8]), n_views=n_cut, config=cut_cfg,
                                     progress=progress)
            views += [(lab, f"{vid}_cut", cloud) for lab, vid, cloud in v]
    return views, classes


def sensor_database(models: dict[str, ObjectModel], *, sensor: str = "laser", seed: int = 0, n_views: int = 8,
                    n_model_views: int = 16, kinect: KinectConfig | None = None,
                    model_kinect: KinectConfig | None = None, scanner: ScannerConfig | None = None,
                    laser: LaserViewConfig | None = None, laser_views: int = LASER_VIEWS,
                    laser_cut_views: int = LASER_CUT_VIEWS, progress: Progress = False, **kwargs: Any):
    """A :class:`~semslam.recognition.ViewDatabase` of ``models`` with recognition views seen by ``sensor``
    (:func:`sensor_view_clouds`, same arguments) and ``n_model_views`` Kinect pose-model views per class at
    ``model_kinect`` (default 0.7 m, 60 degrees; 0: pose estimation uses the recognition views). 16 model views
    (the Kinect databases' 8 before): on benchmarks/real_models.py seed 0 recall 76.9 -> 78.8 %, mean pose NEES
    6.4 -> 5.8; the laser views as the pose model (0) recall 80.8 % but NEES 14. ``kwargs`` go to
    :func:`~semslam.recognition.build_database` (``voxel_leaf_m``, ``normal_radius_m``, ``vfh_variant``,
    ``esf_n_samples``, ``mapper``, ``clean``)."""
    from ..recognition import build_database
    from .kinect import POSE_MODEL_KINECT

    n_model = check_int("n_model_views", n_model_views, caller="sensor_database", minimum=0, maximum=360)
    views, classes = sensor_view_clouds(models, sensor=sensor, seed=seed, n_views=n_views, kinect=kinect,
                                        scanner=scanner, laser=laser, laser_views=laser_views,
                                        laser_cut_views=laser_cut_views, progress=progress)
    model_views = None
    if n_model:
        model_views, _ = models_view_clouds(models, seed=seed, n_views=n_model,
                                            config=model_kinect or POSE_MODEL_KINECT, progress=progress,
                                            tied_rests=True)
    db = with_resting_up(build_database(views, classes, seed=seed, model_views=model_views, progress=progress,
                                        **kwargs), models)
    if "laser" in sensor:  # the camera whose shadows the views have: verification may expect them in queries too
        cam = [float((scanner or (laser or LaserViewConfig()).scanner).baseline_m), 0.0, 0.0]
        object.__setattr__(db, "params", {**db.params, "scanner_camera_xyz_m": cam})
    return db
