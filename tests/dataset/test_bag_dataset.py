"""ROS bags as datasets: a simulated mission written as ROS 1, ROS 2 mcap and ROS 2 sqlite3 bags reads back to
the same logs and scans, gives the same detections and the same trajectories as the dataset directory; topic
maps and the CLI (`semslam bag info/export`, `semslam simulate --format`, `semslam run`)."""

from __future__ import annotations

import json
import os
from dataclasses import replace

import numpy as np
import pytest

from semslam.cli.main import main
from semslam.dataset import read_dataset, write_dataset
from semslam.dataset.rosbag import TopicMap, export_bag, read_topic_map
from semslam.dataset.rosbag_write import FORMATS, SEMSLAM_TOPICS, write_bag
from semslam.errors import BagError, DatasetError


@pytest.fixture(scope="module")
def mission(tmp_path_factory):
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset

    m = simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed=4)
    d = write_dataset(m, tmp_path_factory.mktemp("m") / "mission")
    return replace(read_dataset(d), truth=None)  # a recorded dive has no ground truth


@pytest.fixture(scope="module")
def recognizer(tmp_path_factory):
    os.environ["SEMSLAM_CACHE_DIR"] = str(tmp_path_factory.mktemp("cache"))
    from semslam.pipeline import ScanRecognizer
    from semslam.simulation.builtin_db import builtin_database

    rec = ScanRecognizer(builtin_database(seed=0), seed=0)
    rec.warm_up()
    return rec


def _bag_name(tmp_path, fmt):
    return tmp_path / ("dive.bag" if fmt == "ros1" else f"dive_{fmt}")


def test_every_bag_format_round_trips_the_logs_and_scans(mission, tmp_path):
    """Logs, scans and point stamps come back; the scanner's mounting comes from the bag's /tf_static (the
    vehicle file given here has none: identity), converted from the ROS FLU body to FRD."""
    from semslam.geometry import RigidTransform

    no_mount = mission.vehicle.replace(scanner=replace(mission.vehicle.scanner, T_vehicle_scanner=RigidTransform.identity()))
    for fmt in FORMATS:
        bag = write_bag(mission, _bag_name(tmp_path, fmt), fmt)
        back = read_dataset(export_bag(bag, tmp_path / f"m_{fmt}", topic_map=SEMSLAM_TOPICS, vehicle=no_mount))
        np.testing.assert_allclose(back.vehicle.scanner.T_vehicle_scanner.matrix, mission.vehicle.scanner.T_vehicle_scanner.matrix, atol=1e-12)
        assert back.metadata["source"]["T_vehicle_scanner_from"] == "/tf_static"
        np.testing.assert_allclose(back.attitude.stamp_s, mission.attitude.stamp_s, rtol=0, atol=1e-9)
        np.testing.assert_allclose(back.attitude.rpy_rad, mission.attitude.rpy_rad, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(back.dvl.valid, mission.dvl.valid)
        np.testing.assert_allclose(back.dvl.velocity_body_mps, mission.dvl.velocity_body_mps, rtol=0, atol=1e-12)
        np.testing.assert_allclose(back.dvl.beam_range_m, mission.dvl.beam_range_m, rtol=0, atol=1e-12)
        np.testing.assert_allclose(back.depth.depth_m, mission.depth.depth_m, rtol=0, atol=1e-9)
        assert [s.n_points for s in back.scans] == [s.n_points for s in mission.scans]
        k = len(mission.scans) // 2
        a, b = mission.load_scan(k), back.load_scan(k)
        np.testing.assert_array_equal(a.points_xyz_m, b.points_xyz_m)
        np.testing.assert_allclose(back.point_stamps_s(back.scans[k], b), mission.point_stamps_s(mission.scans[k], a),
                                   rtol=0, atol=1e-9)
        assert back.metadata["source"]["time_origin_ns"] % 1_000_000_000 == 0


def test_bags_give_the_mission_directory_detections_and_trajectories(mission, recognizer, tmp_path):
    """The issue's round trip: ROS 1, ROS 2 mcap and ROS 2 sqlite3 give the same detections and the same
    trajectories (to 1e-9) as the dataset directory."""
    from semslam.pipeline.dataset_detection import detect_dataset
    from semslam.simulation.truth_slam import builtin_symmetries
    from semslam.run import run_slam

    sym = builtin_symmetries()
    ref_dets = detect_dataset(mission, recognizer, seed=0).detections_by_scan
    assert sum(len(v) for v in ref_dets.values()) >= 5
    ref = run_slam(mission, ref_dets, mode="pose", symmetries=sym)
    for fmt in FORMATS:
        bag = write_bag(mission, _bag_name(tmp_path, fmt), fmt)
        ds = read_dataset(export_bag(bag, tmp_path / f"m_{fmt}", topic_map=SEMSLAM_TOPICS, vehicle=mission.vehicle))
        dets = detect_dataset(ds, recognizer, seed=0).detections_by_scan
        assert sorted(dets) == sorted(ref_dets), fmt
        for sid in ref_dets:
            assert [d.label for d in dets[sid]] == [d.label for d in ref_dets[sid]]
            for d, e in zip(dets[sid], ref_dets[sid]):
                np.testing.assert_allclose(d.T_sensor_object.matrix, e.T_sensor_object.matrix, rtol=0, atol=1e-9)
                assert abs(d.stamp_s - e.stamp_s) < 1e-9
        res = run_slam(ds, dets, mode="pose", symmetries=sym)
        np.testing.assert_allclose(res.position_ned_m, ref.position_ned_m, rtol=0, atol=1e-9)
        np.testing.assert_allclose(res.smoothed_position_ned_m, ref.smoothed_position_ned_m, rtol=0, atol=1e-9)
        assert [lm.label for lm in res.landmarks] == [lm.label for lm in ref.landmarks]


def test_topic_map_errors_name_the_topic_and_the_bag(mission, tmp_path):
    bag = write_bag(mission, tmp_path / "d.bag", "ros1")
    missing = replace(SEMSLAM_TOPICS, dvl="/dvl/nothing")
    with pytest.raises(BagError, match=r"topic '/dvl/nothing' not found.*/semslam/imu"):
        export_bag(bag, tmp_path / "x", topic_map=missing, vehicle=mission.vehicle)
    wrong = replace(SEMSLAM_TOPICS, attitude="/semslam/pressure", depth=None)  # one sensor per topic
    with pytest.raises(BagError, match=r"'/semslam/pressure' must have type sensor_msgs/msg/Imu"):
        export_bag(bag, tmp_path / "x", topic_map=wrong, vehicle=mission.vehicle)
    assert not (tmp_path / "x").exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".x")]
    f = tmp_path / "t.toml"
    for text, words in (('[topics]\nimu = "/a"\n', "topics.imu"), ('[frames]\nattitude = "nwu"\n', "enu"),
                        ('[topics]\nscans = "points"\n', "starting with '/'"), ("[topics\n", "TOML")):
        f.write_text(text)
        with pytest.raises(DatasetError, match=words):
            read_topic_map(f)
    assert TopicMap.from_dict({"topics": {"attitude": "/imu"}}).attitude == "/imu"


def test_cli_simulate_bag_info_export_and_run(tmp_path, capsys):
    """`semslam simulate --format ros1` writes the bag with its vehicle and topic files; `bag info` lists the
    topics; `run` goes through detection, SLAM and a report without ground truth."""
    bag = tmp_path / "dive.bag"
    assert main(["simulate", "--quick", "--format", "ros1", "--out", str(bag), "--seed", "1", "--json"]) == 0
    capsys.readouterr()
    assert bag.is_file() and (tmp_path / "dive.bag.vehicle.toml").is_file()
    assert main(["bag", "info", str(bag), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert {t["topic"] for t in info["topics"]} == {"/semslam/scans", "/semslam/imu", "/semslam/dvl", "/semslam/pressure",
                                                    "/tf_static"}
    assert 'attitude = "/semslam/imu"' in info["suggested_topic_map"]
    run = tmp_path / "run"
    assert main(["run", str(bag), "--db", "builtin", "--out", str(run), "--vehicle", f"{bag}.vehicle.toml",
                 "--topics", f"{bag}.topics.toml", "--mode", "pose", "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert (run / "report.html").is_file() and (run / "slam" / "pose" / "trajectory.csv").is_file()
    for name in ("trajectory.tum", "trajectory.kitti", "map.json", "map.ply", "run.mcap"):
        assert (run / "slam" / "pose" / name).is_file(), name
    assert "ate_rmse_m" not in payload["slam"]["pose"]  # no ground truth in a bag: no error metrics
    assert main(["run", str(bag), "--db", "builtin", "--out", str(run)]) == 1
    assert "holds an earlier semslam run" in capsys.readouterr().err
    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\n" + bytes(100))
    assert main(["bag", "info", str(tmp_path / "junk.bag")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "junk.bag" in err[0]


def test_report_of_a_dive_without_ground_truth(tmp_path):
    """A recorded dive has no truth: the report leaves the truth-based sections out and still shows the
    trajectories, the 3-sigma bounds over time and the landmark maps."""
    from semslam.simulation.synthetic import square_dataset
    from semslam.report.build import build_report
    from semslam.simulation.detections import TruthDetectionConfig, simulate_detections
    from semslam.run import run_slam
    from semslam.run.rundir import write_run
    from semslam.run.rundir import mode_dir

    m = square_dataset(seed=1, loops=1)
    dets = simulate_detections(m, TruthDetectionConfig(), seed=1)
    dive = replace(m, truth=None, objects=[])
    for mode in ("dr", "pose"):
        res = run_slam(dive, dets, mode=mode, symmetries={})
        assert "ate_rmse_m" not in res.metrics and res.truth_position_ned_m is None
        write_run(res, mode_dir(tmp_path, mode))
    html = build_report(tmp_path).read_text()
    assert "no ground truth" in html and "Landmark maps" in html and "Fig. 4" in html
    assert "NEES over time" not in html and "Fig. 6: position error" not in html


def test_a_dive_streamed_scan_by_scan_gives_the_same_bag_byte_for_byte(tmp_path):
    """``simulate_scans`` gives ``simulate_dataset``'s scans one at a time (records and clouds bit for bit), and
    ``write_bag(..., scans=...)`` of the navigation-only dataset with them is the bag of the whole dataset, byte for
    byte (a 30-minute dive is written this way without holding its scans)."""
    from semslam.dataset.rosbag_write import topic_map_of
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset, simulate_scans
    from semslam.simulation.config import ScannerConfig

    cfg = SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1),
                                    scanner=ScannerConfig(n_lines=60, points_per_line=60))
    whole = simulate_dataset(cfg, seed=5)
    nav = simulate_dataset(cfg, seed=5, with_scans=False)
    streamed = list(simulate_scans(cfg, seed=5))
    import dataclasses

    assert [dataclasses.astuple(r) for r, _ in streamed] == [dataclasses.astuple(r) for r in whole.scans]
    assert len(whole.scans) > 10
    for rec, cloud in streamed:
        ref = whole.load_scan(rec.scan_id)
        np.testing.assert_array_equal(cloud.points_xyz_m, ref.points_xyz_m)
        assert cloud.fields.keys() == ref.fields.keys()
    a = write_bag(whole, tmp_path / "whole.bag", "ros1")
    b = write_bag(nav, tmp_path / "streamed.bag", "ros1", scans=simulate_scans(cfg, seed=5))
    assert a.read_bytes() == b.read_bytes()
    assert topic_map_of(nav, scans=True) == topic_map_of(whole) != topic_map_of(nav)
    with pytest.raises(Exception, match="scan_interval_s"):
        simulate_scans(cfg, seed=5, scan_interval_s=0.01)
