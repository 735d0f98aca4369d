"""``semslam run`` on a recorded dive, as a user runs it: the simulator's dive written as a ROS 1 bag with only the
files the recorder leaves beside it (no ground truth), streamed through the one runner; frames never guessed; the
health verdict; the same dive as a dataset directory, with and without its ground truth."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from semslam.cli.main import main

SEED = 7


@pytest.fixture(scope="module")
def dive(tmp_path_factory):
    """One short simulated dive (starts at 3.5 m, 5 surface GPS fixes before it) as a ROS 1 bag and as a mission
    directory, both written by the CLI."""
    d = tmp_path_factory.mktemp("dive")
    common = ["--quick", "--seed", str(SEED), "--gps", "5", "--scan-interval", "2.0"]
    assert main(["simulate", "--out", str(d / "dive.bag"), "--format", "ros1", *common]) == 0
    assert main(["simulate", "--out", str(d / "mission"), *common]) == 0
    return d


def _run(capsys, *argv) -> tuple[int, dict]:
    code = main(["run", *argv, "--json", "--no-report"])
    out = capsys.readouterr().out
    return code, (json.loads(out) if code in (0, 3) else {})


def test_bag_run_uses_the_recorders_files_and_starts_at_depth_from_the_gps_fix(dive, tmp_path, capsys):
    code, p = _run(capsys, str(dive / "dive.bag"), "--db", "builtin", "--out", str(tmp_path / "r"), "--mode", "pose")
    assert code == 0
    run = json.loads((tmp_path / "r" / "run.json").read_text())
    assert run["source"]["source"]["topics"].endswith("dive.bag.topics.toml")
    assert run["source"]["source"]["vehicle"].endswith("dive.bag.vehicle.toml")
    start = p["start"]
    assert start["frame"] == "world" and "position fix" in start["sources"]["horizontal"]
    assert start["position_ned_m"][2] == pytest.approx(3.5, abs=0.1)   # the pressure sensor, not z = 0
    assert run["geodetic_origin"]["latitude_deg"] == pytest.approx(41.9785)
    m = p["slam"]["pose"]
    assert m["depth_rejected"] == 0 and m["fix_updates"] == 0            # the fixes are all before the dive
    assert p["verdict"] in ("ok", "warning"), p["health"]
    # streamed: no dataset directory, no scan written
    assert not (tmp_path / "r" / "mission").exists() and not list((tmp_path / "r").rglob("*.pcd"))


def test_bag_and_mission_directory_give_the_same_run(dive, tmp_path, capsys):
    """The same dive through the bag (ENU/FLU messages, NavSatFix) and the dataset directory: the same start, the
    same map, trajectories within millimetres (the bag's float32 fields and pressure conversion)."""
    _, bag = _run(capsys, str(dive / "dive.bag"), "--db", "builtin", "--out", str(tmp_path / "b"), "--mode", "pose")
    _, mis = _run(capsys, str(dive / "mission"), "--db", "builtin", "--out", str(tmp_path / "m"), "--mode", "pose")
    np.testing.assert_allclose(bag["start"]["position_ned_m"], mis["start"]["position_ned_m"], atol=1e-3)
    assert bag["slam"]["pose"]["n_landmarks"] == mis["slam"]["pose"]["n_landmarks"]
    a = np.loadtxt(tmp_path / "b" / "slam" / "pose" / "trajectory.tum")
    b = np.loadtxt(tmp_path / "m" / "slam" / "pose" / "trajectory.tum")
    assert a.shape == b.shape
    np.testing.assert_allclose(a[-1, 1:4], b[-1, 1:4], atol=0.01)


def test_detect_on_a_bag_gives_the_detections_run_keeps(dive, tmp_path, capsys):
    """`semslam detect BAG` streams the bag through the runner of `semslam run`: the same scans and detections, byte
    for byte, as the run directory's detections.jsonl, nothing converted on disk (this short dive's scans hold no
    detection; the demo's mission, with detections, is checked the same way in test_demo_e2e)."""
    code, _ = _run(capsys, str(dive / "dive.bag"), "--db", "builtin", "--out", str(tmp_path / "r"), "--mode", "pose")
    assert code == 0
    dets = tmp_path / "dets.jsonl"
    assert main(["detect", str(dive / "dive.bag"), "--db", "builtin", "--out", str(dets), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)["summary"]
    run = json.loads((tmp_path / "r" / "run.json").read_text())
    assert summary["n_scans"] == run["detection"]["n_scans"] > 0
    assert summary["n_clusters"] == run["detection"]["n_clusters"] > 0
    assert summary["n_kept"] == len(dets.read_text().splitlines())
    assert dets.read_text() == (tmp_path / "r" / "detections.jsonl").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dets.jsonl", "dets.jsonl.config.json", "r"]


def test_same_dive_with_and_without_ground_truth_gives_byte_identical_trajectories_and_maps(dive, tmp_path, capsys):
    blind = tmp_path / "blind"
    shutil.copytree(dive / "mission", blind)
    shutil.rmtree(blind / "ground_truth")
    code_a, a = _run(capsys, str(dive / "mission"), "--db", "builtin", "--out", str(tmp_path / "a"), "--mode", "pose")
    code_b, b = _run(capsys, str(blind), "--db", "builtin", "--out", str(tmp_path / "b"), "--mode", "pose")
    assert code_a == code_b == 0
    assert "ate_rmse_m" in a["slam"]["pose"] and "ate_rmse_m" not in b["slam"]["pose"]
    for name in ("trajectory.tum", "trajectory_smoothed.tum", "trajectory.kitti", "map.json", "map.csv", "map.ply"):
        assert (tmp_path / "a" / "slam" / "pose" / name).read_bytes() == \
            (tmp_path / "b" / "slam" / "pose" / name).read_bytes(), name


def test_forcing_the_wrong_dvl_frame_ends_with_a_bad_verdict_and_strict_exits_3(dive, tmp_path, capsys):
    topics = (dive / "dive.bag.topics.toml").read_text().replace('dvl = "frd"', 'dvl = "flu"')
    (tmp_path / "topics.toml").write_text(topics)
    code, p = _run(capsys, str(dive / "dive.bag"), "--db", "builtin", "--out", str(tmp_path / "r"), "--mode", "pose",
                   "--topics", str(tmp_path / "topics.toml"), "--strict")
    assert code == 3 and p["verdict"] == "bad", p["health"]
    assert any(c["level"] == "bad" and c["check"].startswith("depth") for c in p["health"]["pose"]["checks"])


def test_a_bag_without_a_vehicle_description_is_refused(dive, tmp_path, capsys):
    shutil.copy(dive / "dive.bag", tmp_path / "alone.bag")
    assert main(["run", str(tmp_path / "alone.bag"), "--db", "builtin", "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err
    assert "no vehicle description" in err and "alone.bag.vehicle.toml" in err and err.count("\n") == 1
    assert not (tmp_path / "r").exists()


def test_a_missing_database_is_named_before_the_dive_is_read(tmp_path, capsys):
    assert main(["run", str(tmp_path / "no.bag"), "--db", str(tmp_path / "no.npz"), "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err
    assert "no.npz" in err and err.count("\n") == 1


def test_a_twist_dvl_whose_frame_nothing_states_stops_with_the_suggested_map(tmp_path, capsys):
    """A generic twist carries no frame convention: without a topic map stating it, the run stops (one error, the
    suggested map in it) instead of guessing."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    from semslam.dataset import VehicleDescription, write_vehicle_toml

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    bag = tmp_path / "twist.bag"
    with Writer(bag) as w:
        ci = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=store)
        cd = w.add_connection("/dvl/twist", "geometry_msgs/msg/TwistStamped", typestore=store)
        for k in range(5):
            ns = 1_000_000_000 + k * 100_000_000
            hdr = T["std_msgs/msg/Header"](seq=k, stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=k * 100_000_000),
                                          frame_id="base_link")
            v3 = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
            imu = T["sensor_msgs/msg/Imu"](header=hdr, orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                                           orientation_covariance=np.zeros(9), angular_velocity=v3,
                                           angular_velocity_covariance=np.zeros(9), linear_acceleration=v3,
                                           linear_acceleration_covariance=np.zeros(9))
            tw = T["geometry_msgs/msg/TwistStamped"](header=hdr, twist=T["geometry_msgs/msg/Twist"](
                linear=T["geometry_msgs/msg/Vector3"](x=0.3, y=0.0, z=0.0), angular=v3))
            w.write(ci, ns, store.serialize_ros1(imu, "sensor_msgs/msg/Imu"))
            w.write(cd, ns, store.serialize_ros1(tw, "geometry_msgs/msg/TwistStamped"))
    write_vehicle_toml(VehicleDescription.girona500(), tmp_path / "twist.bag.vehicle.toml")
    assert main(["run", str(bag), "--db", "builtin", "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err
    assert "/dvl/twist" in err and "cannot be established" in err and "[topics]" in err
    assert not (tmp_path / "r").exists()
