"""Synthetic single-object laser scans for tests, calibration and benchmarks (not a public API).

A scanner at the origin of its frame casts a regular grid of rays towards an object mesh placed at
``T_scanner_object``; hits get Gaussian range noise along the ray. Ray casting uses trimesh (embree
when embreex is installed).
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import QhullError
from scipy.spatial.transform import Rotation

from .._validation import as_rng


def scan_mesh(mesh: trimesh.Trimesh, T_scanner_object: np.ndarray, *, n_target_points: int = 2000,
              range_noise_m: float = 0.001, seed=0) -> np.ndarray:
    """Scanner-frame points ``(N, 3)`` of ``mesh`` (object frame) seen from the scanner origin."""
    rng = as_rng(seed)
    m = mesh.copy().apply_transform(T_scanner_object)
    centre, radius = _enclosing_sphere(m)
    d = float(np.linalg.norm(centre))
    half = np.arcsin(min(radius / d, 0.99))
    # angular step so that about n_target_points rays hit (the silhouette covers ~50-70% of the square)
    n_side = max(8, int(np.sqrt(n_target_points / 0.45)))
    a = np.linspace(-half, half, n_side)
    u, v = np.meshgrid(a, a)
    z = centre / d
    x = np.cross(z, [0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    dirs = z[None] + np.tan(u.ravel())[:, None] * x[None] + np.tan(v.ravel())[:, None] * y[None]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origins = np.zeros_like(dirs)
    locs, ray_idx, _ = m.ray.intersects_location(origins, dirs, multiple_hits=False)
    rng_m = np.linalg.norm(locs, axis=1) + rng.normal(0.0, range_noise_m, len(locs))
    return dirs[ray_idx] * rng_m[:, None]


def _enclosing_sphere(mesh: trimesh.Trimesh) -> tuple[np.ndarray, float]:
    """The minimum bounding sphere; a plain cylinder's vertices all lie on one sphere, which Qhull refuses
    ("cospherical"): the bounding-box centre and the farthest vertex from it then."""
    try:
        sphere = mesh.bounding_sphere.primitive
        return np.asarray(sphere.center, dtype=float), float(sphere.radius)
    except QhullError:
        centre = mesh.bounds.mean(axis=0)
        return centre, float(np.linalg.norm(mesh.vertices - centre, axis=1).max())


def random_pose(distance_m: float, seed=0) -> np.ndarray:
    """``T_scanner_object``: uniform random orientation, centre at ``distance_m`` within 20 deg of +x."""
    rng = as_rng(seed)
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng.integers(2**31)).as_matrix()
    az, el = rng.uniform(-0.35, 0.35, 2)
    T[:3, 3] = distance_m * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return T


def model_views(mesh: trimesh.Trimesh, *, n_views: int = 8, distance_m: float = 0.8, elevation_rad: float = 0.5,
                n_points: int = 2500, range_noise_m: float = 0.0003, seed=0) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n_views`` partial views around the object, each ``(points_object (N,3), viewpoint_object (3,))``."""
    rng = as_rng(seed)
    views = []
    for k in range(n_views):
        az = 2 * np.pi * k / n_views
        eye = distance_m * np.array([np.cos(elevation_rad) * np.cos(az), np.cos(elevation_rad) * np.sin(az),
                                     np.sin(elevation_rad)])
        z = -eye / distance_m
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        R_object_scanner = np.column_stack([z, x, np.cross(z, x)])  # scanner x looks at the object
        T_object_scanner = np.eye(4)
        T_object_scanner[:3, :3], T_object_scanner[:3, 3] = R_object_scanner, eye
        pts_s = scan_mesh(mesh, np.linalg.inv(T_object_scanner), n_target_points=n_points,
                          range_noise_m=range_noise_m, seed=rng)
        views.append((pts_s @ R_object_scanner.T + eye, eye))
    return views


def resting_scene_pose(T_rest_object: np.ndarray, distance_m: float, seed=0) -> np.ndarray:
    """``T_scanner_object`` of an object lying in a resting pose (random yaw) seen from above.

    The scanner is ``distance_m`` from the object's centre, 25-70 degrees above the floor, its x axis
    looking at the object (the AUV's scanner looks forward-down).
    """
    rng = as_rng(seed)
    yaw = rng.uniform(-np.pi, np.pi)
    T_world_object = np.eye(4)
    T_world_object[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    T_world_object = T_world_object @ T_rest_object
    centre = T_world_object[:3, 3] + T_world_object[:3, :3] @ np.zeros(3)
    el, az = rng.uniform(np.radians(25), np.radians(70)), rng.uniform(-np.pi, np.pi)
    eye = centre + distance_m * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    x = (centre - eye) / distance_m
    y = np.cross([0.0, 0.0, 1.0], x)
    y /= np.linalg.norm(y)
    T_world_scanner = np.eye(4)
    T_world_scanner[:3, :3] = np.column_stack([x, y, np.cross(x, y)])
    T_world_scanner[:3, 3] = eye
    return np.linalg.inv(T_world_scanner) @ T_world_object


def mesh_model_cloud(mesh: trimesh.Trimesh, n_points: int = 20000, seed=0):
    """A complete model: ``n_points`` uniform surface samples with outward face normals (object frame)."""
    from ..cloud import PointCloud

    pts, face = trimesh.sample.sample_surface(mesh, n_points, seed=int(as_rng(seed).integers(2**31)))
    return PointCloud(np.asarray(pts), normals_xyz=mesh.face_normals[face], frame_id="object")
