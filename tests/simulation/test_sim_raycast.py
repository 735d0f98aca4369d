"""The scanner's ray casting (large faces in numba, small faces culled by bounding spheres, then
Embree) against a brute-force float64 Moller-Trumbore oracle over every face of the scene."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from semslam.errors import SimulationError
from semslam.geometry import rotation_from_rpy
from semslam.simulation import LaserScanner, ScannerConfig
from semslam.simulation._ray_kernels import RayCaster
from semslam.simulation.scanner import BACKSCATTER

END_GAP_M = 1e-3


def _box(lo, hi, rpy=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    T = np.eye(4)
    T[:3, :3] = rotation_from_rpy(*rpy)
    T[:3, 3] = (lo + hi) / 2
    return trimesh.creation.box(extents=hi - lo, transform=T)


def _scene() -> tuple[RayCaster, np.ndarray]:
    """Floor (z = 1.5, scanner looks along +z), a tilted wall, a sphere, a tall post and a tilted
    cylinder: large faces at several angles, small faces casting laser and camera shadows."""
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.15)
    sphere.apply_translation((0.12, 0.05, 1.25))
    cyl = trimesh.creation.cylinder(radius=0.06, height=0.5, sections=24)
    cyl.apply_transform(trimesh.transformations.rotation_matrix(1.1, (0.3, 1.0, 0.2)))
    cyl.apply_translation((-0.3, -0.25, 1.3))
    parts = [_box((-10, -10, 1.5), (10, 10, 1.6)), _box((0.55, -3, 0.0), (0.65, 3, 3.0), rpy=(0.2, -0.5, 0.1)),
             sphere, _box((-0.35, 0.2, 1.1), (-0.27, 0.28, 1.5)), cyl]
    owner = np.concatenate([np.full(len(m.faces), i - 1) for i, m in enumerate(parts)])
    return RayCaster(trimesh.util.concatenate(parts)), owner


def _poses(n_lines: int) -> tuple[np.ndarray, np.ndarray]:
    """A scanner moving and turning during the sweep (one pose per line)."""
    k = np.linspace(0.0, 1.0, n_lines)
    R = np.stack([rotation_from_rpy(0.1 * kk, -0.15 + 0.2 * kk, 0.3 * kk) for kk in k])
    t = np.column_stack([0.2 * k - 0.1, 0.1 * k, 0.05 * k])
    return np.ascontiguousarray(R), np.ascontiguousarray(t)


def _brute(origins, dirs, tris, t_max=None):
    """First hit distance (inf none) of each ray over all triangles; with ``t_max``: True where a
    triangle lies on the segment 0 < t < t_max."""
    out = []
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    for s in range(0, len(origins), 300):
        o, d = origins[s:s + 300, None], dirs[s:s + 300, None]
        p = np.cross(d, e2[None])
        det = np.sum(e1[None] * p, axis=-1)
        ok = np.abs(det) > 1e-14
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        w = o - tris[None, :, 0]
        u = np.sum(w * p, axis=-1) * inv
        q = np.cross(w, e1[None])
        v = np.sum(d * q, axis=-1) * inv
        t = np.sum(e2[None] * q, axis=-1) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        if t_max is None:
            out.append(np.where(hit, t, np.inf).min(axis=1))
        else:
            out.append((hit & (t < t_max[s:s + 300, None])).any(axis=1))
    return np.concatenate(out)


def _check_against_brute(scanner, caster, owner, split):
    R, t = _poses(scanner.config.n_lines)
    tr = scanner._trace(caster, R, t, split)
    m = scanner.config.points_per_line
    line = np.arange(len(tr.tri)) // m
    origins = t[line]
    dirs = np.einsum("nij,nj->ni", R[line], scanner._dirs_flat)
    tris = caster.mesh.vertices[caster.mesh.faces]
    # laser: the first surface along every ray
    dist = _brute(origins, dirs, tris)
    assert np.array_equal(np.isinf(dist), np.isinf(tr.laser_m))
    hit = np.isfinite(dist)
    np.testing.assert_allclose(tr.laser_m[hit], dist[hit], rtol=1e-9, atol=1e-9)
    assert np.sum(owner[tr.tri[hit]] >= 1) > 100  # the small objects are hit
    # camera: the segment from the camera to just before the lit point
    ln = tr.idx // m
    cam = t[ln] + np.einsum("nij,j->ni", R[ln], scanner.camera_xyz_scanner)
    target = origins[tr.idx] + dirs[tr.idx] * tr.laser_m[tr.idx, None]
    to = target - cam
    r = np.linalg.norm(to, axis=1)
    np.testing.assert_allclose(r, tr.camera_m, rtol=1e-12)
    blocked = _brute(cam, to / r[:, None], tris, t_max=r - END_GAP_M)
    assert 20 < blocked.sum() < len(blocked) - 1000  # the scene has camera shadows
    np.testing.assert_array_equal(tr.seen, ~blocked)
    return tr


@pytest.fixture(scope="module")
def scene():
    return _scene()


def test_split_ray_casting_matches_brute_force(scene):
    caster, owner = scene
    sp = caster.split()
    assert len(sp.large_ids) == 24  # floor and wall boxes
    assert 0 < len(sp.sphere_radius) < 20 and sp.small_scene is not None
    tr = _check_against_brute(LaserScanner(ScannerConfig(n_lines=48, points_per_line=40)), caster, owner, sp)
    assert np.mean(tr.seen) > 0.5


def test_unsplit_fallback_matches_brute_force(scene):
    caster, owner = scene
    sp = caster.split(max_large_faces=0)  # every face in Embree, no culling
    assert len(sp.large_ids) == 0 and np.isinf(sp.sphere_radius).all()
    _check_against_brute(LaserScanner(ScannerConfig(n_lines=48, points_per_line=40)), caster, owner, sp)


def test_small_groups_bound_their_faces(scene):
    caster, _ = scene
    sp = caster.split(group_size_m=0.1)
    tris = caster.mesh.vertices[caster.mesh.faces[sp.small_ids]]  # (S, 3, 3)
    d = np.linalg.norm(tris[:, :, None, :] - sp.sphere_centre[None, None], axis=-1)  # (S, 3, G)
    inside = (d <= sp.sphere_radius[None, None]).all(axis=1).any(axis=1)
    assert inside.all() and len(sp.sphere_radius) > 3
    assert not np.isin(sp.large_ids, sp.small_ids).any()


def test_scan_output_is_in_ray_order_with_ground_truth(scene):
    caster, owner = scene
    scanner = LaserScanner(ScannerConfig(n_lines=48, points_per_line=40, backscatter_prob=0.05))
    R, t = _poses(48)
    T = np.tile(np.eye(4), (48, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R, t
    cloud = scanner.scan(caster, T, seed=4, face_instance=owner).cloud
    line, inst = cloud.fields["line"], cloud.fields["instance"]
    assert np.all(np.diff(line) >= 0)
    assert set(np.unique(inst)) >= {-2, -1, 1, 2}
    # instance = owner of the face the noise-free trace hit, point for point
    tr = scanner._trace(caster, R, t)
    again = scanner.scan(caster, T, seed=4, face_instance=owner).cloud
    np.testing.assert_array_equal(again.points_xyz_m, cloud.points_xyz_m)
    surf = inst != BACKSCATTER
    assert surf.sum() <= tr.seen.sum()
    assert np.isin(inst[surf], owner[tr.tri[tr.idx[tr.seen]]]).all()


def test_scan_rejects_face_instance_of_wrong_length(scene):
    caster, owner = scene
    scanner = LaserScanner(ScannerConfig(n_lines=10, points_per_line=10))
    with pytest.raises(SimulationError, match="face_instance"):
        scanner.scan(caster, np.eye(4), face_instance=owner[:-1])
