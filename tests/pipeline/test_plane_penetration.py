"""Verification against the removed planes (``verify_max_plane_penetration_m``): a class posed on a cluster must not
reach behind the floor the cluster lies on. Constructed scenes with a known answer: the scanner at the origin
looking down +z at a floor 1 m away, a 12 mm plate on it; a 22 mm disc fitted top face on the plate's top face
sinks 10 mm into the floor (the shared valve-panel base taken for the blind flange, benchmarks/real_models.py)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.cloud import PointCloud
from semslam.detection import Detection
from semslam.errors import InputError
from semslam.pipeline import PipelineConfig
from semslam.pipeline.hypothesis import plane_penetration_m, verification_failure
from semslam.segmentation.scene import SegmentationConfig, segment_scene

FLOOR_Z = 1.0


def _grid(x0, x1, y0, y1, z, step=0.004):
    x, y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step), indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


def _slab(half_m: float, thickness_m: float, step=0.004) -> np.ndarray:
    """Surface samples of a square slab in its object frame: bottom face at z = 0, top face at z = -thickness
    (z down, as the scanner looks), so resting on a floor its origin is on the floor."""
    top = _grid(-half_m, half_m, -half_m, half_m, -thickness_m, step)
    bottom = _grid(-half_m, half_m, -half_m, half_m, 0.0, step)
    return np.vstack([top, bottom])


def _pose(z: float) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = z
    return T


@pytest.fixture(scope="module")
def scene():
    """The floor (1.2 m square) with a 12 mm plate on it, segmented: the floor removed, the plate's top a cluster."""
    rng = np.random.default_rng(0)
    floor = _grid(-0.6, 0.6, -0.6, 0.6, FLOOR_Z)
    floor = floor[~((np.abs(floor[:, 0]) < 0.12) & (np.abs(floor[:, 1]) < 0.12))]
    plate_top = _grid(-0.12, 0.12, -0.12, 0.12, FLOOR_Z - 0.012, step=0.003)
    pts = np.vstack([floor, plate_top]) + rng.normal(0.0, 3e-4, (len(floor) + len(plate_top), 3))
    seg = segment_scene(PointCloud(pts), SegmentationConfig(max_planes=1), seed=0)
    assert len(seg.planes) == 1 and seg.cluster_indices
    return seg, seg.clusters[0].points_xyz_m


def test_the_right_class_on_the_floor_does_not_reach_behind_it(scene):
    seg, cluster = scene
    depth = plane_penetration_m(seg, cluster, _slab(0.12, 0.012), _pose(FLOOR_Z))
    assert depth == pytest.approx(0.0, abs=1.5e-3)


def test_a_thicker_class_fitted_top_on_top_sinks_by_the_difference(scene):
    """Catches a flange fitted on a plate accepted: its top face on the plate's top, its bottom 10 mm in the floor."""
    seg, cluster = scene
    depth = plane_penetration_m(seg, cluster, _slab(0.11, 0.022), _pose(FLOOR_Z - 0.012 + 0.022))
    assert depth == pytest.approx(0.010, abs=1.5e-3)


def test_a_cluster_far_from_every_removed_plane_is_not_judged(scene):
    """Catches the test applied to an object hanging 20 cm above the floor (on a structure): NaN, never rejected."""
    seg, cluster = scene
    lifted = cluster - [0.0, 0.0, 0.2]
    assert np.isnan(plane_penetration_m(seg, lifted, _slab(0.12, 0.012), _pose(FLOOR_Z + 0.2)))
    assert np.isnan(plane_penetration_m(None, cluster, _slab(0.12, 0.012), _pose(FLOOR_Z)))


def _detection(depth_m: float) -> Detection:
    return Detection("blind_flange", 0.1, np.eye(4), np.eye(6) * 1e-4, fitness=1.0,
                     extras={"plane_penetration_m": depth_m})


def test_verification_rejects_beyond_the_limit_and_names_the_depth():
    assert verification_failure(_detection(0.0106), 0.95, None, 0.005).startswith(
        "pose verification: the posed object reaches 10.6 mm behind a removed plane (> 5 mm")
    assert verification_failure(_detection(0.004), 0.95, None, 0.005) == ""
    assert verification_failure(_detection(float("nan")), 0.95, None, 0.005) == ""  # no plane under it
    assert verification_failure(_detection(0.0106), 0.95, None, None) == ""  # off


def test_the_setting_is_checked_and_the_seabed_preset_uses_it():
    from semslam.run.config import load_run_config

    assert PipelineConfig(verify_max_plane_penetration_m=0.005).verify_max_plane_penetration_m == 0.005
    with pytest.raises(InputError, match="verify_max_plane_penetration_m"):
        PipelineConfig(verify_max_plane_penetration_m=-0.001)
    with pytest.raises(InputError, match="verify_max_plane_penetration_m"):
        PipelineConfig(verify_max_plane_penetration_m=0.005, estimate_pose=False)
    assert PipelineConfig().verify_max_plane_penetration_m is None
    assert load_run_config(preset="seabed").pipeline_config().verify_max_plane_penetration_m == 0.01


def test_the_recogniser_measures_it_on_real_scans_of_objects_on_the_tank_floor(builtin_db_fresh):
    """Simulated laser scans of the four fittings on the tank floor (a dive of seed 4, one scan every 5 s): with the
    setting on, every detection carries the depth its pose reaches behind the floor the segmentation removed, a
    few millimetres at most for these right poses; with it off (the default) it is not measured."""
    from semslam.pipeline import ScanRecognizer
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset

    mission = simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed=4,
                               scan_interval_s=5.0)
    on = ScanRecognizer(builtin_db_fresh, PipelineConfig(verify_max_plane_penetration_m=0.01))
    off = ScanRecognizer(builtin_db_fresh)
    depths = []
    for r in mission.scans:
        cloud = mission.load_scan(r.scan_id)
        depths += [d.extras["plane_penetration_m"] for d in on.recognize(cloud, seed=r.scan_id).detections]
        assert all("plane_penetration_m" not in d.extras for d in off.recognize(cloud, seed=r.scan_id).detections)
    assert len(depths) >= 3
    assert all(0.0 <= v < 0.005 for v in depths), depths


def test_warm_up_builds_the_floor_checks_hull_when_the_check_is_on(builtin_db_fresh):
    """Catches the live node's first scan of each class paying for the convex hull the floor check bounds depths with
    (0.1-0.3 s on a large model): ``warm_up`` builds it with the check on, and not without."""
    from semslam.pipeline import ScanRecognizer

    on = ScanRecognizer(builtin_db_fresh, PipelineConfig(verify_max_plane_penetration_m=0.01))
    off = ScanRecognizer(builtin_db_fresh)
    on.warm_up()
    off.warm_up()
    for label in builtin_db_fresh.classes:
        first = int(builtin_db_fresh.views_of(label)[0])
        assert "hull_points" in vars(on.pose_model(label, first))
        assert "hull_points" not in vars(off.pose_model(label, first))


def _disc(radius_m: float, thickness_m: float, step=0.004) -> np.ndarray:
    """Surface samples of a disc in its object frame, as ``_slab``: bottom face at z = 0, top at z = -thickness."""
    faces = _grid(-radius_m, radius_m, -radius_m, radius_m, 0.0, step)
    faces = faces[np.linalg.norm(faces[:, :2], axis=1) <= radius_m]
    a = np.linspace(0.0, 2 * np.pi, int(2 * np.pi * radius_m / step), endpoint=False)
    z = np.arange(-thickness_m, 0.0, step)
    rim = np.column_stack([np.repeat(radius_m * np.cos(a), len(z)), np.repeat(radius_m * np.sin(a), len(z)),
                           np.tile(z, len(a))])
    return np.vstack([faces, faces - [0.0, 0.0, thickness_m], rim])


def test_a_corner_clipping_a_second_removed_plane_beside_the_object_is_not_a_sinking():
    """Catches the right pose rejected because a removed wall or slope's infinite plane clips its edge (the blind
    flange at the foot of the tank's slope, benchmarks/real_models.py seed 3: 10.6-13.4 mm at its deepest point,
    0.5 % of its points more than 5 mm deep), while a class sunk into the floor is still measured whole."""
    from types import SimpleNamespace

    from semslam.pipeline.hypothesis import PENETRATION_SHARE

    disc = _disc(0.25, 0.022)
    floor = SimpleNamespace(coefficients=np.array([0.0, 0.0, -1.0, FLOOR_Z]))
    # a wall (normal along -x, towards the scanner's side of it) standing 11 mm inside the disc's edge at x = 0.25
    wall = SimpleNamespace(coefficients=np.array([-1.0, 0.0, 0.0, 0.239]))
    seg = SimpleNamespace(planes=[floor, wall])
    top = _grid(-0.1, 0.1, -0.1, 0.1, FLOOR_Z - 0.022)  # the cluster: the disc's top face, within 5 cm of both
    top[:, 0] += 0.135
    pose = _pose(FLOOR_Z)
    model = disc + pose[:3, 3]
    deepest = -np.min(model @ wall.coefficients[:3] + wall.coefficients[3])
    share = np.mean(model @ wall.coefficients[:3] + wall.coefficients[3] < 0.0)
    assert deepest == pytest.approx(0.011, abs=5e-4) and 0.0 < share < PENETRATION_SHARE  # a corner, that deep
    assert plane_penetration_m(seg, top, disc, pose) == pytest.approx(0.0, abs=1e-3)
    # the first removed plane is the one the objects rest on: there the deepest point counts
    first = SimpleNamespace(planes=[wall, floor])
    assert plane_penetration_m(first, top, disc, pose) == pytest.approx(0.011, abs=5e-4)
    sunk = _pose(FLOOR_Z + 0.010)  # the same disc 10 mm into the floor: its whole underside
    assert plane_penetration_m(seg, top, disc, sunk) == pytest.approx(0.010, abs=1e-3)


def test_the_pose_search_is_told_that_a_pose_inside_the_floor_is_inadmissible(scene):
    """Catches the floor check applied only after the pose is chosen (a border-cut cluster posed sunk into the floor
    rejected while its depth twin lay on it, benchmarks/catalogue.py): the admissibility test handed to
    ``estimate_object_pose`` fails the sunk pose and passes the right one; no test without the check or a plane."""
    from types import SimpleNamespace

    from semslam.pipeline.hypothesis import _above_floor

    seg, cluster = scene
    from semslam.pose.model import PoseModel

    model = SimpleNamespace(points_object=_slab(0.12, 0.012))
    model.hull_points = PoseModel.hull_points.func(model)
    admissible = _above_floor(PipelineConfig(verify_max_plane_penetration_m=0.01), seg, cluster, model)
    assert admissible(_pose(FLOOR_Z)) and admissible(_pose(FLOOR_Z + 0.008))
    assert not admissible(_pose(FLOOR_Z + 0.012))
    assert not admissible(_pose(FLOOR_Z + 0.05))
    assert _above_floor(PipelineConfig(), seg, cluster, model) is None
    assert _above_floor(PipelineConfig(verify_max_plane_penetration_m=0.01), None, cluster, model) is None


def test_the_fast_verdict_equals_the_exact_depth_against_the_limit(monkeypatch):
    """Catches the bound of ``within_planes`` (the deepest point) passing a pose the exact depth fails, or failing one
    it passes: 400 random poses about the floor and a wall beside the disc, limits around their depths; and the exact
    depth is computed only for a pose at the limit."""
    from types import SimpleNamespace

    from scipy.spatial.transform import Rotation

    import semslam.pipeline.hypothesis as H

    disc = _disc(0.25, 0.022)
    floor = SimpleNamespace(coefficients=np.array([0.0, 0.0, -1.0, FLOOR_Z]))
    wall = SimpleNamespace(coefficients=np.array([-1.0, 0.0, 0.0, 0.239]))
    top = _grid(-0.1, 0.1, -0.1, 0.1, FLOOR_Z - 0.022)
    top[:, 0] += 0.135
    rng = np.random.default_rng(7)
    verdicts = []
    for planes in ([floor, wall], [wall, floor], [floor]):
        seg = SimpleNamespace(planes=planes)
        for _ in range(400 // 3):
            T = _pose(FLOOR_Z + rng.uniform(-0.01, 0.03))
            T[:3, :3] = Rotation.from_rotvec(rng.normal(0.0, 0.05, 3)).as_matrix()
            T[:2, 3] = rng.normal(0.0, 0.01, 2)
            limit = rng.uniform(0.0, 0.03)
            exact = not plane_penetration_m(seg, top, disc, T) > limit
            assert H.within_planes(seg, top, disc, T, limit) == exact
            verdicts.append(exact)
    assert 0.2 < np.mean(verdicts) < 0.8  # both verdicts well represented
    calls = []
    monkeypatch.setattr(H, "plane_penetration_m", lambda *a: calls.append(a) or 0.0)
    on_floor = SimpleNamespace(planes=[floor])
    assert H.within_planes(on_floor, top, disc, _pose(FLOOR_Z - 0.005), 0.01)  # 5 mm above
    assert not H.within_planes(on_floor, top, disc, _pose(FLOOR_Z + 0.02), 0.01)  # 20 mm in
    # the wall clips a corner 11 mm deep, its deepest 2 % stay in front: passes by counting
    assert H.within_planes(SimpleNamespace(planes=[floor, wall]), top, disc, _pose(FLOOR_Z - 0.005), 0.01)
    assert not calls
    H.within_planes(on_floor, top, disc, _pose(FLOOR_Z + 0.01), 0.01)  # exactly at the limit: the exact depth
    assert len(calls) == 1
    assert H.within_planes(None, top, disc, _pose(FLOOR_Z + 0.05), 0.01)  # no segmentation: not judged


def test_the_floor_verdict_from_the_hull_is_the_measured_depths_verdict():
    """Catches the convex-hull shortcut of the floor check deciding otherwise than the depth it stands for: over
    random poses of a flange-like model about the floor and a wall (deep, shallow, at the limit to a micron), the
    verdict with the hull, without it, and ``not plane_penetration_m > limit`` agree."""
    from types import SimpleNamespace

    from scipy.spatial.transform import Rotation

    from semslam.pipeline.hypothesis import within_planes
    from semslam.pose.model import PoseModel

    disc = _disc(0.15, 0.03)
    hull = PoseModel.hull_points.func(SimpleNamespace(points_object=disc))
    assert 10 < len(hull) < len(disc) // 4
    floor = SimpleNamespace(coefficients=np.array([0.0, 0.0, -1.0, FLOOR_Z]))
    wall = SimpleNamespace(coefficients=np.array([-1.0, 0.0, 0.0, 0.16]))
    top = _grid(-0.1, 0.1, -0.1, 0.1, FLOOR_Z - 0.03)
    rng = np.random.default_rng(3)
    limit = 0.01
    for planes in ([floor], [floor, wall], [wall, floor]):
        seg = SimpleNamespace(planes=planes)
        verdicts = []
        for k in range(150):
            T = np.eye(4)
            T[:3, :3] = Rotation.from_rotvec(rng.normal(scale=0.05, size=3)).as_matrix()
            T[:3, 3] = [rng.normal(scale=0.01), 0.0, FLOOR_Z + rng.uniform(-0.01, 0.03)]
            if k % 10 == 0:  # the deepest point at the limit to a micron
                T[2, 3] += limit - (np.max(disc @ T[2, :3] + T[2, 3]) - FLOOR_Z) + 1e-6 * (k % 3 - 1)
            want = not plane_penetration_m(seg, top, disc, T) > limit
            assert within_planes(seg, top, disc, T, limit, hull_points=hull) == want
            assert within_planes(seg, top, disc, T, limit) == want
            verdicts.append(want)
        assert 0 < sum(verdicts) < len(verdicts)
    flat = _grid(-0.1, 0.1, -0.1, 0.1, 0.0)  # a degenerate hull: every point
    assert len(PoseModel.hull_points.func(SimpleNamespace(points_object=flat))) == len(flat)
