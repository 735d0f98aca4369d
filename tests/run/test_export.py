"""Standard results out (issue 14): TUM, KITTI, the map as JSON / CSV / PLY and a ROS 2 mcap bag, each read back
and compared with the SlamResult it came from, in semslam's frames and in ROS's (REP-103/105); the export's file
names, headers, keyword-only options, argument checks and directories (``semslam/run/export.py``)."""

from __future__ import annotations

import csv
import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import plyfile
import pytest

from semslam.errors import InputError, SlamError
from semslam.geometry import RigidTransform, rotation_from_quat_wxyz, rotation_from_rpy
from semslam.io import read_point_cloud
from semslam.io.ros import (
    C_NED_ENU,
    open_bag,
    quat_xyzw_from_R_world_ned_vehicle_frd,
    R_world_enu_vehicle_flu_from_R_world_ned_vehicle_frd,
    vectors_enu_from_ned,
)
from semslam.run.export import (
    export_run,
    FORMATS,
    kitti_times_path,
    write_kitti,
    write_landmarks_csv,
    write_landmarks_json,
    write_landmarks_ply,
    write_tum,
)
from semslam.run.export_mcap import write_mcap
from semslam.slam import SlamConfig, SlamResult


@pytest.fixture(scope="module")
def run():
    """A one-loop square mission, pose SLAM with truth-based detections (seeded): 101 epochs, 4 landmarks."""
    from semslam.simulation.synthetic import square_dataset
    from semslam.simulation.detections import simulate_detections
    from semslam.simulation.truth_slam import builtin_symmetries, run_truth_slam, truth_detection_config

    mission = square_dataset(seed=1, loops=1)
    result = run_truth_slam(mission, mode="pose", seed=1)
    dets = simulate_detections(mission, truth_detection_config(mission), seed=1, symmetries=builtin_symmetries())
    assert result.attitude_rpy_rad is not None and result.smoothed_position_ned_m is not None
    assert len(result.landmarks) >= 3 and sum(map(len, dets.values())) > 10
    return mission, result, dets


def _tiny_result(rpy, positions=None) -> SlamResult:
    rpy = np.asarray(rpy, dtype=float).reshape(-1, 3)
    k = len(rpy)
    pos = np.arange(3.0 * k).reshape(k, 3) if positions is None else np.asarray(positions, dtype=float)
    cov = np.tile(np.diag([1e-4, 4e-4, 9e-4]), (k, 1, 1))
    return SlamResult(mode="pose", stamps_s=np.arange(k) * 0.5, position_ned_m=pos, position_cov_m2=cov,
                      velocity_body_mps=np.zeros((k, 3)), velocity_cov=cov.copy(), yaw_bias_rad=np.zeros(k),
                      truth_position_ned_m=None, landmarks=[], update_log=[], metrics={}, config=SlamConfig(),
                      attitude_rpy_rad=rpy)


def _read_tum(path: Path) -> np.ndarray:
    data = np.loadtxt(path, comments="#")
    assert data.ndim == 2 and data.shape[1] == 8
    return data


def _R_xyzw(q) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    assert abs(np.linalg.norm(q) - 1.0) < 1e-9
    return rotation_from_quat_wxyz(q[[3, 0, 1, 2]])


# -- TUM -------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("smoothed", [False, True])
def test_tum_round_trip_ned(run, tmp_path: Path, smoothed: bool) -> None:
    _, r, _ = run
    out = write_tum(r, tmp_path / "t.tum", smoothed=smoothed)
    assert out == tmp_path / "t.tum" and out.read_text().startswith("# semslam")
    d = _read_tum(out)
    assert len(d) == len(r.stamps_s)
    np.testing.assert_allclose(d[:, 0], r.stamps_s, atol=1e-9, rtol=0)
    want = r.smoothed_position_ned_m if smoothed else r.position_ned_m
    np.testing.assert_allclose(d[:, 1:4], want, atol=1e-9, rtol=0)
    assert (d[:, 7] >= 0).all()
    for row, rpy in zip(d, r.attitude_rpy_rad):
        np.testing.assert_allclose(_R_xyzw(row[4:]), rotation_from_rpy(*rpy), atol=1e-10)


def test_tum_enu_is_the_frames_modules_conversion(run, tmp_path: Path) -> None:
    _, r, _ = run
    ned = _read_tum(write_tum(r, tmp_path / "ned.tum"))
    enu = _read_tum(write_tum(r, tmp_path / "enu.tum", frame="enu"))
    np.testing.assert_allclose(enu[:, 0], ned[:, 0])
    np.testing.assert_allclose(enu[:, 1:4], vectors_enu_from_ned(r.position_ned_m), atol=1e-9, rtol=0)
    for row_e, row_n in zip(enu, ned):
        want = quat_xyzw_from_R_world_ned_vehicle_frd(_R_xyzw(row_n[4:]))
        assert min(np.abs(row_e[4:] - want).max(), np.abs(row_e[4:] + want).max()) < 1e-10
        np.testing.assert_allclose(_R_xyzw(row_e[4:]), R_world_enu_vehicle_flu_from_R_world_ned_vehicle_frd(
            _R_xyzw(row_n[4:])), atol=1e-10)


def test_tum_enu_known_headings(tmp_path: Path) -> None:
    """REP-103: a level vehicle facing east (semslam yaw +90 deg) has the identity orientation in ENU/FLU; facing
    north (yaw 0) it is yawed +90 deg about ENU's up axis. North 1 m, east 2 m, depth 3 m -> ENU (2, 1, -3)."""
    r = _tiny_result([[0, 0, np.pi / 2], [0, 0, 0]], positions=[[1, 2, 3], [1, 2, 3]])
    d = _read_tum(write_tum(r, tmp_path / "e.tum", frame="enu"))
    np.testing.assert_allclose(d[:, 1:4], [[2, 1, -3], [2, 1, -3]], atol=1e-12)
    np.testing.assert_allclose(d[0, 4:], [0, 0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(d[1, 4:], [0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)], atol=1e-12)


def test_tum_reads_in_evo(run, tmp_path: Path) -> None:
    file_interface = pytest.importorskip("evo.tools.file_interface")  # optional (GPL-3), never a dependency
    _, r, _ = run
    traj = file_interface.read_tum_trajectory_file(str(write_tum(r, tmp_path / "t.tum")))
    assert traj.num_poses == len(r.stamps_s)
    np.testing.assert_allclose(traj.positions_xyz, r.position_ned_m, atol=1e-9)


# -- KITTI -----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("frame", ["ned", "enu"])
def test_kitti_poses_and_times(run, tmp_path: Path, frame: str) -> None:
    _, r, _ = run
    poses, times = write_kitti(r, tmp_path / "traj.kitti", frame=frame)
    assert times == kitti_times_path(poses) == tmp_path / "traj.times.txt"
    rows = np.loadtxt(poses)
    assert rows.shape == (len(r.stamps_s), 12)
    np.testing.assert_allclose(np.loadtxt(times), r.stamps_s, atol=1e-9, rtol=0)
    for row, p, rpy in zip(rows, r.position_ned_m, r.attitude_rpy_rad):
        M = row.reshape(3, 4)
        R, t = M[:, :3], M[:, 3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-10)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-10)
        R_ned = rotation_from_rpy(*rpy)
        if frame == "ned":
            np.testing.assert_allclose(R, R_ned, atol=1e-11)
            np.testing.assert_allclose(t, p, atol=1e-10)
        else:
            np.testing.assert_allclose(R, R_world_enu_vehicle_flu_from_R_world_ned_vehicle_frd(R_ned), atol=1e-11)
            np.testing.assert_allclose(t, vectors_enu_from_ned(p), atol=1e-10)


def test_kitti_times_path_argument(run, tmp_path: Path) -> None:
    _, r, _ = run
    poses, times = write_kitti(r, tmp_path / "00.txt", smoothed=True, times_path=tmp_path / "times.txt")
    assert times == tmp_path / "times.txt" and len(times.read_text().splitlines()) == len(r.stamps_s)
    np.testing.assert_allclose(np.loadtxt(poses)[:, [3, 7, 11]], r.smoothed_position_ned_m, atol=1e-10)
    with pytest.raises(InputError, match=r"The 'times_path' argument of write_kitti must differ from 'path'"):
        write_kitti(r, tmp_path / "a.txt", times_path=tmp_path / "a.txt")


# -- the map ---------------------------------------------------------------------------------------------------
def test_landmarks_json(run, tmp_path: Path) -> None:
    _, r, _ = run
    text = write_landmarks_json(r, tmp_path / "map.json").read_text()

    def no_nan(name: str):
        raise AssertionError(f"non-standard JSON constant {name}")

    doc = json.loads(text, parse_constant=no_nan)
    assert doc["format"] == "semslam-map" and doc["format_version"] == 2
    assert doc["covariance_order"] == ["x", "y", "z", "roll", "pitch", "yaw"]
    assert len(doc["landmarks"]) == len(r.landmarks)
    assert doc["classes"] == {label: i for i, label in enumerate(sorted({lm.label for lm in r.landmarks}))}
    for rec, lm in zip(doc["landmarks"], r.landmarks):
        cov = np.array(rec["covariance_6x6"])
        assert cov.shape == (6, 6)
        np.testing.assert_array_equal(cov, cov.T)
        np.testing.assert_array_equal(cov, lm.covariance_6x6)
        assert (rec["landmark_id"], rec["label"], rec["name"], rec["n_updates"]) == (
            lm.landmark_id, lm.label, lm.name, lm.n_updates)
        assert rec["first_seen_s"] == lm.first_seen_s and rec["last_seen_s"] == lm.last_seen_s
        np.testing.assert_array_equal(rec["position_ned_m"], lm.pose_xyzrpy[:3])
        np.testing.assert_allclose(rotation_from_quat_wxyz(rec["quat_wxyz"]), rotation_from_rpy(*lm.pose_xyzrpy[3:]),
                                   atol=1e-12)
        assert rec["quat_wxyz"][0] >= 0


def test_landmarks_csv(run, tmp_path: Path) -> None:
    _, r, _ = run
    with open(write_landmarks_csv(r, tmp_path / "map.csv"), newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(r.landmarks)
    axes = ["x", "y", "z", "roll", "pitch", "yaw"]
    for row, lm in zip(rows, r.landmarks):
        cov = np.array([[float(row[f"cov_{a}_{b}"]) for b in axes] for a in axes])
        np.testing.assert_array_equal(cov, lm.covariance_6x6)  # 17 significant digits: exact
        assert int(row["landmark_id"]) == lm.landmark_id and row["label"] == lm.label
        np.testing.assert_array_equal([float(row[k]) for k in ("x_m", "y_m", "z_m")], lm.pose_xyzrpy[:3])
        q = [float(row[k]) for k in ("qw", "qx", "qy", "qz")]
        np.testing.assert_allclose(rotation_from_quat_wxyz(q), rotation_from_rpy(*lm.pose_xyzrpy[3:]), atol=1e-12)


def test_landmarks_ply_reads_back(run, tmp_path: Path) -> None:
    _, r, _ = run
    path = write_landmarks_ply(r, tmp_path / "map.ply")
    ply = plyfile.PlyData.read(str(path))
    v = ply["vertex"].data
    assert v.dtype["x"] == np.float64 and len(v) == len(r.landmarks)
    classes = {int(c.split()[1]): c.split()[2] for c in ply.comments if c.startswith("class ")}
    for row, lm in zip(v, r.landmarks):
        np.testing.assert_array_equal([row["x"], row["y"], row["z"]], lm.pose_xyzrpy[:3])
        assert classes[int(row["class_index"])] == lm.label and int(row["landmark_id"]) == lm.landmark_id
    cloud = read_point_cloud(path)
    np.testing.assert_array_equal(cloud.points_xyz_m, np.array([lm.pose_xyzrpy[:3] for lm in r.landmarks]))
    assert cloud.fields["landmark_id"].tolist() == [lm.landmark_id for lm in r.landmarks]


# -- mcap ------------------------------------------------------------------------------------------------------
def _messages(path: Path) -> tuple[dict, dict]:
    with open_bag(path) as bag:
        records = {rec.topic: rec for rec in bag.topics()}
        by_topic: dict = {}
        for m in bag.messages():
            by_topic.setdefault(m.topic, []).append(m)
    return records, by_topic


def _q(msg) -> np.ndarray:
    return np.array([msg.x, msg.y, msg.z, msg.w])


def test_mcap_topics_poses_path_and_markers(run, tmp_path: Path) -> None:
    _, r, _ = run
    path = write_mcap(r, tmp_path / "run.mcap")
    assert path.is_file() and sorted(os.listdir(tmp_path)) == ["run.mcap"]  # one file, no temporary left
    records, msgs = _messages(path)
    k = len(r.stamps_s)
    want = {"/semslam/pose": ("geometry_msgs/msg/PoseWithCovarianceStamped", k), "/tf": ("tf2_msgs/msg/TFMessage", k),
            "/semslam/path": ("nav_msgs/msg/Path", 1), "/semslam/path_smoothed": ("nav_msgs/msg/Path", 1),
            "/semslam/landmarks": ("visualization_msgs/msg/MarkerArray", 1)}
    assert {t: (rec.msgtype, rec.count) for t, rec in records.items()} == want

    C = C_NED_ENU
    for j in (0, k // 2, k - 1):
        m = msgs["/semslam/pose"][j]
        assert m.stamp_ns == round(r.stamps_s[j] * 1e9) and m.msg.header.frame_id == "map"
        p = m.msg.pose.pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], vectors_enu_from_ned(r.position_ned_m[j]), atol=1e-12)
        q = _q(m.msg.pose.pose.orientation)
        np.testing.assert_allclose(_R_xyzw(q), C @ rotation_from_rpy(*r.attitude_rpy_rad[j]) @ np.diag([1, -1, -1]),
                                   atol=1e-10)
        cov = m.msg.pose.covariance.reshape(6, 6)
        np.testing.assert_allclose(cov[:3, :3], C @ r.position_cov_m2[j] @ C.T, rtol=1e-12, atol=0)
        assert not cov[3:].any() and not cov[:, 3:].any()  # orientation: not estimated (documented)
        tf = msgs["/tf"][j].msg.transforms[0]
        assert (tf.header.frame_id, tf.child_frame_id) == ("map", "base_link")
        np.testing.assert_allclose(_q(tf.transform.rotation), q)

    path_msg = msgs["/semslam/path"][0].msg
    assert len(path_msg.poses) == k
    got = np.array([[ps.pose.position.x, ps.pose.position.y, ps.pose.position.z] for ps in path_msg.poses])
    np.testing.assert_allclose(got, vectors_enu_from_ned(r.position_ned_m), atol=1e-12)
    sm = msgs["/semslam/path_smoothed"][0].msg
    np.testing.assert_allclose([sm.poses[3].pose.position.x, sm.poses[3].pose.position.y, sm.poses[3].pose.position.z],
                               vectors_enu_from_ned(r.smoothed_position_ned_m[3]), atol=1e-12)

    markers = msgs["/semslam/landmarks"][0].msg.markers
    spheres = [mk for mk in markers if mk.type == 2]
    texts = [mk for mk in markers if mk.type == 9]
    assert len(spheres) == len(texts) == len(r.landmarks)
    for sphere, text, lm in zip(spheres, texts, r.landmarks):
        assert sphere.id == lm.landmark_id and sphere.header.frame_id == "map" and lm.label in text.text
        pos = sphere.pose.position
        np.testing.assert_allclose([pos.x, pos.y, pos.z], vectors_enu_from_ned(lm.pose_xyzrpy[:3]), atol=1e-12)
        sigma3 = 6 * np.sqrt(np.linalg.eigvalsh(lm.covariance_6x6[:3, :3]))
        np.testing.assert_allclose(sorted([sphere.scale.x, sphere.scale.y, sphere.scale.z]),
                                   np.maximum(sorted(sigma3), 1e-3), rtol=1e-9)
        # the ellipsoid's axes are the ENU position covariance's eigenvectors
        V = _R_xyzw(_q(sphere.pose.orientation))
        P = C @ lm.covariance_6x6[:3, :3] @ C.T
        D = V.T @ P @ V
        np.testing.assert_allclose(D - np.diag(np.diag(D)), 0, atol=1e-12 * np.abs(P).max())


def test_mcap_detections_land_on_the_map(run, tmp_path: Path) -> None:
    mission, r, dets = run
    T_vs = mission.vehicle.scanner.T_vehicle_scanner
    path = write_mcap(r, tmp_path / "bag", detections_by_scan=dets, T_vehicle_scanner=T_vs, smoothed=False,
                      time_origin_ns=1_700_000_000 * 10**9)
    assert sorted(p.name for p in path.iterdir()) == ["bag.mcap", "metadata.yaml"]  # a rosbag2 directory
    records, msgs = _messages(path)
    assert "/semslam/path_smoothed" not in records
    assert records["/semslam/detections"].msgtype == "geometry_msgs/msg/PoseArray"
    in_span = {s: [d for d in v if r.stamps_s[0] <= d.stamp_s <= r.stamps_s[-1]] for s, v in dets.items()}
    assert records["/semslam/detections"].count == sum(1 for v in in_span.values() if v) > 10
    assert msgs["/semslam/pose"][0].stamp_ns == 1_700_000_000 * 10**9 + round(r.stamps_s[0] * 1e9)
    lm_enu = vectors_enu_from_ned(np.array([lm.pose_xyzrpy[:3] for lm in r.landmarks]))
    for m in msgs["/semslam/detections"]:
        for pose in m.msg.poses:
            p = np.array([pose.position.x, pose.position.y, pose.position.z])
            assert np.linalg.norm(lm_enu - p, axis=1).min() < 0.1  # every detection sits on a mapped object
    # one detection by hand, at an epoch (no interpolation): T_world_vehicle @ T_vehicle_scanner @ T_sensor_object
    scan, k = next((s, int(np.flatnonzero(np.isclose(r.stamps_s, v[0].stamp_s))[0])) for s, v in sorted(in_span.items())
                   if v and np.isclose(r.stamps_s, v[0].stamp_s).any())
    det = in_span[scan][0]
    T_wv = RigidTransform.from_xyz_rpy(r.position_ned_m[k], r.attitude_rpy_rad[k])
    T_wo = T_wv @ T_vs @ det.T_sensor_object
    m = next(m for m in msgs["/semslam/detections"] if m.msg.header.stamp.sec == 1_700_000_000 + int(det.stamp_s)
             and m.msg.header.stamp.nanosec == round(det.stamp_s * 1e9) % 10**9)
    pose = m.msg.poses[0]
    np.testing.assert_allclose([pose.position.x, pose.position.y, pose.position.z],
                               vectors_enu_from_ned(T_wo.translation_m), atol=1e-9)
    np.testing.assert_allclose(_R_xyzw(_q(pose.orientation)), C_NED_ENU @ T_wo.rotation, atol=1e-9)
    # rewriting a bag directory replaces it
    write_mcap(r, path, smoothed=False)
    assert "/semslam/detections" not in _messages(path)[0]


def test_mcap_orientation_variance(tmp_path: Path) -> None:
    r = _tiny_result([[0.1, 0.2, 0.3]] * 3)
    _, msgs = _messages(write_mcap(r, tmp_path / "t.mcap", orientation_variance_rad2=[1e-5, 2e-5, 3e-4]))
    cov = msgs["/semslam/pose"][1].msg.pose.covariance.reshape(6, 6)
    np.testing.assert_allclose(np.diag(cov), [4e-4, 1e-4, 9e-4, 1e-5, 2e-5, 3e-4])  # NED y (east) -> ENU x
    assert msgs["/semslam/landmarks"][0].msg.markers == []


def test_mcap_interrupted_write_leaves_nothing(run, tmp_path: Path, monkeypatch) -> None:
    from rosbags.rosbag2 import Writer

    _, r, _ = run
    target = tmp_path / "run.mcap"
    real_write, calls = Writer.write, []

    def failing_write(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 50:
            raise KeyboardInterrupt("interrupted")
        return real_write(self, *args, **kwargs)

    monkeypatch.setattr(Writer, "write", failing_write)
    for out in (target, tmp_path / "bagdir"):  # single file and bag directory
        calls.clear()
        with pytest.raises(KeyboardInterrupt):
            write_mcap(r, out)
        assert len(calls) == 50 and os.listdir(tmp_path) == []
    monkeypatch.setattr(Writer, "write", real_write)
    before = write_mcap(r, target, smoothed=False).read_bytes()
    monkeypatch.setattr(Writer, "write", failing_write)
    calls.clear()
    with pytest.raises(KeyboardInterrupt):
        write_mcap(r, target)  # a failed rewrite keeps the previous file whole
    assert target.read_bytes() == before and os.listdir(tmp_path) == ["run.mcap"]


def test_ply_and_tum_interrupted_writes_leave_nothing(run, tmp_path: Path, monkeypatch) -> None:
    _, r, _ = run

    def half_write(self, stream):
        stream.write(b"ply\nformat binary_little_endian 1.0\n")
        raise OSError("disk full")

    monkeypatch.setattr(plyfile.PlyData, "write", half_write)
    with pytest.raises(OSError, match="disk full"):
        write_landmarks_ply(r, tmp_path / "map.ply")
    import semslam.run.export as export

    calls = []

    def failing_quat(R):
        calls.append(1)
        if len(calls) > 5:
            raise RuntimeError("interrupted")
        return np.array([1.0, 0, 0, 0])

    monkeypatch.setattr(export, "quat_wxyz_from_rotation", failing_quat)
    with pytest.raises(RuntimeError):
        write_tum(r, tmp_path / "t.tum")
    assert os.listdir(tmp_path) == []


# -- export_run and bad input ----------------------------------------------------------------------------------
def test_export_run_writes_every_format(run, tmp_path: Path) -> None:
    _, r, _ = run
    written = export_run(r, tmp_path / "out")
    names = sorted(p.name for p in written)
    assert names == sorted(["trajectory.tum", "trajectory_smoothed.tum", "trajectory.kitti", "trajectory.times.txt",
                            "trajectory_smoothed.kitti", "trajectory_smoothed.times.txt", "map.json", "map.csv",
                            "map.ply", "run.mcap"])
    assert sorted(os.listdir(tmp_path / "out")) == names and all(p.stat().st_size > 0 for p in written)
    only = export_run(replace(r, attitude_rpy_rad=None), tmp_path / "map_only", formats="landmarks")
    assert [p.name for p in only] == ["map.json", "map.csv", "map.ply"]
    tum = export_run(r, tmp_path / "enu", formats=["tum"], frame="enu", smoothed=False)
    assert [p.name for p in tum] == ["trajectory.tum"]
    np.testing.assert_allclose(_read_tum(tum[0])[:, 1:4], vectors_enu_from_ned(r.position_ned_m), atol=1e-9)
    assert FORMATS == ("tum", "kitti", "landmarks", "mcap")


def test_bad_inputs(run, tmp_path: Path) -> None:
    _, r, _ = run
    no_att = replace(r, attitude_rpy_rad=None)
    no_smooth = replace(r, smoothed_position_ned_m=None)
    with pytest.raises(InputError, match=r"^The 'formats' argument of export_run must name one or more of "
                                         r"\('tum', 'kitti', 'landmarks', 'mcap'\)\. Got 'ply' instead\.$"):
        export_run(r, tmp_path / "x", formats=["tum", "ply"])
    with pytest.raises(SlamError, match=r"The 'result' argument of export_run must have an attitude "
                                        r"\(attitude_rpy_rad.*Got none instead"):
        export_run(no_att, tmp_path / "y")
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()  # checked before anything is written
    for fn in (write_tum, write_kitti, write_mcap):
        with pytest.raises(SlamError, match=rf"The 'result' argument of {fn.__name__} must have an attitude"):
            fn(no_att, tmp_path / "z.mcap")
    (tmp_path / "d.tum").mkdir()
    (tmp_path / "d.mcap").mkdir()
    with pytest.raises(InputError, match=r"The 'path' argument of write_tum must be a file path\. Got the directory"):
        write_tum(r, tmp_path / "d.tum")
    with pytest.raises(InputError, match=r"The 'path' argument of write_landmarks_ply must be a file path"):
        write_landmarks_ply(r, tmp_path)
    with pytest.raises(InputError, match=r"The 'path' argument of write_mcap must be a file path .*Got the directory"):
        write_mcap(r, tmp_path / "d.mcap")
    (tmp_path / "notabag").mkdir()
    (tmp_path / "notabag" / "keep.txt").write_text("mine")
    with pytest.raises(InputError, match=r"The 'path' argument of write_mcap must be .*that is not a bag"):
        write_mcap(r, tmp_path / "notabag")
    assert (tmp_path / "notabag" / "keep.txt").read_text() == "mine"
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match=r"The 'out_dir' argument of export_run must be a directory\. Got the file"):
        export_run(r, tmp_path / "file")
    with pytest.raises(SlamError, match=r"The 'smoothed' argument of write_tum .*has none"):
        write_tum(no_smooth, tmp_path / "s.tum", smoothed=True)
    with pytest.raises(InputError, match=r"The 'frame' argument of write_kitti must be one of \('ned', 'enu'\)\. "
                                         r"Got 'nwu' instead\."):
        write_kitti(r, tmp_path / "k.kitti", frame="nwu")
    with pytest.raises(InputError, match=r"The 'T_vehicle_scanner' argument of write_mcap must be given with"):
        write_mcap(r, tmp_path / "a.mcap", detections_by_scan={})
    with pytest.raises(InputError, match=r"The 'orientation_variance_rad2' argument of write_mcap must be 3 finite"):
        write_mcap(r, tmp_path / "a.mcap", orientation_variance_rad2=[1.0, -1.0, 0.0])
    with pytest.raises(InputError, match=r"The keyword arguments of export_run must be options of write_mcap "
                                         r"\(frame_id, .*\)\. Got 'frame_idd' instead\."):
        export_run(r, tmp_path / "w", frame_idd="odom")
    with pytest.raises(InputError, match=r"The 'result' argument of write_landmarks_json must be a "
                                         r"semslam\.slam\.SlamResult\. Got dict instead\."):
        write_landmarks_json({}, tmp_path / "m.json")
    assert not any((tmp_path / n).exists() for n in ("z.mcap", "s.tum", "k.kitti", "a.mcap", "m.json", "w"))


def test_export_into_an_existing_directory(tmp_path: Path):
    """Catches ``mkdir(exist_ok=False)``: exporting into a directory that already exists (a run directory, or a
    second export of the same run) writes the files there instead of failing, and a re-export overwrites them
    with the same content."""
    k = 4
    cov = np.tile(np.diag([1e-4, 4e-4, 9e-4]), (k, 1, 1))
    res = SlamResult(mode="pose", stamps_s=np.arange(k) * 0.5, position_ned_m=np.arange(3.0 * k).reshape(k, 3),
                     position_cov_m2=cov, velocity_body_mps=np.zeros((k, 3)), velocity_cov=cov.copy(),
                     yaw_bias_rad=np.zeros(k), truth_position_ned_m=None, landmarks=[], update_log=[], metrics={},
                     config=SlamConfig(), attitude_rpy_rad=np.zeros((k, 3)))
    out = tmp_path / "run"
    out.mkdir()
    first = export_run(res, out, formats=("tum",))
    assert [p.name for p in first] == ["trajectory.tum"] and first[0].parent == out
    text = first[0].read_text()
    assert len([ln for ln in text.splitlines() if ln and not ln.startswith("#")]) == k
    again = export_run(res, out, formats=("tum",))
    assert again == first and again[0].read_text() == text


def _smoothed_result(k=4):
    cov = np.tile(np.diag([1e-4, 4e-4, 9e-4]), (k, 1, 1))
    pos = np.arange(3.0 * k).reshape(k, 3)
    return SlamResult(mode="pose", stamps_s=np.arange(k) * 0.5, position_ned_m=pos, position_cov_m2=cov,
                      velocity_body_mps=np.zeros((k, 3)), velocity_cov=cov.copy(), yaw_bias_rad=np.zeros(k),
                      truth_position_ned_m=None, landmarks=[], update_log=[], metrics={}, config=SlamConfig(),
                      attitude_rpy_rad=np.zeros((k, 3)), smoothed_position_ned_m=pos + 100.0,
                      smoothed_position_cov_m2=cov.copy())


def _kitti_positions(path: Path) -> np.ndarray:
    return np.loadtxt(path).reshape(-1, 3, 4)[:, :, 3]


def test_export_names_the_smoothed_kitti_files_after_their_content(tmp_path: Path):
    """Catches swapped KITTI file names in ``export_run`` (``'_smoothed' if not s``): ``trajectory.kitti`` holds the
    online positions and ``trajectory_smoothed.kitti`` the smoothed ones (here offset by 100 m), as documented."""
    res = _smoothed_result()
    written = export_run(res, tmp_path, formats=("kitti",), smoothed=True)
    names = sorted(p.name for p in written)
    assert names == ["trajectory.kitti", "trajectory.times.txt", "trajectory_smoothed.kitti",
                     "trajectory_smoothed.times.txt"]
    np.testing.assert_allclose(_kitti_positions(tmp_path / "trajectory.kitti"), res.position_ned_m, atol=1e-9)
    np.testing.assert_allclose(_kitti_positions(tmp_path / "trajectory_smoothed.kitti"), res.smoothed_position_ned_m,
                               atol=1e-9)


def test_tum_header_names_the_body_frame_of_the_world_frame(tmp_path: Path):
    """Catches an inverted body-frame label in the TUM header (``"FLU" if not frame == "enu"``): NED files are
    ``T_world_vehicle`` with an FRD body, ENU files with an FLU body (the module's frame convention)."""
    from semslam.run.export import write_tum

    res = _smoothed_result()
    ned = write_tum(res, tmp_path / "ned.tum").read_text().splitlines()[0]
    enu = write_tum(res, tmp_path / "enu.tum", frame="enu").read_text().splitlines()[0]
    assert "world NED, body FRD" in ned
    assert "world ENU, body FLU" in enu


def test_write_kitti_takes_its_paths_by_keyword_and_its_options_by_keyword_only(tmp_path: Path):
    """Catches a positional-only marker (``/``) in place of the keyword-only one (``*``) in ``write_kitti``'s
    signature: ``path`` may be given by name, and ``smoothed`` / ``frame`` must not be accepted positionally (a
    stray positional ``True`` would silently export the smoothed trajectory)."""
    import pytest

    from semslam.run.export import write_kitti

    res = _smoothed_result()
    poses, times = write_kitti(result=res, path=tmp_path / "a.kitti")
    assert poses.name == "a.kitti" and times.name == "a.times.txt"
    with pytest.raises(TypeError):
        write_kitti(res, tmp_path / "b.kitti", True)


def test_a_non_path_is_an_input_error_naming_the_argument(tmp_path: Path):
    """Catches a ``TypeError`` escaping the path check (its ``except TypeError`` never taken): a number given as
    the output path is an ``InputError`` naming the argument and the function."""
    import pytest

    from semslam.errors import InputError
    from semslam.run.export import write_kitti, write_tum

    res = _smoothed_result()
    with pytest.raises(InputError, match="The 'path' argument of write_tum must be a file path"):
        write_tum(res, 3)
    with pytest.raises(InputError, match="The 'times_path' argument of write_kitti must be a file path"):
        write_kitti(res, tmp_path / "a.kitti", times_path=3.5)


def test_export_creates_missing_parent_directories(tmp_path: Path):
    """Catches ``mkdir(parents=False)`` in ``export_run``: an output directory several levels below an existing one
    is created with its parents, and the files land in it."""
    out = tmp_path / "a" / "b" / "run"
    written = export_run(_smoothed_result(), out, formats=("tum",))
    assert [p.parent for p in written] == [out, out] and all(p.is_file() for p in written)
