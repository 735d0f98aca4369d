"""Synthetic scenes with known objects, shared by several tests (and by the golden generator in
``tests/data/segmentation``)."""

from __future__ import annotations

import numpy as np

from semslam.cloud import PointCloud


def tank_scene(seed=0) -> tuple[PointCloud, list[int]]:
    """Scanner frame (z down): a floor at z = 2 m seen from above, a 20 cm box and a 12 cm ball on it.

    Returns the cloud and, per point, the ground-truth object id (0 floor, 1 box, 2 ball).
    """
    rng = np.random.default_rng(seed)
    floor = np.c_[rng.uniform(-0.6, 0.6, (12000, 2)), 2.0 + rng.normal(0, 0.001, 12000)]
    lo = np.array([-0.3, -0.3, 1.78])
    box = rng.uniform(lo, [-0.1, -0.1, 1.98], (3000, 3))
    face = rng.integers(
        0, 3, 3000
    )  # the three faces the scanner sees: x = -0.3, y = -0.3, z = 1.78
    box[np.arange(3000), face] = lo[face]
    direction = rng.normal(size=(2000, 3))
    ball = [0.3, 0.2, 1.86] + 0.06 * direction / np.linalg.norm(direction, axis=1, keepdims=True)
    pts = np.r_[floor, box, ball]
    labels = np.r_[np.zeros(len(floor)), np.ones(len(box)), np.full(len(ball), 2)].astype(int)
    order = rng.permutation(len(pts))
    return PointCloud(
        pts[order], intensity=labels[order].astype(float), frame_id="scanner"
    ), labels[order]


def flange_mesh():
    """A flange-like part: a 32 cm ring, 3 cm thick, with a raised hub (axis z), as a trimesh mesh (metres)."""
    import trimesh

    rim = trimesh.creation.annulus(r_min=0.05, r_max=0.16, height=0.03)
    hub = trimesh.creation.annulus(r_min=0.05, r_max=0.08, height=0.04)
    hub.apply_translation([0.0, 0.0, 0.035])
    return trimesh.util.concatenate([rim, hub])


def flange_view(tilt_deg: float):
    """:func:`flange_mesh` seen ``tilt_deg`` off its axis from 1 m: the mesh, the true ``T_scanner_object``
    (4, 4), the scan points (scanner frame, 1 mm range noise) and the same points in the object frame."""
    from scipy.spatial.transform import Rotation

    from semslam.simulation.scan_sim import scan_mesh

    mesh = flange_mesh()
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("y", tilt_deg, degrees=True).as_matrix() @ np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [0.02, -0.03, 1.0]
    pts = scan_mesh(mesh, T, n_target_points=4000, range_noise_m=0.001, seed=np.random.default_rng(3))
    return mesh, T, pts, (pts - T[:3, 3]) @ T[:3, :3]


#: A roof over a floor plate seen by a triangulation laser (scanner frame, z forward, down onto the plates): the
#: laser at the origin, its camera 0.3 m along x; the plates' depths and the roof's extent (metres).
ROOF_CAMERA = np.array([0.3, 0.0, 0.0])
ROOF_FLOOR_Z, ROOF_Z = 1.5, 1.2
ROOF_X, ROOF_Y = (0.0, 0.1), (-0.1, 0.1)


def roof_plates(step=0.004):
    """The floor plate and the roof above it: points (N, 3), normals facing the scanner (N, 3), and the number of
    floor points (they come first)."""
    g = np.arange(-0.2, 0.2 + 1e-9, step)
    x, y = np.meshgrid(g, g, indexing="ij")
    floor = np.c_[x.ravel(), y.ravel(), np.full(x.size, ROOF_FLOOR_Z)]
    x, y = np.meshgrid(np.arange(ROOF_X[0], ROOF_X[1] + 1e-9, step), np.arange(ROOF_Y[0], ROOF_Y[1] + 1e-9, step),
                       indexing="ij")
    roof = np.c_[x.ravel(), y.ravel(), np.full(x.size, ROOF_Z)]
    pts = np.vstack([floor, roof])
    return pts, np.tile([0.0, 0.0, -1.0], (len(pts), 1)), len(floor)


def under_roof(p, eye):
    """Does the segment from the floor points ``p`` (N, 3) to ``eye`` (3,) cross the roof (its analytic shadow)?"""
    eye = np.asarray(eye, dtype=float)
    s = (ROOF_Z - p[:, 2]) / (eye[2] - p[:, 2])
    q = p + s[:, None] * (eye - p)
    return (q[:, 0] >= ROOF_X[0]) & (q[:, 0] <= ROOF_X[1]) & (q[:, 1] >= ROOF_Y[0]) & (q[:, 1] <= ROOF_Y[1])
