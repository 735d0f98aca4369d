"""The virtual laser scanner: geometry, noise, occlusion from the laser and from the camera."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from semslam.errors import SimulationError
from semslam.simulation import LaserScanner, ScannerConfig
from semslam.simulation._ray_kernels import RayCaster
from semslam.simulation.scanner import BACKSCATTER

PLANE_Z = 1.5


def _box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2))


def _scene(*meshes):
    floor = _box((-10, -10, PLANE_Z), (10, 10, PLANE_Z + 0.1))
    parts = [floor, *meshes]
    owner = np.concatenate([np.full(len(m.faces), i - 1) for i, m in enumerate(parts)])
    return RayCaster(trimesh.util.concatenate(parts)), owner


def _cfg(**kw) -> ScannerConfig:
    base = dict(n_lines=60, points_per_line=60, dropout_prob=0.0, backscatter_prob=0.0,
                noise_floor_m=0.001, noise_range2_per_m=0.004)
    base.update(kw)
    return ScannerConfig(**base)


def test_plane_at_known_distance_has_the_configured_noise():
    scanner = LaserScanner(_cfg())
    caster, owner = _scene()
    cloud = scanner.scan(caster, np.eye(4), seed=0, face_instance=owner).cloud  # scanner frame = world
    assert cloud.frame_id == "scanner" and cloud.n_points > 3000
    p = cloud.points_xyz_m
    cam = scanner.camera_xyz_scanner
    ray = p - cam
    r = np.linalg.norm(ray, axis=1)
    sigma_perp = (0.001 + 0.004 * r**2) * np.abs(ray[:, 2]) / r  # noise is along the camera ray
    z = (p[:, 2] - PLANE_Z) / sigma_perp
    assert abs(z.mean()) < 0.1
    assert 0.92 < z.std() < 1.08
    # the laser sweep: points lie on the laser planes, inside the configured fields of view
    a = np.arctan2(p[:, 0], p[:, 2])
    assert np.abs(a).max() < scanner.config.sweep_fov_rad / 2 + 0.01


def test_noise_free_points_are_exact_and_dropouts_and_backscatter_follow_their_rates():
    caster, owner = _scene()
    exact = LaserScanner(_cfg(noise_floor_m=0.0, noise_range2_per_m=0.0)).scan(caster, np.eye(4), seed=1).cloud
    np.testing.assert_allclose(exact.points_xyz_m[:, 2], PLANE_Z, atol=1e-9)
    n_all = exact.n_points
    dropped = LaserScanner(_cfg(dropout_prob=0.3)).scan(caster, np.eye(4), seed=2, face_instance=owner).cloud
    expected = 0.7 * n_all
    assert abs(dropped.n_points - expected) < 4 * np.sqrt(n_all * 0.3 * 0.7)
    scat = LaserScanner(_cfg(backscatter_prob=0.05)).scan(caster, np.eye(4), seed=3, face_instance=owner).cloud
    n_bs = int(np.sum(scat.fields["instance"] == BACKSCATTER))
    assert abs(n_bs - 0.05 * 3600) < 4 * np.sqrt(3600 * 0.05 * 0.95)
    bs = scat.points_xyz_m[scat.fields["instance"] == BACKSCATTER]
    assert np.all(bs[:, 2] < PLANE_Z) and np.all(np.linalg.norm(bs, axis=1) >= 0.3 - 1e-9)


def test_object_hidden_behind_another_yields_no_point():
    big = _box((-0.3, -0.3, 1.0), (0.3, 0.3, 1.2))
    hidden = _box((-0.05, -0.05, 1.4), (0.05, 0.05, PLANE_Z))
    caster, owner = _scene(big, hidden)
    inst = LaserScanner(_cfg()).scan(caster, np.eye(4), seed=0, face_instance=owner).cloud.fields["instance"]
    assert np.sum(inst == 0) > 100  # the front box is seen
    assert np.sum(inst == 1) == 0  # the hidden one is not
    # control: without the front box the small one is seen
    caster2, owner2 = _scene(_box((5, 5, 1.0), (5.1, 5.1, 1.1)), hidden)
    inst2 = LaserScanner(_cfg()).scan(caster2, np.eye(4), seed=0, face_instance=owner2).cloud.fields["instance"]
    assert np.sum(inst2 == 1) > 5


def test_point_lit_by_the_laser_but_hidden_from_the_camera_is_not_measured():
    target = _box((-0.35, -0.05, 1.4), (-0.25, 0.05, PLANE_Z))
    # a plate between the camera (x = +0.3) and the target that leaves the laser ray free
    plate = _box((0.0, -0.2, 0.5), (0.2, 0.2, 0.51))
    caster, owner = _scene(target, plate)
    cfg = _cfg(n_lines=120, camera_toe_in_rad=0.2)
    inst = LaserScanner(cfg).scan(caster, np.eye(4), seed=0, face_instance=owner).cloud.fields["instance"]
    assert np.sum(inst == 0) == 0
    caster2, owner2 = _scene(target, _box((5, 5, 0.5), (5.2, 5.2, 0.51)))
    inst2 = LaserScanner(cfg).scan(caster2, np.eye(4), seed=0, face_instance=owner2).cloud.fields["instance"]
    assert np.sum(inst2 == 0) > 5


def test_motion_during_a_scan_distorts_it():
    """Moving along x during the sweep: each line is in its own scanner frame, so a floor line seen
    while moving is shifted by the motion made since the first line."""
    caster, _ = _scene()
    scanner = LaserScanner(_cfg(noise_floor_m=0.0, noise_range2_per_m=0.0))
    n = scanner.config.n_lines
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    T[:, 0, 3] = np.linspace(0.0, 0.5, n)  # 0.5 m during the scan
    moving = scanner.scan(caster, T, seed=0).cloud
    static = scanner.scan(caster, np.eye(4), seed=0).cloud
    # on a flat floor the per-line local coordinates do not change with a pure translation ...
    np.testing.assert_allclose(np.sort(moving.points_xyz_m[:, 0]), np.sort(static.points_xyz_m[:, 0]), atol=1e-9)
    # ... but a step in the floor shows up shifted: the world point of line k is local + x_k
    step = _box((0.2, -10, 1.3), (10, 10, PLANE_Z))
    caster_s, _ = _scene(step)
    moved = scanner.scan(caster_s, T, seed=0).cloud
    line = moved.fields["line"]
    world_x = moved.points_xyz_m[:, 0] + T[line, 0, 3]
    on_step = np.abs(moved.points_xyz_m[:, 2] - 1.3) < 1e-6
    assert world_x[on_step].min() > 0.2 - 1e-6  # in the world the step edge is where it is
    assert moved.points_xyz_m[on_step, 0].min() < 0.2 - 0.05  # but the raw scan shows it displaced


def test_scan_rejects_bad_poses_and_config():
    scanner = LaserScanner(_cfg())
    caster, _ = _scene()
    with pytest.raises(SimulationError, match="T_world_scanner_lines"):
        scanner.scan(caster, np.eye(3))
    with pytest.raises(SimulationError, match="min_range_m"):
        ScannerConfig(min_range_m=5.0, max_range_m=4.0)
    with pytest.raises(SimulationError, match="dropout_prob"):
        ScannerConfig(dropout_prob=1.5)
