"""Object meshes and Kinect view acquisition of the simulator."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import Delaunay, cKDTree

from semslam.errors import InputError, SimulationError
from semslam.simulation import (
    KinectConfig,
    ObjectModel,
    acquire_views,
    builtin_objects,
    builtin_view_clouds,
    kinect_view,
    load_object,
    make_object,
)
from semslam.simulation._ray_kernels import RayCaster
from semslam.symmetry import Symmetry

EXPECTED_SIZE_MM = {"reducing_tee": (107, 74, 63), "reducing_socket": (57, 57, 63), "elbow": (76, 41, 63),
                    "ball_valve": (85, 125, 63)}


@pytest.fixture(scope="module")
def objects() -> dict[str, ObjectModel]:
    return builtin_objects()


def _xor_volume(mesh: trimesh.Trimesh, R: np.ndarray) -> float:
    """Volume of the mesh minus its rotated copy (0 when the rotation is a symmetry)."""
    T = np.eye(4)
    T[:3, :3] = R
    return float(trimesh.boolean.difference([mesh, mesh.copy().apply_transform(T)], engine="manifold").volume)


def test_builtin_objects_sizes_frames_watertight(objects):
    assert tuple(objects) == ("reducing_tee", "reducing_socket", "elbow", "ball_valve")
    for label, model in objects.items():
        assert model.label == label
        assert model.mesh.is_watertight and model.mesh.volume > 0
        np.testing.assert_allclose(model.size_xyz_m * 1000, EXPECTED_SIZE_MM[label], atol=0.5)
        np.testing.assert_allclose(model.mesh.bounds.mean(axis=0), 0.0, atol=1e-9)  # canonical origin = box centre


@pytest.mark.parametrize("label, angle, axis, symmetric", [
    ("reducing_tee", np.pi, (0, 1, 0), True),
    ("reducing_tee", np.pi, (1, 0, 0), False),
    ("reducing_socket", 0.7, (0, 0, 1), True),
    ("reducing_socket", np.pi, (1, 0, 0), False),
    ("elbow", np.pi, (1, 0, 0), False),
    ("ball_valve", np.pi, (0, 1, 0), False),
])
def test_declared_symmetry_matches_geometry(objects, label, angle, axis, symmetric):
    model = objects[label]
    R = trimesh.transformations.rotation_matrix(angle, axis)[:3, :3]
    frac = _xor_volume(model.mesh, R) / model.mesh.volume
    if symmetric:
        assert frac < 0.01  # only faceting differs
        sym = model.symmetry
        assert sym.kind in ("discrete", "continuous") and abs(abs(np.dot(sym.axis_object, axis)) - 1) < 1e-12
    else:
        assert frac > 0.05


def test_declared_symmetry_kinds(objects):
    assert objects["reducing_tee"].symmetry.order == 2
    assert objects["reducing_socket"].symmetry.kind == "continuous"
    assert objects["elbow"].symmetry.kind == "none" and objects["ball_valve"].symmetry.kind == "none"


def test_resting_poses_are_on_the_floor_and_stable(objects):
    for model in objects.values():
        assert 1 <= len(model.resting_poses) == len(model.resting_probabilities)
        assert np.all(np.diff(model.resting_probabilities) <= 0) and 0 < model.resting_probabilities.sum() <= 1
        for T in model.resting_poses:
            m = model.mesh.copy().apply_transform(T)
            assert abs(m.bounds[0, 2]) < 1e-9  # touches the floor z = 0
            com = m.center_mass
            contact = m.vertices[m.vertices[:, 2] < 1e-6, :2]
            # centre of mass above the convex hull of the contact points -> stable
            assert Delaunay(contact).find_simplex(com[:2]) >= 0


def test_load_object_from_stl_in_mm(tmp_path, objects):
    path = tmp_path / "elbow_mm.stl"
    objects["elbow"].mesh.copy().apply_scale(1000.0).apply_translation([5.0, 6.0, 7.0]).export(path)
    model = load_object(path, "my_elbow", Symmetry("none"), scale=0.001)
    assert model.label == "my_elbow"
    np.testing.assert_allclose(model.size_xyz_m, objects["elbow"].size_xyz_m, atol=1e-6)
    np.testing.assert_allclose(model.mesh.bounds.mean(axis=0), 0.0, atol=1e-9)


def test_load_object_errors(tmp_path):
    with pytest.raises(SimulationError, match="path"):
        load_object(tmp_path / "missing.stl", "x")
    bad = tmp_path / "bad.stl"
    bad.write_text("solid nothing\nendsolid nothing\n")
    with pytest.raises(SimulationError):
        load_object(bad, "x")
    with pytest.raises(SimulationError, match="label"):
        make_object("", trimesh.creation.box())
    with pytest.raises(SimulationError, match="label"):
        make_object("clutter", trimesh.creation.box())


def test_kinect_view_points_lie_on_the_visible_surface(objects):
    model = objects["ball_valve"]
    cloud = kinect_view(model, 0.3, seed=1)
    assert cloud.frame_id == "object" and cloud.n_points > 1000
    surface = model.mesh.sample(200_000, seed=0)
    d, _ = cKDTree(surface).query(cloud.points_xyz_m)
    assert np.percentile(d, 95) < 0.004 and d.max() < 0.01
    # every point is seen from the viewpoint: the first hit along the ray is at the point's range
    dirs = cloud.points_xyz_m - cloud.viewpoint_xyz_m
    rng_m = np.linalg.norm(dirs, axis=1)
    hit, _ = RayCaster(model.mesh).first_hit(np.broadcast_to(cloud.viewpoint_xyz_m, dirs.shape), dirs / rng_m[:, None])
    assert np.percentile(np.abs(hit - rng_m), 95) < 0.004
    # the viewpoint is at the configured distance and elevation from the object
    assert 0.6 < np.linalg.norm(cloud.viewpoint_xyz_m) < 0.8


def test_kinect_depth_noise_grows_with_square_of_depth():
    """A large flat plate seen with quantisation off: residuals along the ray have sigma k z^2."""
    plate = make_object("plate", trimesh.creation.box(extents=(0.6, 0.6, 0.02)))
    cfg = KinectConfig(disparity_step_px=0.0, depth_noise_per_m=0.004, distance_m=0.9, elevation_rad=np.radians(60))
    cloud = kinect_view(plate, 0.0, config=cfg, seed=3)
    p = cloud.points_xyz_m
    top = p[(np.abs(p[:, 2] - 0.01) < 0.015) & (np.abs(p[:, :2]).max(axis=1) < 0.29)]  # top face, no sides
    assert len(top) > 5000
    rays = top - cloud.viewpoint_xyz_m
    r = np.linalg.norm(rays, axis=1)
    cos_n = np.abs(rays[:, 2]) / r  # plate normal is z in the object frame (resting pose flat)
    T0 = plate.resting_poses[0]
    assert abs(abs(T0[2, 2]) - 1) < 1e-9
    # depth z along the optical axis: optical axis points from the eye to the plate's centre of mass
    axis = -cloud.viewpoint_xyz_m / np.linalg.norm(cloud.viewpoint_xyz_m)
    z = rays @ axis
    sigma_along_ray = cfg.depth_noise_per_m * z**2 * (r / z)
    standardized = (top[:, 2] - 0.01) / (sigma_along_ray * cos_n)
    assert abs(np.mean(standardized)) < 0.05
    assert 0.93 < np.std(standardized) < 1.07


def test_builtin_view_clouds_contract_and_reproducibility():
    views, classes = builtin_view_clouds(seed=5, n_views=2)
    assert len(views) == 8 and set(classes) == {"reducing_tee", "reducing_socket", "elbow", "ball_valve"}
    assert len({v[1] for v in views}) == 8
    for label, view_id, cloud in views:
        assert view_id.startswith(label) and cloud.frame_id == "object" and cloud.n_points > 500
    for c in classes.values():
        assert isinstance(c["symmetry"], Symmetry) and c["size_xyz_m"].shape == (3,)
    again, _ = builtin_view_clouds(seed=5, n_views=2)
    assert all(np.array_equal(a[2].points_xyz_m, b[2].points_xyz_m) for a, b in zip(views, again))
    other, _ = builtin_view_clouds(seed=6, n_views=2)
    assert not np.array_equal(views[0][2].points_xyz_m, other[0][2].points_xyz_m)


def test_a_models_views_share_one_prepared_scene(objects, monkeypatch):
    """The views of one model are rendered from one posed mesh and one ray caster (built once: ~2.5 s on a mesh of a
    million faces), and are the very clouds that one ``kinect_view`` per azimuth gives with the same generator."""
    import semslam.simulation.kinect as kinect

    built = []
    monkeypatch.setattr(kinect, "RayCaster", lambda mesh: built.append(mesh) or RayCaster(mesh))
    model = objects["ball_valve"]
    views = acquire_views(model, n_views=4, seed=np.random.default_rng(9))
    assert len(built) == 1
    rng = np.random.default_rng(9)
    for k, (_, cloud) in enumerate(views):
        one = kinect_view(model, 2 * np.pi * k / 4, seed=rng)
        assert np.array_equal(one.points_xyz_m, cloud.points_xyz_m)
        assert np.array_equal(one.viewpoint_xyz_m, cloud.viewpoint_xyz_m)
    assert len(built) == 5


def test_acquire_views_checks_arguments(objects):
    with pytest.raises(InputError, match="n_views"):
        acquire_views(objects["elbow"], n_views=0)
    with pytest.raises(SimulationError, match="elevation_rad"):
        KinectConfig(elevation_rad=2.0)
