"""Where a run starts: from the dive's own data (depth sensor, position fixes, DVL), never from its ground truth.

Replaces the former ``test_mutants_runner_start.py`` (the launch point drawn around the truth is gone)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from semslam.dataset import PositionFixLog
from semslam.detection import Detection
from semslam.errors import SimulationError
from semslam.simulation.synthetic import square_dataset
from semslam.geometry import RigidTransform
from semslam.slam import SlamConfig, initial_state
from semslam.run import run_slam
from semslam.run.dataset_loop import merged_messages


@pytest.fixture(scope="module")
def mission():
    return square_dataset(seed=3, loops=1)


def test_same_dive_with_and_without_truth_gives_identical_estimates(mission):
    """The estimate never reads the truth: the trajectory, covariances and map are bit-identical without it."""
    a = run_slam(mission, {}, mode="dr")
    b = run_slam(replace(mission, truth=None, objects=[]), {}, mode="dr")
    np.testing.assert_array_equal(a.position_ned_m, b.position_ned_m)
    np.testing.assert_array_equal(a.position_cov_m2, b.position_cov_m2)
    assert "ate_rmse_m" in a.metrics and "ate_rmse_m" not in b.metrics
    assert a.metrics["start"] == b.metrics["start"]


def test_start_depth_comes_from_the_pressure_sensor_not_zero(mission):
    """A dive that starts at depth starts the filter at the first depth sample (a dive starting at 3.5 m used to
    start at z = 0 and reject half its depth updates)."""
    r = run_slam(replace(mission, truth=None), {}, mode="dr")
    assert r.position_ned_m[0, 2] == pytest.approx(float(mission.depth.depth_m[0]))
    assert r.metrics["start"]["frame"] == "local"
    assert np.sqrt(r.position_cov_m2[0, 2, 2]) == pytest.approx(mission.vehicle.depth.noise_m)
    assert r.metrics["depth_rejected"] == 0


def test_without_fixes_the_local_frame_starts_at_north_east_zero_and_evaluation_aligns_it(mission):
    r = run_slam(mission, {}, mode="dr")
    np.testing.assert_array_equal(r.position_ned_m[0, :2], np.zeros(2))
    ev = r.metrics["evaluation_frame"]
    assert ev["frame"] == "local"
    np.testing.assert_allclose(ev["offset_ned_m"][:2], mission.truth.interpolate_position(r.stamps_s[0])[0, :2])
    # the truth stored with the result is expressed in the local frame: the start errors only by the depth noise
    assert np.linalg.norm(r.position_ned_m[0] - r.truth_position_ned_m[0]) < 0.1
    assert r.metrics["ate_4dof_rmse_m"] <= r.metrics["ate_rmse_m"] + 1e-12


def _with_fix(mission, offset_ne, sigma=2.0, stamp=-5.0):
    p0 = mission.truth.interpolate_position(mission.attitude.stamp_s[0])[0, :2] + np.asarray(offset_ne)
    return replace(mission, fixes=PositionFixLog([stamp], [p0], [np.eye(2) * sigma ** 2], ("gps",)))


def test_a_surface_fix_before_the_dive_places_the_start_in_the_world_frame(mission):
    m = _with_fix(mission, (1.5, -0.5))
    r = run_slam(m, {}, mode="dr")
    assert r.metrics["start"]["frame"] == "world"
    np.testing.assert_allclose(r.position_ned_m[0, :2], m.fixes.position_ne_m[0])
    np.testing.assert_allclose(r.position_cov_m2[0, :2, :2], np.eye(2) * 4.0, rtol=0.05)
    assert r.metrics["evaluation_frame"]["frame"] == "world"
    assert r.metrics["launch_error_m"] == pytest.approx(np.hypot(1.5, 0.5), abs=0.05)
    # the fix error is an offset common to the whole run: the 4-DoF aligned ATE removes it
    assert r.metrics["ate_4dof_rmse_m"] < 0.2 < r.metrics["ate_rmse_m"]


def test_a_fix_older_than_the_limit_is_not_the_start(mission):
    cfg = SlamConfig().updated(max_fix_age_s=10.0)
    m = _with_fix(mission, (0.0, 0.0), stamp=-60.0)
    r = run_slam(m, {}, mode="dr", config=cfg)
    assert r.metrics["start"]["frame"] == "world"
    assert np.sqrt(r.position_cov_m2[0, 0, 0]) == pytest.approx(cfg.initialisation.unknown_position_sigma_m)


def test_fixes_during_the_dive_are_gated_and_a_1km_jump_is_rejected_and_counted(mission):
    t = mission.dvl.stamp_s[10:60:10]
    p = mission.truth.interpolate_position(t)[:, :2]
    p[2] += 1000.0
    cov = np.broadcast_to(np.eye(2) * 0.3 ** 2, (len(t), 2, 2))
    nan = np.array([[np.nan, np.nan]])
    fixes = PositionFixLog(np.r_[-5.0, t, t[-1] + 0.05], np.r_[mission.truth.position_ned_m[:1, :2], p, nan],
                           np.r_[np.eye(2)[None] * 0.25, cov, np.eye(2)[None]], ("gps",) + ("usbl",) * (len(t) + 1))
    r = run_slam(replace(mission, fixes=fixes), {}, mode="dr")
    assert r.metrics["fix_updates"] == len(t)
    assert r.metrics["fix_rejected"] == 1
    assert r.metrics["fix_unusable"] == 1
    assert np.all(np.abs(r.position_ned_m[:, :2]) < 100)


def test_initial_state_prefers_the_last_fix_before_the_start_and_uses_the_first_valid_dvl():
    s = initial_state(10.0, depth_stamps_s=[9.0, 10.5, 30.0], depth_m=[1.0, 4.0, 5.0], depth_noise_m=0.02,
                      fix_stamps_s=[2.0, 8.0, 11.0], fix_positions_ne_m=[[1, 1], [2, 2], [3, 3]],
                      fix_covariances_ne_m2=[np.eye(2)] * 3, dvl_stamps_s=[10.2, 10.4],
                      dvl_velocities_mps=[[np.nan] * 3, [0.3, 0.0, 0.0]], dvl_valid=[False, True])
    np.testing.assert_array_equal(s.position_ned_m, [2.0, 2.0, 4.0])   # depth nearest the start: 10.5 s
    np.testing.assert_array_equal(s.velocity_body_mps, [0.3, 0.0, 0.0])
    late = initial_state(10.0, depth_stamps_s=[], depth_m=[], depth_noise_m=0.02, dvl_stamps_s=[20.0],
                         dvl_velocities_mps=[[0.3, 0, 0]], dvl_valid=[True])
    assert late.velocity_body_mps is None and late.frame == "local"
    assert np.sqrt(late.position_cov_m2[2, 2]) == SlamConfig().initialisation.unknown_depth_sigma_m


def test_messages_at_one_stamp_come_in_the_documented_order(mission):
    """attitude, DVL, depth, fix, detections at a shared stamp, whatever their indices."""
    t = float(mission.dvl.stamp_s[2])
    assert t == mission.attitude.stamp_s[8] == mission.depth.stamp_s[4]
    m = replace(mission, fixes=PositionFixLog([t], [[0.0, 0.0]], [np.eye(2)], ("usbl",)))
    det = Detection("valve", 0.9, RigidTransform.identity(), np.eye(6) * 1e-4, stamp_s=t)
    kinds = [k for s, k, _ in merged_messages(m, {0: [det]}) if s == t]
    assert kinds == ["attitude", "dvl", "depth", "fix", "detections"]


def test_simulated_survey_errors_are_zero_mean_at_the_survey_sigma(mission):
    from semslam.simulation.truth_slam import simulated_survey

    names = [o.name for o in mission.objects]
    cfg = SlamConfig()
    survey = simulated_survey(mission, names, config=cfg, seed=0)
    sr, sp = cfg.initialisation.survey_rotation_sigma_rad, cfg.initialisation.survey_position_sigma_m
    # no fixes: the run's local frame starts at the start point, and the survey is given from that launch mark
    start = np.r_[mission.truth.interpolate_position(mission.attitude.stamp_s[0])[0, :2], 0.0]
    for o, T in zip(mission.objects, survey.poses):
        dR = T.rotation @ o.T_world_object.rotation.T
        assert np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)) < 5 * sr * np.sqrt(3)
        assert np.linalg.norm(T.translation_m - (o.T_world_object.translation_m - start)) < 5 * sp * np.sqrt(3)
    fixed = simulated_survey(_with_fix(mission, (0.0, 0.0)), names, config=cfg, seed=0)   # world frame: no shift
    for o, T in zip(mission.objects, fixed.poses):
        assert np.linalg.norm(T.translation_m - o.T_world_object.translation_m) < 5 * sp * np.sqrt(3)
    assert list(survey.labels) == [o.label for o in mission.objects]
    with pytest.raises(SimulationError, match="no_such_object"):
        simulated_survey(mission, ["no_such_object"])
