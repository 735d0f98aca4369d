"""View-database acquisition with a Kinect-like depth camera, as in the papers (8 partial views per
object, taken offline around it at a fixed elevation, stored in the object's canonical frame).

:data:`SURVEY_KINECT` is the acquisition geometry of the built-in recognition database: the vehicle's
laser looks down from 1-2 m, so objects are seen from 60-90 degrees of elevation, and a Kinect at 1.5 m
has the laser's density (~3 mm/pixel against ~4 mm line spacing) and noise (~3 mm against 2.75 mm).
On simulated missions (``benchmarks/recognition.py``) the nearest-view accuracy of ESF on laser clusters
not cut by the scan border is 55 % with the papers' bench (45 degrees, 0.7 m; with the 5 mm voxel grid),
85 % at 75 degrees and 0.7 m, and 100 % at 75 degrees and 1.5 m. Pose estimation wants the opposite
(less noise, more of the sides): the built-in database also stores views at :data:`POSE_MODEL_KINECT`
(60 degrees, 0.7 m) as the classes' pose models.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_rng, check_int
from ..cloud import PointCloud
from ..errors import SimulationError
from ._ray_kernels import RayCaster, unit
from .config import KinectConfig
from .objects import ObjectModel, builtin_objects

#: Kinect settings matching the survey geometry (see the module docstring).
SURVEY_KINECT = KinectConfig(distance_m=1.5, elevation_rad=float(np.radians(75.0)))

#: Kinect settings of the built-in database's POSE-MODEL views (60 degrees, 0.7 m). Pose estimation fuses
#: these instead of the survey views: at 0.7 m the depth noise is ~4.6 times smaller (sigma_z ~ z^2) and the
#: lower camera sees more of the sides. On the ground-truth clusters of simulated missions
#: (``benchmarks/pose_accuracy.py``, seeds 0-2, altitudes 1 and 1.5 m, 143 clusters) the fused survey views
#: give a median rotation error of ~5 degrees, these 2.1 degrees and 95 % success (45 degrees, 0.7 m: 2.5
#: degrees, 94 %; both at 0.7 m alike on seeds 3-5; survey and pose-model views fused together: worse).
POSE_MODEL_KINECT = KinectConfig(distance_m=0.7, elevation_rad=float(np.radians(60.0)))


def _look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Rotation ``R_parent_camera`` of an OpenCV camera (z forward, x right, y down) at ``eye``."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)  # right = forward x up (y down)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def kinect_view(model: ObjectModel, azimuth_rad: float, *, config: KinectConfig | None = None,
                seed: int | np.random.Generator | None = 0) -> PointCloud:
    """One depth image of ``model`` (alone, in its most probable resting pose) back-projected to points.

    The camera looks at the object's centre of mass from ``config.distance_m`` away, ``config.elevation_rad``
    above the floor, at ``azimuth_rad`` around the vertical. Only pixels whose ray can hit the object are
    cast. Depth noise: sigma_z = ``depth_noise_per_m * z**2``, applied to the disparity
    ``f * b / z``, which is then quantised to ``disparity_step_px``. (Several views of one model:
    :class:`RestScene` prepares the posed mesh and its ray caster once, :meth:`RestScene.view` renders each.)

    Returns
    -------
    PointCloud
        Points (N, 3) in the OBJECT's canonical frame (metres), ``viewpoint_xyz_m`` = the camera centre
        in that frame, ``frame_id="object"``.
    """
    return RestScene(model).view(azimuth_rad, config=config, seed=seed)


class RestScene:
    """``model`` in its most probable resting pose (rest frame: z up, floor z = 0), ready to be seen from any
    azimuth: the posed mesh, the camera's target (centre of mass, or the bounding box's centre when the mesh is
    not watertight), its bounding radius and the mesh's ray caster, computed once (on a mesh of a million faces
    they cost ~2.5 s, the rendering of a view ~0.5 s)."""

    def __init__(self, model: ObjectModel) -> None:
        self.T_rest_object = np.asarray(model.resting_poses[0], dtype=float)
        self.mesh = model.mesh.copy().apply_transform(self.T_rest_object)
        self.target = np.asarray(self.mesh.center_mass if self.mesh.is_watertight else self.mesh.bounds.mean(axis=0),
                                 dtype=float)
        self.radius_m = float(np.linalg.norm(self.mesh.vertices - self.target, axis=1).max())
        self.caster = RayCaster(self.mesh)

    def view(self, azimuth_rad: float, *, config: KinectConfig | None = None,
             seed: int | np.random.Generator | None = 0) -> PointCloud:
        """:func:`kinect_view` of this scene's model."""
        cfg = config or KinectConfig()
        rng = as_rng(seed, caller="kinect_view")
        target = self.target
        ce, se = np.cos(cfg.elevation_rad), np.sin(cfg.elevation_rad)
        eye = target + cfg.distance_m * np.array([ce * np.cos(azimuth_rad), ce * np.sin(azimuth_rad), se])
        R = _look_at(eye, target, np.array([0.0, 0.0, 1.0]))
        # pixels within the object's bounding sphere (plus a margin)
        half = cfg.focal_px * np.tan(np.arcsin(min(self.radius_m * 1.1 / cfg.distance_m, 0.99)))
        cx, cy = (cfg.width_px - 1) / 2, (cfg.height_px - 1) / 2
        us = np.arange(max(0, int(cx - half)), min(cfg.width_px, int(np.ceil(cx + half)) + 1))
        vs = np.arange(max(0, int(cy - half)), min(cfg.height_px, int(np.ceil(cy + half)) + 1))
        u, v = (a.ravel() for a in np.meshgrid(us, vs))
        rays_cam = np.column_stack([(u - cx) / cfg.focal_px, (v - cy) / cfg.focal_px, np.ones(len(u))])
        dirs_rest, _ = unit(rays_cam @ R.T)
        dist, _ = self.caster.first_hit(np.broadcast_to(eye, dirs_rest.shape), dirs_rest)
        hit = np.isfinite(dist)
        z = dist[hit] / np.linalg.norm(rays_cam[hit], axis=1)  # depth along the optical axis
        fb = cfg.focal_px * cfg.baseline_m
        disparity = fb / z + rng.normal(0.0, 1.0, len(z)) * cfg.depth_noise_per_m * fb  # sigma_z = k z^2
        if cfg.disparity_step_px > 0:
            disparity = np.round(disparity / cfg.disparity_step_px) * cfg.disparity_step_px
        z_meas = fb / disparity
        pts_cam = rays_cam[hit] * z_meas[:, None]
        T_object_rest = np.linalg.inv(self.T_rest_object)
        pts_rest = pts_cam @ R.T + eye
        pts_obj = pts_rest @ T_object_rest[:3, :3].T + T_object_rest[:3, 3]
        eye_obj = T_object_rest[:3, :3] @ eye + T_object_rest[:3, 3]
        return PointCloud(pts_obj, viewpoint_xyz_m=eye_obj, frame_id="object")


def acquire_views(model: ObjectModel, *, n_views: int = 8, config: KinectConfig | None = None,
                  seed: int | np.random.Generator | None = 0) -> list[tuple[str, PointCloud]]:
    """``n_views`` Kinect views of ``model`` at azimuths ``360 * k / n_views`` degrees.

    Returns a list of ``(view_id, cloud)`` with ``view_id = "<label>_az<degrees, 3 digits>"``.
    """
    n = check_int("n_views", n_views, caller="acquire_views", minimum=1, maximum=360)
    rng = as_rng(seed, caller="acquire_views")
    scene = RestScene(model)
    out = []
    for k in range(n):
        az = 2 * np.pi * k / n
        cloud = scene.view(az, config=config, seed=rng)
        if cloud.n_points == 0:
            raise SimulationError(
                f"The Kinect view {k} of {model.label!r} saw no point; check KinectConfig.distance_m."
            )
        out.append((f"{model.label}_az{round(np.degrees(az)):03d}", cloud))
    return out


def builtin_view_clouds(
    *, seed: int | np.random.Generator | None = 0, n_views: int = 8, config: KinectConfig | None = None
) -> tuple[list[tuple[str, str, PointCloud]], dict[str, dict]]:
    """The view-database inputs for the four built-in fittings (``semslam db build --builtin``).

    Returns
    -------
    views : list of (label, view_id, PointCloud)
        ``n_views`` partial views per object, points in the OBJECT's canonical frame (metres) with the
        camera centre as ``viewpoint_xyz_m``.
    classes : dict
        Per label ``{"symmetry": Symmetry, "size_xyz_m": ndarray (3,)}``.
    """
    rng = as_rng(seed, caller="builtin_view_clouds")
    views, classes = [], {}
    for label, model in builtin_objects().items():
        for view_id, cloud in acquire_views(model, n_views=n_views, config=config, seed=rng):
            views.append((label, view_id, cloud))
        classes[label] = {"symmetry": model.symmetry, "size_xyz_m": np.array(model.size_xyz_m)}
    return views, classes
