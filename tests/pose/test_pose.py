"""Object pose estimation on simulated scans of the built-in fittings: the issue-4 goals on the simulator's
own laser scans (grid search, fused database views), refinement from a prior pose, symmetry handling,
reliability, the RANSAC path."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.detection import Detection
from semslam.errors import InputError, RegistrationError
from semslam.geometry import rpy_from_rotation, wrap_angle
from semslam.pose import estimate_object_pose, prepare_pose_model
from semslam.simulation.scan_sim import mesh_model_cloud, resting_scene_pose, scan_mesh


@pytest.fixture(scope="module")
def objects():
    from semslam.simulation import builtin_objects

    return builtin_objects()


@pytest.fixture(scope="module")
def models(objects):
    return {label: prepare_pose_model(mesh_model_cloud(o.mesh, seed=1)) for label, o in objects.items()}


def _scan(obj, rng, n_points=None):
    T = resting_scene_pose(obj.resting_poses[0], rng.uniform(0.5, 2.0), seed=rng)
    n = int(rng.uniform(1000, 5000)) if n_points is None else n_points
    return T, scan_mesh(obj.mesh, T, n_target_points=n, range_noise_m=0.001, seed=rng)


def _errors(obj, est, T):
    Te = est.T_scanner_object.matrix
    e = np.concatenate([Te[:3, 3] - T[:3, 3],
                        wrap_angle(rpy_from_rotation(Te[:3, :3]) - rpy_from_rotation(obj.symmetry.canonicalize(T[:3, :3])))])
    return obj.symmetry.rotation_error_rad(Te[:3, :3], T[:3, :3]), float(np.linalg.norm(e[:3])), \
        float(e @ np.linalg.solve(est.covariance_6x6, e))


def test_prior_pose_refinement_is_accurate_and_consistent(objects, models):
    obj, model = objects["ball_valve"], models["ball_valve"]
    rng = np.random.default_rng(0)
    rot, tr, nees = [], [], []
    for _ in range(12):
        T, pts = _scan(obj, rng)
        P = np.eye(4)
        P[:3, :3] = Rotation.from_rotvec(rng.normal(0, np.radians(2), 3)).as_matrix()
        P[:3, 3] = rng.normal(0, 0.003, 3)
        est = estimate_object_pose(pts, model, symmetry=obj.symmetry, init_T_scanner_object=T @ P)
        r, t, n = _errors(obj, est, T)
        rot.append(r), tr.append(t), nees.append(n)
        assert est.reliable and est.fitness > 0.9
    assert np.degrees(np.median(rot)) <= 1.0
    assert np.median(tr) <= 0.001
    # the covariance is calibrated on the mission scans (motion-distorted, database-view models: rotation
    # floor 0.04 rad), so it is conservative on these idealised scans with an exact mesh model
    assert np.median(nees) <= 9.0, nees


def test_full_pipeline_on_socket_continuous_symmetry(objects, models):
    obj, model = objects["reducing_socket"], models["reducing_socket"]
    rng = np.random.default_rng(1)
    for i in range(4):
        T, pts = _scan(obj, rng, n_points=2000)
        est = estimate_object_pose(pts, model, symmetry=obj.symmetry, seed=i)
        r, t, _ = _errors(obj, est, T)
        assert np.degrees(r) < 10 and t < 0.01, (np.degrees(r), t)
        # the rotation about the axis is unobservable: one huge eigenvalue, the others small
        w = np.linalg.eigvalsh(est.covariance_6x6)
        assert w[-1] >= 1e3 and w[-2] < 1.0
        Detection("reducing_socket", 0.0, est.T_scanner_object, est.covariance_6x6)  # valid for the filter
        # canonical: the object's x axis as close as possible to the scanner's +z
        R = est.T_scanner_object.rotation
        np.testing.assert_allclose(obj.symmetry.canonicalize(R), R, atol=1e-9)


def test_reproducible_with_seed(objects, models):
    obj, model = objects["elbow"], models["elbow"]
    _, pts = _scan(obj, np.random.default_rng(2), n_points=1500)
    a = estimate_object_pose(pts, model, symmetry=obj.symmetry, seed=3)
    b = estimate_object_pose(pts, model, symmetry=obj.symmetry, seed=3)
    np.testing.assert_array_equal(a.T_scanner_object.matrix, b.T_scanner_object.matrix)
    np.testing.assert_array_equal(a.covariance_6x6, b.covariance_6x6)


def test_unrelated_cluster_is_unreliable(models):
    rng = np.random.default_rng(4)
    blob = rng.normal(0, 0.03, (800, 3)) + [1.0, 0.0, 0.0]
    est = estimate_object_pose(blob, models["ball_valve"], seed=0)
    assert not est.reliable


def test_too_small_cluster_raises(models):
    with pytest.raises(RegistrationError, match="min_points"):
        estimate_object_pose(np.zeros((5, 3)), models["elbow"])


@pytest.fixture(scope="module")
def mission_eval():
    """One-loop missions at 1 m altitude (seeds 0, 1): ground-truth clusters, aligned to the models the
    pipeline uses (ScanRecognizer on the built-in database: its pose-model views, fused)."""
    from semslam.pipeline import ScanRecognizer
    from semslam.simulation.builtin_db import builtin_database
    from semslam.experiments.pose_eval import evaluate, simulated_clusters

    clusters = simulated_clusters((0, 1), altitudes_m=(1.0,))
    recognizer = ScanRecognizer(builtin_database(seed=0, cache=False))
    models = {lab: recognizer.pose_model(lab, int(recognizer.db.views_of(lab)[0])) for lab in recognizer.db.classes}
    return clusters, evaluate(clusters, models)


def test_goals_on_simulated_mission_scans(mission_eval):
    clusters, rows = mission_eval
    assert len(rows) >= 20 and {r.label for r in rows} == {"ball_valve", "elbow", "reducing_socket", "reducing_tee"}
    ok = [r for r in rows if r.success]
    # issue-4 goals: median rotation <= 3 deg, translation <= 5 mm, success >= 95 %, mean NEES in [4.5, 7.5].
    # The goals are checked on the benchmark's 140 clusters (benchmarks/pose_accuracy.py: 2.39 deg, 1.85 mm,
    # 95.7 %, mean NEES 6.24 with the teleoperated flight). On this ~30-cluster subset a mean NEES is ruled by
    # its largest term (here 29 / 30 right; one correct pose at NEES 53 moves the mean from 8.0 to 9.5), so the
    # test checks the median (6.7; chi-square(6): 5.35) and bounds the mean below the 10.4 that the survey
    # views the pipeline fused before gave (with 80.6 % success) on the former subset.
    assert np.degrees(np.median([r.rot_rad for r in rows])) <= 3.0
    assert np.median([r.trans_m for r in rows]) <= 0.005
    assert len(ok) / len(rows) >= 0.9  # goal 0.95: met on the benchmark's clusters, not on this subset
    nees = np.array([r.nees for r in ok])
    assert 3.0 <= np.median(nees) <= 7.5, nees
    assert nees.mean() <= 10.0, nees
    # few correct poses are flagged unreliable (6 / 29 here, 9 / 136 on the benchmark's clusters)
    assert sum(not r.reliable for r in ok) <= 0.25 * len(ok)


def test_wrong_poses_are_flagged(mission_eval):
    # one of the two elbow flips is flagged here; over seeds 0-5 at 1 and 1.5 m, 4 of the 13 wrong poses are
    # (a known gap, issue 4: the other flips' score margin and visibility pass the reliability thresholds)
    _, rows = mission_eval
    wrong = [r for r in rows if not r.success]
    assert wrong and sum(not r.reliable for r in wrong) >= len(wrong) / 2


@pytest.mark.parametrize("label", ["elbow", "reducing_tee"])
def test_numba_icp_backend_matches_small_gicp(objects, label):
    """The grid search's ICP in numba (default) gives the pose small_gicp gives, within the noise."""
    from semslam.pose import PoseConfig

    obj = objects[label]
    rng = np.random.default_rng(11)
    T, scan = _scan(obj, rng, n_points=3000)
    cloud = mesh_model_cloud(obj.mesh, seed=1)
    poses = []
    for backend in ("field", "small_gicp"):
        model = prepare_pose_model(cloud, PoseConfig(icp_backend=backend))
        est = estimate_object_pose(scan, model, symmetry=obj.symmetry)
        rot, trans, _ = _errors(obj, est, T)
        assert np.degrees(rot) < 5.0 and trans < 0.005, (backend, np.degrees(rot), trans)
        poses.append(est.T_scanner_object.matrix)
    np.testing.assert_allclose(poses[0][:3, 3], poses[1][:3, 3], atol=0.002)


def test_coarse_to_fine_grid_finds_the_exhaustive_grid_pose(objects, models):
    from semslam.pose import PoseConfig

    obj = objects["ball_valve"]
    rng = np.random.default_rng(12)
    T, scan = _scan(obj, rng, n_points=3000)
    exhaustive = prepare_pose_model(mesh_model_cloud(obj.mesh, seed=1), PoseConfig(n_coarse_rotations=0))
    assert exhaustive.rotation_hierarchy is None and models["ball_valve"].rotation_hierarchy is not None
    a = estimate_object_pose(scan, models["ball_valve"], symmetry=obj.symmetry)
    b = estimate_object_pose(scan, exhaustive, symmetry=obj.symmetry)
    assert obj.symmetry.rotation_error_rad(a.T_scanner_object.rotation, b.T_scanner_object.rotation) < np.radians(2.0)
    np.testing.assert_allclose(a.T_scanner_object.translation_m, b.T_scanner_object.translation_m, atol=0.002)


def test_a_part_lying_on_its_other_face_is_found_with_both_ups_and_not_with_one(objects, models):
    """The elbow rests on either face about equally often (two tied resting poses): the database records both ups
    (``tied_up_objects``) and the upright search scans the orientations keeping either of them up. Seen lying on
    its second face, it is found with both ups given; constrained to the first face's up alone, it cannot be."""
    from semslam.simulation.model_views import tied_up_objects

    obj, model = objects["elbow"], models["elbow"]
    ups = tied_up_objects({"elbow": obj})["elbow"]
    rng = np.random.default_rng(5)
    T = resting_scene_pose(obj.resting_poses[1], 1.0, seed=rng)
    pts = scan_mesh(obj.mesh, T, n_target_points=3000, range_noise_m=0.001, seed=rng)
    up_scanner = T[:3, :3] @ np.asarray(ups[1])  # the world's up seen from the scanner
    both = estimate_object_pose(pts, model, symmetry=obj.symmetry, up_scanner=up_scanner, up_object=ups)
    r_both, t_both, _ = _errors(obj, both, T)
    assert np.degrees(r_both) < 5.0 and t_both < 0.005 and both.extras["upright"]
    one = estimate_object_pose(pts, model, symmetry=obj.symmetry, up_scanner=up_scanner, up_object=ups[0])
    assert np.degrees(_errors(obj, one, T)[0]) > 30.0
    with pytest.raises(InputError, match="up_object"):
        estimate_object_pose(pts, model, up_scanner=up_scanner, up_object=[[0.0, 1.0]])
