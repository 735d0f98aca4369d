"""Whole-mission simulation: sensor statistics, reproducibility, the directory format and the CLI."""

from __future__ import annotations

import dataclasses
import filecmp
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from semslam._outdir import MARKER
from semslam.cli.main import main
from semslam.errors import DatasetError, SimulationError
from semslam.geometry import wrap_angle
from semslam.simulation import AhrsConfig, DepthConfig, DvlConfig, ScannerConfig, SimulatorConfig, TrajectoryConfig, WorldConfig, simulate_dataset
from semslam.dataset import read_dataset, write_dataset
from semslam.simulation.sensors import dvl_beams_over_slope


def _tiny() -> SimulatorConfig:
    """One loop, 40 x 40-ray scans: a few seconds end to end."""
    return SimulatorConfig(trajectory=TrajectoryConfig(loops=1), scanner=ScannerConfig(n_lines=40, points_per_line=40))


@pytest.fixture(scope="module")
def tiny_mission():
    return simulate_dataset(_tiny(), seed=7)


@pytest.fixture(scope="module")
def long_nav():
    cfg = SimulatorConfig(
        trajectory=TrajectoryConfig(loops=8),
        dvl=DvlConfig.white(rate_hz=10.0, outlier_prob=0.0, slope_outlier_prob=0.0, dropout_prob=0.05, slope_dropout_prob=0.2),
        ahrs=AhrsConfig(yaw_bias_rad=0.03),
        depth=DepthConfig(bias_m=0.05),
    )
    return cfg, simulate_dataset(cfg, seed=11, with_scans=False)


def _at_truth(mission, stamps):
    common, i_s, i_t = np.intersect1d(stamps, mission.truth.stamp_s, return_indices=True)
    assert len(common) > 0.3 * len(stamps)
    return i_s, i_t


def test_dvl_noise_and_dropouts_match_configuration(long_nav):
    cfg, m = long_nav
    i_s, i_t = _at_truth(m, m.dvl.stamp_s)
    truth_v = m.truth.velocity_body_mps[i_t]
    slope = dvl_beams_over_slope(cfg.world, m.truth.position_ned_m[i_t], m.truth.rpy_rad[i_t], cfg.dvl.beam_angle_rad)
    assert 0.05 < slope.mean() < 0.95  # the square goes near the sloped side: both regimes are exercised
    sigma = cfg.dvl.noise_rel * np.linalg.norm(truth_v, axis=1) + cfg.dvl.noise_abs_mps
    sigma = np.where(slope, sigma * cfg.dvl.slope_noise_factor, sigma)
    valid = m.dvl.valid[i_s]
    z = (m.dvl.velocity_body_mps[i_s] - truth_v)[valid] / sigma[valid, None]
    assert abs(z.mean()) < 0.1 and 0.93 < z.std() < 1.07
    assert np.isnan(m.dvl.velocity_body_mps[~m.dvl.valid]).all()
    p = np.where(slope, cfg.dvl.slope_dropout_prob, cfg.dvl.dropout_prob)
    n_drop = np.sum(~valid)
    assert abs(n_drop - p.sum()) < 4 * np.sqrt(np.sum(p * (1 - p)))


def test_ahrs_and_depth_noise_match_configuration(long_nav):
    cfg, m = long_nav
    i_s, i_t = _at_truth(m, m.attitude.stamp_s)
    err = wrap_angle(m.attitude.rpy_rad[i_s] - m.truth.rpy_rad[i_t])
    np.testing.assert_allclose(err.mean(axis=0), [0.0, 0.0, 0.03], atol=4 * np.max(cfg.ahrs.noise_rpy_rad) / np.sqrt(len(err)) + 1e-4)
    np.testing.assert_allclose(err.std(axis=0), cfg.ahrs.noise_rpy_rad, rtol=0.08)
    i_s, i_t = _at_truth(m, m.depth.stamp_s)
    e = m.depth.depth_m[i_s] - m.truth.position_ned_m[i_t, 2]
    assert abs(e.mean() - 0.05) < 4 * 0.02 / np.sqrt(len(e))
    assert abs(e.std() / 0.02 - 1) < 0.08


def test_sensor_rates_and_truth(long_nav):
    _, m = long_nav
    np.testing.assert_allclose(np.diff(m.dvl.stamp_s), 0.1)
    np.testing.assert_allclose(np.diff(m.attitude.stamp_s), 0.05)
    np.testing.assert_allclose(np.diff(m.depth.stamp_s), 0.1)
    np.testing.assert_allclose(np.diff(m.truth.stamp_s), 0.02)
    speed = np.linalg.norm(m.truth.velocity_body_mps, axis=1)
    assert 0.25 < np.median(speed) < 0.35
    # the body velocity integrates to the position (consistency of the truth)
    from semslam.geometry import rotations_from_rpy

    v_ned = np.einsum("nij,nj->ni", rotations_from_rpy(m.truth.rpy_rad), m.truth.velocity_body_mps)
    dp = np.cumsum(0.5 * (v_ned[1:] + v_ned[:-1]) * 0.02, axis=0)
    np.testing.assert_allclose(m.truth.position_ned_m[1:] - m.truth.position_ned_m[0], dp, atol=0.01)
    # altitude ~ 1.5 m over the 5 m floor; the objects lie on the floor
    assert np.all(np.abs(5.0 - m.truth.position_ned_m[:, 2] - 1.5) < 0.2)
    assert len(m.objects) == 4 and all(o.in_database for o in m.objects)


def test_no_scans_gives_the_same_navigation(tiny_mission):
    nav = simulate_dataset(_tiny(), seed=7, with_scans=False)
    assert nav.scans == [] and nav.scan_clouds is None
    for a, b in [(nav.dvl.velocity_body_mps, tiny_mission.dvl.velocity_body_mps), (nav.attitude.rpy_rad, tiny_mission.attitude.rpy_rad),
                 (nav.depth.depth_m, tiny_mission.depth.depth_m), (nav.truth.position_ned_m, tiny_mission.truth.position_ned_m)]:
        np.testing.assert_array_equal(a, b)


def test_scans_see_the_objects_and_are_stamped(tiny_mission):
    m = tiny_mission
    assert 10 < len(m.scans) < 60
    seen = set()
    for rec in m.scans:
        cloud = m.load_scan(rec.scan_id)
        assert cloud.n_points == rec.n_points > 0 and cloud.frame_id == "scanner"
        assert rec.end_stamp_s - rec.start_stamp_s == pytest.approx((40 - 1) / 40 / 3.0)
        seen |= set(np.unique(cloud.fields["instance"][cloud.fields["instance"] >= 0]).tolist())
    assert seen == {0, 1, 2, 3}  # every fitting is scanned during the loop


def test_same_seed_gives_byte_identical_directories(tmp_path, tiny_mission):
    write_dataset(tiny_mission, tmp_path / "a")
    write_dataset(simulate_dataset(_tiny(), seed=7), tmp_path / "b")
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert len(files) == 7 + 2 + len(tiny_mission.scans)  # 6 CSV/JSON, vehicle.toml, index, marker, scans
    _, mismatch, errors = filecmp.cmpfiles(tmp_path / "a", tmp_path / "b", [str(f) for f in files], shallow=False)
    assert mismatch == [MARKER] and not errors  # the ownership marker's id is drawn per directory (semslam._outdir)
    write_dataset(simulate_dataset(_tiny(), seed=8), tmp_path / "c")
    assert (tmp_path / "a" / "dvl.csv").read_bytes() != (tmp_path / "c" / "dvl.csv").read_bytes()


def test_mission_round_trips_through_disk(tmp_path, tiny_mission):
    m = tiny_mission
    out = write_dataset(m, tmp_path / "m")
    r = read_dataset(out)
    assert r.directory == out and r.seed == 7 and r.scan_clouds is None
    assert json.dumps(r.metadata, sort_keys=True) == json.dumps(m.metadata, sort_keys=True, default=list)
    np.testing.assert_array_equal(r.vehicle.scanner.T_vehicle_scanner.matrix, m.vehicle.scanner.T_vehicle_scanner.matrix)
    for a, b in [(r.dvl.stamp_s, m.dvl.stamp_s), (r.dvl.velocity_body_mps, m.dvl.velocity_body_mps), (r.dvl.valid, m.dvl.valid),
                 (r.attitude.rpy_rad, m.attitude.rpy_rad), (r.depth.depth_m, m.depth.depth_m),
                 (r.truth.position_ned_m, m.truth.position_ned_m), (r.truth.velocity_body_mps, m.truth.velocity_body_mps)]:
        np.testing.assert_array_equal(a, b)
    assert [(o.name, o.label, o.in_database) for o in r.objects] == [(o.name, o.label, o.in_database) for o in m.objects]
    for a, b in zip(r.objects, m.objects):
        np.testing.assert_allclose(a.T_world_object.matrix, b.T_world_object.matrix, atol=1e-12)
    assert [(s.scan_id, s.start_stamp_s, s.end_stamp_s, s.path, s.n_points) for s in r.scans] == \
           [(s.scan_id, s.start_stamp_s, s.end_stamp_s, s.path, s.n_points) for s in m.scans]
    a, b = r.load_scan(3), m.load_scan(3)
    np.testing.assert_allclose(a.points_xyz_m, b.points_xyz_m, atol=1e-5)  # float32 on disk
    np.testing.assert_array_equal(a.fields["instance"], b.fields["instance"])
    with pytest.raises(DatasetError, match="scan_id"):
        r.load_scan(10_000)


def _corrupt(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def test_malformed_missions_raise_mission_errors(tmp_path, tiny_mission):
    good = write_dataset(tiny_mission, tmp_path / "good")
    with pytest.raises(DatasetError, match="does not exist"):
        read_dataset(tmp_path / "nothing")
    d = _corrupt(good, tmp_path / "d1")
    (d / "dvl.csv").unlink()
    with pytest.raises(DatasetError, match="dvl.csv"):
        read_dataset(d)
    d = _corrupt(good, tmp_path / "d2")
    (d / "ahrs.csv").write_text("stamp_s,roll,pitch,yaw\n0,0,0,0\n")
    with pytest.raises(DatasetError, match="header"):
        read_dataset(d)
    d = _corrupt(good, tmp_path / "d3")
    (d / "depth.csv").write_text("stamp_s,depth_m\n0.0,abc\n")
    with pytest.raises(DatasetError, match="depth.csv.*line 2.*depth_m"):
        read_dataset(d)
    d = _corrupt(good, tmp_path / "d4")
    meta = json.loads((d / "mission.json").read_text())
    meta["format_version"] = 99
    (d / "mission.json").write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match="format_version"):
        read_dataset(d)
    d = _corrupt(good, tmp_path / "d5")
    (d / "mission.json").write_text("{not json")
    with pytest.raises(DatasetError, match="JSON"):
        read_dataset(d)
    d = _corrupt(good, tmp_path / "d6")
    (d / tiny_mission.scans[0].path).unlink()
    with pytest.raises(DatasetError, match="scan_00000.pcd"):
        read_dataset(d)
    d = _corrupt(good, tmp_path / "d7")
    (d / "depth.csv").write_text("stamp_s,depth_m\n1.0,5\n0.5,5\n")
    with pytest.raises(DatasetError, match="sorted"):
        read_dataset(d)
    with pytest.raises(DatasetError, match="must not exist"):
        write_dataset(tiny_mission, good)


def _flight(**kw):
    from semslam.simulation.simulate import mission_trajectory

    cfg = SimulatorConfig(trajectory=TrajectoryConfig(**kw))
    return mission_trajectory(None, cfg, np.random.default_rng(3))


def test_teleoperated_flight_wanders_but_stays_consistent():
    """Speed wander and crab: the truth stays self-consistent (d position / dt = velocity, to finite-difference
    accuracy), starts and stops at rest on the start point, and has the configured rms in cruise."""
    import math

    tr = _flight(speed_wander_mps=0.02, crab_rms_rad=math.radians(2.0))
    dt = 1e-3
    t = np.arange(0.0, tr.duration_s, dt)
    s = tr.sample(t)
    dp = np.gradient(s.position_ned_m, dt, axis=0)
    np.testing.assert_allclose(dp[2:-2], s.velocity_ned_mps[2:-2], atol=2e-4)  # no jump in speed anywhere
    ends = tr.sample([0.0, tr.duration_s])
    np.testing.assert_allclose(np.linalg.norm(ends.velocity_ned_mps[:, :2], axis=1), 0.0, atol=1e-9)  # at rest
    np.testing.assert_allclose(ends.position_ned_m[1, :2], ends.position_ned_m[0, :2], atol=1e-9)
    cruise = (t > 5.0) & (t < tr.duration_s - 5.0)
    speed = np.linalg.norm(s.velocity_ned_mps[cruise, :2], axis=1)
    assert 0.015 < speed.std() < 0.025 and abs(speed.mean() - 0.3) < 0.01
    assert speed.min() > 0.2  # never stops or reverses
    crab = tr.crab_rad(t[cruise])
    assert math.radians(1.5) < crab.std() < math.radians(2.5)
    # the crab is heading minus course: body sway = -speed sin(crab)
    np.testing.assert_allclose(s.velocity_body_mps[cruise, 1], -speed * np.sin(crab), atol=2e-3)
    # off: exactly the nominal speed in cruise and no sway
    ideal = _flight(speed_wander_mps=0.0, crab_rms_rad=0.0).sample(t[cruise])
    np.testing.assert_allclose(np.linalg.norm(ideal.velocity_ned_mps[:, :2], axis=1), 0.3, atol=1e-12)
    assert np.abs(ideal.velocity_body_mps[:, 1]).max() < 2e-3


def test_bad_configuration_raises_simulation_error():
    with pytest.raises(SimulationError, match="seed"):
        simulate_dataset(_tiny(), seed=-1, with_scans=False)
    with pytest.raises(SimulationError, match="loops"):
        TrajectoryConfig(loops=0)
    with pytest.raises(SimulationError, match="corner_radius_m"):
        simulate_dataset(SimulatorConfig(trajectory=TrajectoryConfig(corner_radius_m=2.0)), with_scans=False)
    with pytest.raises(SimulationError, match="speed_wander_mps"):
        TrajectoryConfig(speed_wander_mps=0.1)
    with pytest.raises(SimulationError, match="crab_rms_rad"):
        TrajectoryConfig(crab_rms_rad=-0.01)
    with pytest.raises(SimulationError, match="Unknown field"):
        SimulatorConfig.from_dict({"dvl": {"rate": 5}})
    cfg = SimulatorConfig(world=WorldConfig(clutter=True))
    assert SimulatorConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg


def test_clutter_is_marked_not_in_database():
    cfg = dataclasses.replace(_tiny(), world=WorldConfig(clutter=True, n_clutter=4))
    m = simulate_dataset(cfg, seed=1, with_scans=False)
    clutter = [o for o in m.objects if not o.in_database]
    assert len(clutter) == 4 and all(o.label == "clutter" for o in clutter)


def test_cli_simulate(tmp_path, capsys):
    out = tmp_path / "cli"
    assert main(["simulate", "--out", str(out), "--quick", "--no-scans", "--seed", "3", "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["n_scans"] == 0 and payload["seed"] == 3 and (out / "mission.json").is_file()
    assert read_dataset(out).seed == 3
    assert main(["simulate", "--out", str(out), "--quick", "--no-scans"]) == 1
    assert "--overwrite" in capsys.readouterr().err
    assert main(["simulate", "--out", str(tmp_path / "x"), "--quick", "--scan-rate", "0"]) == 1
