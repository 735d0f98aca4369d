"""The ROS 1 node on a real roscore, no mocks: a simulated dive played with `rosbag play`, the node's outputs
recorded with `rosbag record` and read back with semslam's bag reader, compared with the offline chain
(detect_dataset + run_slam) on the same bag. Everything started is stopped by PID; ROS logs stay in tmp_path."""

from __future__ import annotations

import json
from pathlib import Path
import subprocess
import sys
import time

import numpy as np
import pytest

from tests._support.ros1 import free_port, require_ros, ros_env, roscore, started, stop

pytestmark = pytest.mark.slow


def _wait(cond, timeout_s: float, what: str, log=None) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            tail = log.read_text(errors="replace")[-3000:] if log is not None and log.exists() else ""
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}\n{tail}")
        time.sleep(0.2)


def _node_up(uri: str, name: str) -> bool:
    import rosgraph

    try:
        rosgraph.Master("/semslam_test", master_uri=uri).lookupNode(name)
        return True
    except Exception:  # noqa: BLE001 - not registered yet
        return False


def _subscribed(uri: str, topic: str, n: int = 1) -> bool:
    import rosgraph

    _, subs, _ = rosgraph.Master("/semslam_test", master_uri=uri).getSystemState()
    return any(t == topic and len(nodes) >= n for t, nodes in subs)


@pytest.fixture(scope="module")
def dive(tmp_path_factory):
    """A 24 s simulated dive with objects (40k-point scans) as a ROS 1 bag, its topic map, vehicle file and the
    built-in database file."""
    require_ros()
    from semslam.dataset import write_dataset, read_dataset, write_vehicle_toml
    from semslam.dataset.rosbag_write import SEMSLAM_TOPICS, write_bag
    from semslam.recognition.storage import save_database
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset
    from semslam.simulation.builtin_db import builtin_database
    from semslam.simulation.config import ScannerConfig

    d = tmp_path_factory.mktemp("dive")
    cfg = SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1), scanner=ScannerConfig(n_lines=200,
                                                                                                  points_per_line=200))
    mission = read_dataset(write_dataset(simulate_dataset(cfg, seed=4), d / "mission"))
    bag = write_bag(mission, d / "dive.bag", "ros1")
    (d / "topics.toml").write_text(SEMSLAM_TOPICS.to_toml(), encoding="utf-8")
    write_vehicle_toml(mission.vehicle, d / "vehicle.toml")
    save_database(builtin_database(seed=0), d / "objects.npz")
    return {"bag": bag, "topics": d / "topics.toml", "vehicle": d / "vehicle.toml", "db": d / "objects.npz",
            "mission": mission}


def _offline(dive, tmp_path):
    """`semslam run` of the bag (run_dive, the one runner): its pose trajectory and landmarks as written."""
    import csv

    from semslam.recognition import load_database
    from semslam.run.dive import run_dive

    out = tmp_path / "offline"
    out.mkdir()
    payload = run_dive(dive["bag"], out, db=load_database(dive["db"]), modes=("pose",), topics=dive["topics"],
                       vehicle=dive["vehicle"], export=False)
    rows = list(csv.DictReader(open(out / "slam" / "pose" / "trajectory.csv", encoding="utf-8")))
    lms = list(csv.DictReader(open(out / "slam" / "pose" / "landmarks.csv", encoding="utf-8")))
    return {"stamps_s": np.array([float(r["stamp_s"]) for r in rows]),
            "position_ned_m": np.array([[float(r[k]) for k in ("x_m", "y_m", "z_m")] for r in rows]),
            "landmarks": [(r["label"], int(r["landmark_id"]), np.array([float(r[k]) for k in ("x_m", "y_m", "z_m")]))
                          for r in lms], "payload": payload, "dir": out}


def _recorder() -> list[str]:
    """Debian's C++ recorder itself (one process: one SIGINT closes its bag), else the ``rosbag record`` wrapper
    (whose child, signalled with its group and again by the wrapper, left ``NAME.bag.active`` unclosed in 2 of ~8
    loaded runs)."""
    binary = Path("/usr/lib/rosbag/record")
    return [str(binary)] if binary.is_file() else ["rosbag", "record"]


def test_node_on_a_real_roscore_matches_the_offline_run(dive, tmp_path):
    """rosbag play -> node -> rosbag record: every odometry within 5 cm of the offline filter at its stamp, one
    ellipsoid per mapped landmark where the offline map has it, diagnostics OK; at SIGINT the run directory holds
    the offline trajectory (to 1e-6 m when no message was dropped)."""
    from semslam.io.ros import open_bag

    run = tmp_path / "run"
    with roscore(tmp_path) as env:
        uri = env["ROS_MASTER_URI"]
        node_cmd = [sys.executable, "-m", "semslam.run.ros1.node", "--db", str(dive["db"]), "--topics",
                    str(dive["topics"]), "--vehicle", str(dive["vehicle"]), "--mode", "pose", "--out", str(run),
                    "--scan-queue", "all", "--max-hold", "1000", "--window", "4.5"]
        with started(node_cmd, env, tmp_path / "node.log") as node:
            ref = _offline(dive, tmp_path)  # while the node starts
            _wait(lambda: _node_up(uri, "/semslam") and _subscribed(uri, "/semslam/scans"), 60, "the node",
                  tmp_path / "node.log")
            topics = ["/semslam/odometry", "/semslam/odometry/filtered", "/semslam/landmarks", "/diagnostics",
                      "/semslam/path", "/tf", "/semslam/detections"]
            # a loaded machine may need a while to close the bag: SIGINT, then up to 60 s to rename out.bag.active
            with started([*_recorder(), "-O", str(tmp_path / "out.bag"), *topics], env,
                         tmp_path / "record.log", stop_timeout_s=60.0) as rec:
                _wait(lambda: _subscribed(uri, "/semslam/odometry"), 30, "rosbag record", tmp_path / "record.log")
                play = subprocess.run(["rosbag", "play", "-q", "-d", "1", "-r", "1.5", str(dive["bag"])], env=env,
                                      capture_output=True, text=True, timeout=120)
                assert play.returncode == 0, play.stderr
                time.sleep(3.0)  # the node recognises the last scans
            assert rec.poll() is not None
            stop(node, timeout=60.0)
            assert node.returncode == 0, (tmp_path / "node.log").read_text()[-3000:]
        assert node.poll() is not None
    stats = json.loads((run / "ros_node.json").read_text())
    assert stats["stats"]["scans_recognised"] == len(dive["mission"].scans)

    odo, pred, markers, diags, n_tf, dets = [], [], None, [], 0, []
    with open_bag(tmp_path / "out.bag") as b:
        for m in b.messages(["/semslam/odometry", "/semslam/odometry/filtered", "/semslam/landmarks", "/diagnostics",
                             "/tf", "/semslam/detections"]):
            if m.topic.startswith("/semslam/odometry"):
                s = m.msg.header.stamp
                p = m.msg.pose.pose.position
                (odo if m.topic.endswith("filtered") else pred).append((s.sec + s.nanosec * 1e-9, p.y, p.x, -p.z))
                assert m.msg.header.frame_id == "map" and m.msg.child_frame_id == "base_link"
            elif m.topic == "/tf":
                n_tf += m.msg.transforms[0].child_frame_id == "base_link"
            elif m.topic == "/semslam/landmarks":
                markers = m.msg
            elif m.topic == "/semslam/detections":
                dets.append(m.msg)
            else:
                diags.append(m.msg.status[0])
    # odometry: within 5 cm of the offline filter's history (interpolated at the odometry's stamp)
    odo = np.array(odo)
    assert len(odo) > 100
    origin = stats["time_origin_ns"] / 1e9
    rs, rp = ref["stamps_s"], ref["position_ned_m"]
    t = odo[:, 0] - origin
    inside = t <= rs[-1]
    ref_p = np.stack([np.interp(t[inside], rs, rp[:, i]) for i in range(3)], axis=1)
    err = np.linalg.norm(odo[inside, 1:] - ref_p, axis=1)
    assert err.max() < 0.05, f"odometry off the offline run by up to {err.max():.3f} m"
    # the low-latency odometry: one per attitude sample once the filter has started, as many TFs
    pred = np.array(pred)
    assert len(pred) > 0.8 * len(odo) and n_tf == len(pred)
    t = pred[:, 0] - origin
    inside = t <= rs[-1]
    ref_p = np.stack([np.interp(t[inside], rs, rp[:, i]) for i in range(3)], axis=1)
    pred_err = np.linalg.norm(pred[inside, 1:] - ref_p, axis=1)
    print(f"predicted odometry vs offline: median {np.median(pred_err):.3f} m, max {pred_err.max():.3f} m")
    assert np.median(pred_err) < 0.25
    # landmarks: one ellipsoid per landmark of the offline map, at its position (ENU)
    assert markers is not None
    spheres = {(mk.ns, mk.id): mk for mk in markers.markers if mk.type == 2}
    texts = {(mk.ns, mk.id) for mk in markers.markers if mk.type == 9}
    assert len(ref["landmarks"]) >= 1 and len(spheres) == len(ref["landmarks"]) == len(texts)
    for label, lid, p_ned in ref["landmarks"]:
        p = spheres[(label, lid)].pose.position
        assert np.linalg.norm(np.array([p.y, p.x, -p.z]) - p_ned) < 0.05
    # /semslam/detections (semslam_msgs/DetectionArray, published raw), decoded from the recorded bytes: one array
    # per recognised scan (the recorder stops while the node may still recognise the last ones), the detections
    # kept for SLAM among them (reliable), as in the run directory
    ids = [a.scan_id for a in dets]
    assert len(set(ids)) == len(ids) and len(ids) >= len(dive["mission"].scans) // 2
    kept: dict = {}
    for line in open(run / "detections.jsonl", encoding="utf-8"):
        d = json.loads(line)
        kept[d["scan_id"]] = kept.get(d["scan_id"], 0) + 1
    assert sum(kept.values()) >= 1
    for a in dets:
        assert sum(d.reliable for d in a.detections) == kept.get(a.scan_id, 0)
        assert a.header.frame_id and all(len(d.pose.covariance) == 36 for d in a.detections)
    # diagnostics: published, healthy while the bag played (the health verdict among them), with the scan counters
    assert diags and all(s.name == "semslam: SLAM" for s in diags)
    assert any(s.level == 0 and s.message == "OK" for s in diags)
    last = {kv.key: kv.value for kv in diags[-1].values}
    assert int(last["scans_recognised"]) >= 1 and "scan_latency_p90_ms" in last and last["verdict"] == "ok"
    # the run directory written at SIGINT: the offline trajectory
    import csv

    rows = list(csv.DictReader(open(run / "slam" / "pose" / "trajectory.csv", encoding="utf-8")))
    live_p = np.array([[float(r["x_m"]), float(r["y_m"]), float(r["z_m"])] for r in rows])
    assert live_p.shape == rp.shape
    assert np.abs(live_p - rp).max() < 0.05
    if not stats["dropped_late"]:
        np.testing.assert_allclose(live_p, rp, rtol=0, atol=1e-6)
    # the same layout as `semslam run`: run.json with the start, counts and verdict
    run_doc, ref_doc = (json.loads((d / "run.json").read_text()) for d in (run, ref["dir"]))
    assert run_doc["format"] == "semslam-run" and run_doc["verdict"] == ref_doc["verdict"]
    assert run_doc["start"] == ref_doc["start"] and run_doc["detection"]["n_kept"] == ref_doc["detection"]["n_kept"]
    assert (run / "slam" / "pose" / "map.json").is_file()


def test_node_without_a_roscore_says_so_in_one_line(dive, tmp_path):
    home = tmp_path / "ros_home"
    home.mkdir()
    env = ros_env(f"http://127.0.0.1:{free_port()}", home)
    out = subprocess.run([sys.executable, "-m", "semslam.run.ros1.node", "--db", str(dive["db"]), "--topics",
                          str(dive["topics"]), "--vehicle", str(dive["vehicle"])], env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 1
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("semslam: error: No ROS master answers at ROS_MASTER_URI=")


def test_node_refuses_a_mapped_topic_of_the_wrong_type(dive, tmp_path):
    """The depth topic published as sensor_msgs/Imu: the node stops at once with one line naming the topic."""
    with roscore(tmp_path) as env:
        with started(["rostopic", "pub", "-r", "5", "/semslam/pressure", "sensor_msgs/Imu", "{}"], env,
                     tmp_path / "pub.log"):
            import rosgraph

            _wait(lambda: "/semslam/pressure" in dict(rosgraph.Master("/t", master_uri=env["ROS_MASTER_URI"])
                                                      .getTopicTypes()), 30, "rostopic pub", tmp_path / "pub.log")
            out = subprocess.run([sys.executable, "-m", "semslam.run.ros1.node", "--db", str(dive["db"]), "--topics",
                                  str(dive["topics"]), "--vehicle", str(dive["vehicle"])], env=env,
                                 capture_output=True, text=True, timeout=120)
    assert out.returncode == 1
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("semslam: error: Topic '/semslam/pressure' (topics.depth")
    assert lines[0].endswith("Got sensor_msgs/msg/Imu instead.")


def test_semslam_ros_without_a_roscore_says_so_in_one_line(dive, tmp_path, monkeypatch, capsys):
    """The CLI `semslam ros` (cmd_ros.py through semslam.cli.main) with no master: one line, exit 1, no run dir."""
    from semslam.cli.main import main

    home = tmp_path / "ros_home"
    home.mkdir()
    for k, v in ros_env(f"http://127.0.0.1:{free_port()}", home).items():
        monkeypatch.setenv(k, v)
    rc = main(["ros", "--db", str(dive["db"]), "--topics", str(dive["topics"]), "--vehicle", str(dive["vehicle"]),
               "--mode", "pose", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and err[0].startswith("semslam: error: No ROS master answers at ROS_MASTER_URI=")
    assert not (tmp_path / "run").exists()


def test_semslam_ros_stopped_with_ctrl_c_writes_its_run_and_exits_0(dive, tmp_path):
    """The user's command, `semslam ros` (its console entry point and SIGINT handler), on a real roscore, stopped
    with Ctrl-C after 8 s of the dive: the stop is the node's normal end, not an interrupt: exit 0, the summary
    line, the run directory complete (the command's handler, chained by rospy's, must not count it)."""
    run = tmp_path / "run"
    with roscore(tmp_path) as env:
        uri = env["ROS_MASTER_URI"]
        cmd = [sys.executable, "-m", "semslam.cli.main", "ros", "--db", str(dive["db"]), "--topics",
               str(dive["topics"]), "--vehicle", str(dive["vehicle"]), "--out", str(run), "--scan-queue", "all"]
        with started(cmd, env, tmp_path / "ros.log") as node:
            _wait(lambda: _node_up(uri, "/semslam") and _subscribed(uri, "/semslam/scans"), 60, "semslam ros",
                  tmp_path / "ros.log")
            play = subprocess.run(["rosbag", "play", "-q", "-u", "8", str(dive["bag"])], env=env,
                                  capture_output=True, text=True, timeout=120)
            assert play.returncode == 0, play.stderr
            stop(node, timeout=60.0)
        log = (tmp_path / "ros.log").read_text(errors="replace")
        assert node.returncode == 0, log[-3000:]
    assert "semslam: interrupted" not in log and "run written to" in log, log[-3000:]
    doc = json.loads((run / "run.json").read_text())
    assert doc["format"] == "semslam-run" and doc["verdict"] in ("ok", "warning")
    assert len((run / "slam" / "pose" / "trajectory.csv").read_text().splitlines()) > 10



@pytest.fixture(scope="module")
def dive_with_gps(tmp_path_factory):
    """The dive of ``dive`` (seed 4) with 5 surface GPS fixes before it, as a ROS 1 bag, its topic map (GPS topic
    and geodetic origin), vehicle file and database; and dive 1's map (the same dive run offline: a map placed by
    the fixes, reusable)."""
    require_ros()
    import dataclasses

    from semslam.dataset import write_vehicle_toml
    from semslam.dataset.rosbag_write import topic_map_of, write_bag
    from semslam.recognition import load_database
    from semslam.recognition.storage import save_database
    from semslam.run.dive import run_dive
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset
    from semslam.simulation.builtin_db import builtin_database
    from semslam.simulation.config import ScannerConfig

    d = tmp_path_factory.mktemp("dive_gps")
    cfg = SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1), scanner=ScannerConfig(n_lines=200,
                                                                                                  points_per_line=200))
    cfg = cfg.replace(fixes=dataclasses.replace(cfg.fixes, gps_count=5))
    mission = simulate_dataset(cfg, seed=4)
    files = {"bag": write_bag(mission, d / "dive.bag", "ros1"), "topics": d / "topics.toml",
             "vehicle": d / "vehicle.toml", "db": d / "objects.npz"}
    files["topics"].write_text(topic_map_of(mission).to_toml(), encoding="utf-8")
    write_vehicle_toml(mission.vehicle, files["vehicle"])
    save_database(builtin_database(seed=0), files["db"])
    (d / "dive1").mkdir()
    run_dive(files["bag"], d / "dive1", db=load_database(files["db"]), modes=("pose",), topics=files["topics"],
             vehicle=files["vehicle"])
    files["prior"] = d / "dive1" / "slam" / "pose" / "map.json"
    return files


def test_node_stopped_mid_dive_with_gps_a_prior_map_and_a_silent_topic_writes_a_complete_run(dive_with_gps, tmp_path):
    """The node on a dive with GPS fixes before it, given dive 1's map (``--prior-map``) and a topic map naming a
    USBL topic nothing publishes, stopped with SIGINT while ``rosbag play`` is still playing: /diagnostics names
    the silent topic (WARN) while odometry goes on being published; the run directory written at SIGINT is
    complete, started from the GPS fix, its trajectory the offline run's with the same prior map up to where it
    stopped (within 5 cm), its map the prior map's landmarks (none duplicated)."""
    import csv

    from semslam.dataset.rosbag import read_topic_map
    from semslam.io.ros import open_bag
    from semslam.recognition import load_database
    from semslam.run.dive import run_dive
    from semslam.slam.survey import read_survey

    dive, prior = dive_with_gps, dive_with_gps["prior"]
    ref_dir = tmp_path / "offline_prior"
    ref_dir.mkdir()
    run_dive(dive["bag"], ref_dir, db=load_database(dive["db"]), modes=("pose",), topics=dive["topics"],
             vehicle=dive["vehicle"], survey=read_survey(prior), export=False)
    ref = list(csv.DictReader(open(ref_dir / "slam" / "pose" / "trajectory.csv", encoding="utf-8")))
    rs = np.array([float(r["stamp_s"]) for r in ref])
    rp = np.array([[float(r[k]) for k in ("x_m", "y_m", "z_m")] for r in ref])
    tmap = read_topic_map(dive["topics"])
    assert tmap.gps is not None and tmap.usbl is None
    topics = tmp_path / "topics_usbl.toml"
    topics.write_text(tmap.to_toml().replace("[topics]\n", '[topics]\nusbl = "/usbl/fix"\n'), encoding="utf-8")
    assert read_topic_map(topics).usbl == "/usbl/fix"

    run = tmp_path / "run"
    with roscore(tmp_path) as env:
        uri = env["ROS_MASTER_URI"]
        node_cmd = [sys.executable, "-m", "semslam.run.ros1.node", "--db", str(dive["db"]), "--topics", str(topics),
                    "--vehicle", str(dive["vehicle"]), "--mode", "pose", "--out", str(run), "--prior-map", str(prior),
                    "--scan-queue", "all", "--max-hold", "1000", "--window", "4.5", "--silent-after", "2"]
        with started(node_cmd, env, tmp_path / "node.log") as node:
            _wait(lambda: _node_up(uri, "/semslam") and _subscribed(uri, "/semslam/scans"), 60, "the node",
                  tmp_path / "node.log")
            with started([*_recorder(), "-O", str(tmp_path / "out.bag"), "/diagnostics", "/semslam/odometry"], env,
                         tmp_path / "record.log", stop_timeout_s=60.0) as rec:
                _wait(lambda: _subscribed(uri, "/semslam/odometry"), 30, "rosbag record", tmp_path / "record.log")
                with started(["rosbag", "play", "-q", "-r", "1", str(dive["bag"])], env, tmp_path / "play.log") as play:
                    time.sleep(rs[0] + 10.0)  # the fixes at the surface, then about half of the 24 s dive
                    assert play.poll() is None, "rosbag play ended before the node was stopped"
                    stop(node, timeout=60.0)  # Ctrl-C mid-dive
                    assert node.returncode == 0, (tmp_path / "node.log").read_text()[-3000:]
            assert rec.poll() is not None
    # diagnostics: the silent USBL topic named (WARN), and odometry published after that warning
    warned_at, last_odometry = None, None
    with open_bag(tmp_path / "out.bag") as b:
        for m in b.messages(["/diagnostics", "/semslam/odometry"]):
            if m.topic == "/diagnostics":
                st = m.msg.status[0]
                if warned_at is None and st.level == 1 and "/usbl/fix" in st.message:
                    warned_at = m.stamp_ns
                    assert "no message for 2 s" in st.message
            else:
                last_odometry = m.stamp_ns
    assert warned_at is not None, "no diagnostics named the silent USBL topic"
    assert last_odometry is not None and last_odometry > warned_at + 10**9  # the node went on publishing
    # the run directory written at SIGINT: complete, the offline run with the prior map up to the stop
    for f in ("run.json", "detections.jsonl", "ros_node.json", "slam/pose/trajectory.csv",
              "slam/pose/map.json", "slam/pose/landmarks.csv"):
        assert (run / f).is_file(), f
    doc = json.loads((run / "run.json").read_text())
    assert doc["source"]["source"]["prior_map"] == str(prior) and doc["verdict"] in ("ok", "warning")
    assert "position fix" in doc["start"]["sources"]["horizontal"]
    rows = list(csv.DictReader(open(run / "slam" / "pose" / "trajectory.csv", encoding="utf-8")))
    ts = np.array([float(r["stamp_s"]) for r in rows])
    p = np.array([[float(r[k]) for k in ("x_m", "y_m", "z_m")] for r in rows])
    assert rs[0] + 5.0 < ts[-1] < rs[-1] - 3.0, f"stopped at {ts[-1]:.1f} s of a {rs[0]:.1f}-{rs[-1]:.1f} s dive"
    ref_p = np.stack([np.interp(ts, rs, rp[:, i]) for i in range(3)], axis=1)
    err = np.linalg.norm(p - ref_p, axis=1)
    assert err.max() < 0.05, f"trajectory off the offline run with the prior map by up to {err.max():.3f} m"
    n_prior = len(json.loads(prior.read_text())["landmarks"])
    assert n_prior >= 1
    assert len(json.loads((run / "slam" / "pose" / "map.json").read_text())["landmarks"]) == n_prior
