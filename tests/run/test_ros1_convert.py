"""The ROS 1 node's border, without ROS: outgoing numbers in REP-105 frames (analytic cases), incoming raw ROS 1
bytes decoded like the bag reader, the reordering window and the keep-newest slot, and the live wiring giving the
offline filter's trajectory."""

from __future__ import annotations

import random
import threading

import numpy as np
import pytest

from semslam.errors import BagError, InputError
from semslam.geometry import rotation_from_quat_wxyz
from semslam.run.ros1.convert import ELLIPSOID_CHI2_3DOF, SPHERE, TEXT_VIEW_FACING, landmark_markers, odometry_spec
from semslam.run.ros1.timing import LatestSlot, ReorderBuffer
from semslam.slam.results import LandmarkEstimate


def _R_of(quat_xyzw):
    x, y, z, w = quat_xyzw
    return rotation_from_quat_wxyz([w, x, y, z])


def _odom(rpy=(0.0, 0.0, 0.0), p=(0.0, 0.0, 0.0), P=np.eye(3), v=(0.0, 0.0, 0.0), Pv=np.eye(3), att=None):
    return odometry_spec(1.5, p, P, rpy, att, v, Pv)


def test_heading_north_in_ned_is_facing_plus_y_in_enu():
    o = _odom(rpy=(0.0, 0.0, 0.0))
    np.testing.assert_allclose(_R_of(o.quat_xyzw) @ [1, 0, 0], [0, 1, 0], atol=1e-12)  # forward = north = +y ENU
    np.testing.assert_allclose(_R_of(o.quat_xyzw) @ [0, 1, 0], [-1, 0, 0], atol=1e-12)  # left = west = -x ENU
    o = _odom(rpy=(0.0, 0.0, np.pi / 2))  # heading east: ROS yaw 0, the identity
    np.testing.assert_allclose(_R_of(o.quat_xyzw), np.eye(3), atol=1e-12)


def test_nose_up_and_starboard_down_keep_their_meaning():
    o = _odom(rpy=(0.0, 0.3, 0.0))  # nose up 0.3 rad while heading north: forward gains +z (up) in ENU
    np.testing.assert_allclose(_R_of(o.quat_xyzw) @ [1, 0, 0], [0, np.cos(0.3), np.sin(0.3)], atol=1e-12)
    o = _odom(rpy=(0.2, 0.0, 0.0))  # starboard down: the left (FLU +y) side goes up
    left = _R_of(o.quat_xyzw) @ [0, 1, 0]
    assert left[2] == pytest.approx(np.sin(0.2))


def test_position_covariance_and_velocity_change_axes():
    P = np.array([[4.0, 0.5, 0.1], [0.5, 9.0, 0.2], [0.1, 0.2, 1.0]])  # NED
    att = np.diag([1e-4, 2e-4, 3e-4])  # world NED rotations
    o = _odom(p=(10.0, 20.0, 5.0), P=P, v=(1.0, 0.25, -0.1), Pv=np.diag([0.01, 0.02, 0.03]), att=att)
    np.testing.assert_allclose(o.position_enu_m, [20.0, 10.0, -5.0])  # east, north, up
    C = o.pose_covariance_6x6
    assert C[0, 0] == 9.0 and C[1, 1] == 4.0 and C[2, 2] == 1.0  # var(east), var(north), var(up)
    assert C[0, 1] == 0.5 and C[0, 2] == -0.2 and C[1, 2] == -0.1  # signs of the z flip
    np.testing.assert_allclose(np.diag(C)[3:], [2e-4, 1e-4, 3e-4])
    assert np.all(C[:3, 3:] == 0)
    np.testing.assert_allclose(o.velocity_flu_mps, [1.0, -0.25, 0.1])  # starboard -> left, down -> up
    np.testing.assert_allclose(np.diag(o.twist_covariance_6x6)[:3], [0.01, 0.02, 0.03])


def _landmark(j, label, p_ned, P_ned):
    cov = np.eye(6) * 1e-3
    cov[:3, :3] = P_ned
    return LandmarkEstimate(j, label, np.array([*p_ned, 0.0, 0.0, 0.0]), cov, 0.0, 1.0, 3)


def test_one_ellipsoid_and_one_text_per_landmark_with_stable_ids():
    P = np.diag([0.04, 0.01, 0.0025])  # sigma north 0.2, east 0.1, down 0.05
    lms = [_landmark(0, "ball_valve", (1.0, 2.0, 3.0), P), _landmark(1, "elbow", (0.0, 0.0, 1.0), P * 4)]
    specs = landmark_markers(lms)
    assert [(s.ns, s.id, s.type) for s in specs] == [("ball_valve", 0, SPHERE), ("ball_valve/text", 0, TEXT_VIEW_FACING),
                                                      ("elbow", 1, SPHERE), ("elbow/text", 1, TEXT_VIEW_FACING)]
    ell = specs[0]
    np.testing.assert_allclose(ell.position_enu_m, [2.0, 1.0, -3.0])
    # the ellipsoid's axes and half-lengths give back the ENU covariance at the 95 % quantile
    R = _R_of(ell.quat_xyzw)
    half = ell.scale / 2.0
    np.testing.assert_allclose(R @ np.diag(half ** 2 / ELLIPSOID_CHI2_3DOF) @ R.T, np.diag([0.01, 0.04, 0.0025]),
                               atol=1e-12)
    assert "ball_valve #0" in specs[1].text
    again = landmark_markers(lms)
    assert [(s.ns, s.id) for s in again] == [(s.ns, s.id) for s in specs]
    assert again[0].rgba == specs[0].rgba and specs[0].rgba != specs[2].rgba


# ---------------------------------------------------------------------------------------------- decoding
def _noetic():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC)


def _imu_bytes(store, quat_xyzw, stamp_ns):
    from semslam.io.ros._encode import ros_header

    T = store.types
    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    x, y, z, w = quat_xyzw
    msg = T["sensor_msgs/msg/Imu"](header=ros_header(store, stamp_ns, "imu"), orientation=Q(x=x, y=y, z=z, w=w),
                                   orientation_covariance=np.zeros(9), angular_velocity=V3(x=0.0, y=0.0, z=0.0),
                                   angular_velocity_covariance=np.zeros(9), linear_acceleration=V3(x=0.0, y=0.0, z=0.0),
                                   linear_acceleration_covariance=np.zeros(9))
    return bytes(store.serialize_ros1(msg, "sensor_msgs/msg/Imu"))


def test_raw_imu_bytes_decode_to_the_ned_attitude():
    from semslam.dataset import VehicleDescription
    from semslam.dataset.rosbag import TopicMap
    from semslam.run.ros1.decode import LiveDecoder

    store = _noetic()
    dec = LiveDecoder(TopicMap(attitude="/imu", depth="/p"), VehicleDescription.girona500())
    s = np.sin(np.pi / 4)
    md5 = store.generate_msgdef("sensor_msgs/msg/Imu")[1]
    m = dec.decode("/imu", "sensor_msgs/Imu", _imu_bytes(store, (0.0, 0.0, s, s), 1_700_000_000_250_000_000), md5sum=md5)
    assert m.kind == "attitude" and m.stamp_ns == 1_700_000_000_250_000_000
    np.testing.assert_allclose(m.payload, [0.0, 0.0, 0.0], atol=1e-12)  # ROS yaw +90 deg (north) = NED yaw 0


def test_a_mapped_topic_with_the_wrong_type_is_named():
    from semslam.dataset import VehicleDescription
    from semslam.dataset.rosbag import TopicMap
    from semslam.run.ros1.decode import LiveDecoder

    store = _noetic()
    dec = LiveDecoder(TopicMap(attitude="/imu", depth="/p"), VehicleDescription.girona500())
    with pytest.raises(BagError, match=r"Topic '/p' .*topics.depth.* Got sensor_msgs/msg/Imu"):
        dec.decode("/p", "sensor_msgs/Imu", _imu_bytes(store, (0, 0, 0, 1), 1))
    with pytest.raises(BagError, match="not in the topic map"):
        dec.check_type("/other", "sensor_msgs/Imu")
    with pytest.raises(BagError, match="cannot be decoded"):
        dec.decode("/imu", "sensor_msgs/Imu", b"\x00\x01")


def test_the_bag_readers_decoding_on_raw_bytes(ros1_bag):
    """Every mapped message of a bag, given as a subscriber gets it (bytes, type, md5, definition; a vendor DVL
    type known only from its definition), decodes to what the bag reader's stream gives."""
    from semslam.dataset.rosbag import stream_bag
    from semslam.io.ros import open_bag
    from semslam.run.ros1.decode import LiveDecoder
    from tests._support.ros1 import raw_bag_messages

    bag, tmap, vehicle = ros1_bag
    topics = [tmap.attitude, tmap.dvl, tmap.depth, tmap.scans]
    dec = LiveDecoder(tmap, vehicle)
    live = [dec.decode(t, ty, raw, md5sum=md5, definition=d, receive_ns=ns) for t, ty, md5, d, raw, ns
            in raw_bag_messages(bag, topics)]
    origin = []
    with open_bag(bag) as b:
        ref = list(stream_bag(b, tmap, vehicle, time_origin_ns=origin))
    assert len(live) == len(ref) and {m.kind for m in live} == {"attitude", "dvl", "depth", "scan"}
    for m, (t, kind, payload) in zip(live, ref):
        assert m.kind == kind and (m.stamp_ns - origin[0]) / 1e9 == t
        if kind == "scan":
            np.testing.assert_array_equal(m.payload.points_xyz_m, payload.points_xyz_m)
            np.testing.assert_array_equal(m.payload.time_offset_s, payload.time_offset_s)
        elif kind == "dvl":
            np.testing.assert_array_equal(m.payload[0], payload[0])
            assert m.payload[1] == payload[1]
        else:
            np.testing.assert_array_equal(m.payload, payload)


# ---------------------------------------------------------------------------------------------- timing
def test_reorder_window_sorts_late_arrivals_and_drops_older_ones():
    buf = ReorderBuffer(0.5)
    out = []
    for t, k in [(0.0, "attitude"), (0.25, "dvl"), (0.125, "depth"), (0.5, "attitude"), (0.0625, "dvl")]:
        out += buf.push(t, k, None)
    assert [(t, k) for t, k, _ in out] == [(0.0, "attitude")]  # released up to newest - window = 0.0
    out = buf.push(0.75, "attitude", None)  # releases up to 0.25, in stamp order: 0.0625 was reordered
    assert [(t, k) for t, k, _ in out] == [(0.0625, "dvl"), (0.125, "depth"), (0.25, "dvl")]
    assert buf.n_reordered == 2
    assert buf.push(0.1875, "depth", None) == [] and buf.dropped_late == {"depth": 1}  # older than released 0.25
    assert buf.push(0.25, "attitude", None) == [(0.25, "attitude", None)]  # equal to the released: still in order
    buf.push(0.75, "dvl", None)
    assert [(t, k) for t, k, _ in buf.flush()] == [(0.5, "attitude"), (0.75, "attitude"), (0.75, "dvl")]
    with pytest.raises(InputError, match="window_s"):
        ReorderBuffer(-1.0)


def test_latest_slot_keeps_the_newest_and_counts_drops():
    slot = LatestSlot()
    assert slot.put(1) is None
    assert slot.put(2) == 1 and slot.put(3) == 2 and slot.n_dropped == 2
    got = []
    th = threading.Thread(target=lambda: got.extend(iter(slot.get, None)))
    th.start()
    assert slot.wait_empty(5.0)
    slot.close()
    th.join(5.0)
    assert got == [3] and not th.is_alive()


# ---------------------------------------------------------------------------------------------- wiring
@pytest.fixture(scope="module")
def ros1_bag(tmp_path_factory):
    """A short simulated ROS 1 bag (vendor DVL type, scans with per-point time), its topic map and vehicle."""
    from semslam.dataset import read_vehicle_toml
    from semslam.dataset.rosbag import read_topic_map
    from semslam.cli.main import main

    d = tmp_path_factory.mktemp("bag")
    bag = d / "dive.bag"
    assert main(["--json", "simulate", "--out", str(bag), "--format", "ros1", "--quick", "--seed", "3"]) == 0
    return bag, read_topic_map(f"{bag}.topics.toml"), read_vehicle_toml(f"{bag}.vehicle.toml")


def test_live_wiring_shuffled_within_the_window_gives_the_offline_trajectory(ros1_bag, tmp_path):
    """Dead reckoning fed message by message from raw bytes, shuffled by up to 0.2 s, through LiveSlam (the one
    runner), is `semslam run`'s result on the same bag (run_stream of open_dive; to 1e-9 m)."""
    from semslam.run import open_dive, run_stream
    from semslam.run.ros1.decode import LiveDecoder
    from semslam.run.ros1.live import LiveSlam
    from tests._support.ros1 import raw_bag_messages

    bag, tmap, vehicle = ros1_bag
    ref = run_stream(open_dive(bag, topics=tmap, vehicle=vehicle, scans=False), modes=("dr",)).results["dr"]
    dec = LiveDecoder(tmap, vehicle)
    msgs = [dec.decode(t, ty, raw, md5sum=md5, definition=d, receive_ns=ns)
            for t, ty, md5, d, raw, ns in raw_bag_messages(bag, [tmap.attitude, tmap.dvl, tmap.depth])]
    origin = msgs[0].stamp_ns - msgs[0].stamp_ns % 1_000_000_000
    rng = random.Random(0)
    keyed = sorted(msgs, key=lambda m: m.stamp_ns / 1e9 + rng.uniform(0.0, 0.2))  # arrival jitter < the window
    n_est, preds = [], []
    live = LiveSlam(vehicle, None, mode="dr", reorder_window_s=0.5, on_estimate=lambda lv: n_est.append(lv.session.t),
                    on_prediction=lambda lv, pr: preds.append(pr))
    for m in keyed:
        live.add((m.stamp_ns - origin) / 1e9, m.kind, m.payload)
    assert live.buffer.n_reordered > 10 and live.dropped_late == {}
    res = live.close().results["dr"]
    # the filter's state after each batch that moved it, in time order, from the start on
    assert len(n_est) >= 0.9 * len(ref.stamps_s) and np.all(np.diff(n_est) > 0), (len(n_est), len(ref.stamps_s))
    np.testing.assert_allclose(res.stamps_s, ref.stamps_s, rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.position_ned_m, ref.position_ned_m, rtol=0, atol=1e-9)
    assert res.metrics["start"] == ref.metrics["start"]
    # the low-latency pose: the filter carried ~the runner's delay line ahead through the attitude and the DVL
    # samples received since (dead reckoning: 3 cm median, 16 cm max measured); the stale filter state's error is
    # the motion in the delay line (0.7 m median)
    assert len(preds) > len(n_est) and np.median([p.horizon_s for p in preds]) > 1.0
    t = np.array([p.stamp_s for p in preds])
    inside = t <= ref.stamps_s[-1]
    ref_p = np.stack([np.interp(t[inside], ref.stamps_s, ref.position_ned_m[:, i]) for i in range(3)], axis=1)
    err = np.linalg.norm(np.array([p.position_ned_m for p in preds])[inside] - ref_p, axis=1)
    stale = np.stack([np.interp(t[inside] - np.array([p.horizon_s for p in preds])[inside], ref.stamps_s,
                                ref.position_ned_m[:, i]) for i in range(3)], axis=1)
    stale_err = np.linalg.norm(stale - ref_p, axis=1)
    print(f"prediction vs offline: max {err.max():.3f} m, median {np.median(err):.3f} m; stale median "
          f"{np.median(stale_err):.3f} m")
    assert err.max() < 0.25 and np.median(err) < 0.05 and np.median(err) < 0.1 * np.median(stale_err), \
        (err.max(), np.median(err), np.median(stale_err))


def test_a_late_message_is_counted_by_the_runner_never_applied(ros1_bag):
    """A navigation message older than what the runner already processed is dropped and counted per kind."""
    from semslam.run.ros1.decode import LiveDecoder
    from semslam.run.ros1.live import LiveSlam
    from tests._support.ros1 import raw_bag_messages

    bag, tmap, vehicle = ros1_bag
    dec = LiveDecoder(tmap, vehicle)
    msgs = [dec.decode(t, ty, raw, md5sum=md5, definition=d, receive_ns=ns)
            for t, ty, md5, d, raw, ns in raw_bag_messages(bag, [tmap.attitude, tmap.depth])]
    origin = msgs[0].stamp_ns - msgs[0].stamp_ns % 1_000_000_000
    live = LiveSlam(vehicle, None, mode="dr")
    for m in msgs[: len(msgs) // 2]:
        live.add((m.stamp_ns - origin) / 1e9, m.kind, m.payload)
    first_depth = next(m for m in msgs if m.kind == "depth")
    live.add((first_depth.stamp_ns - origin) / 1e9, "depth", first_depth.payload)
    assert live.dropped_late == {"depth": 1}
    live.close()


def test_detection_array_bytes_decode_with_the_packaged_definition():
    """/semslam/detections' raw bytes (semslam_msgs/DetectionArray) decode with rosbags from the definition a
    subscriber receives in the connection header: label, score, pose in the scanner frame, covariance, stamp."""
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    from semslam.detection import Detection
    from semslam.geometry import RigidTransform, rotation_from_rpy
    from semslam.run.ros1.detections_msg import detection_array_bytes, detection_array_spec

    R = rotation_from_rpy(0.1, -0.2, 0.3)
    T = RigidTransform.from_rotation_translation(R, [1.0, -2.0, 3.5])
    cov = np.diag([1e-4, 2e-4, 3e-4, 1e-3, 2e-3, 3e-3])
    dets = [Detection("ball_valve", 0.5, T, cov, reliable=True, n_points=321, stamp_s=2.0),
            Detection("tee", 3.0, T, cov, reliable=False, n_points=12, stamp_s=2.0)]
    ros_type, md5, full_text = detection_array_spec()
    assert ros_type == "semslam_msgs/DetectionArray" and len(md5) == 32
    raw = detection_array_bytes(1_700_000_002_250_000_000, "laser", 7, dets, seq=3)
    # a subscriber knows only the connection header: parse the full text as a ROS 1 subscriber would
    store = get_typestore(Stores.EMPTY)
    types = {}
    for i, block in enumerate(full_text.split("=" * 80 + "\n")):
        name = ros_type if i == 0 else block.splitlines()[0].removeprefix("MSG: ")
        body = block if i == 0 else "\n".join(block.splitlines()[1:])
        pkg, msg = name.split("/")
        types.update(get_types_from_msg(body, f"{pkg}/msg/{msg}"))
    store.register(types)
    assert store.generate_msgdef("semslam_msgs/msg/DetectionArray")[1] == md5
    m = store.deserialize_ros1(raw, "semslam_msgs/msg/DetectionArray")
    assert (m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id, m.scan_id) == (1_700_000_002, 250_000_000,
                                                                                          "laser", 7)
    assert [d.label for d in m.detections] == ["ball_valve", "tee"] and [d.reliable for d in m.detections] == [True, False]
    d = m.detections[0]
    assert d.score == 0.5 and d.n_points == 321
    p, q = d.pose.pose.position, d.pose.pose.orientation
    np.testing.assert_allclose([p.x, p.y, p.z], [1.0, -2.0, 3.5])
    np.testing.assert_allclose(rotation_from_quat_wxyz([q.w, q.x, q.y, q.z]), R, atol=1e-12)
    np.testing.assert_allclose(np.asarray(d.pose.covariance).reshape(6, 6), cov)


def test_live_fixes_and_a_prior_map_give_semslam_runs_result(tmp_path):
    """GPS and USBL fixes decoded from raw NavSatFix bytes and a prior map (survey CSV) go through the runner as in
    `semslam run`: the same trajectory (to 1e-9 m), the fixes fused, the surveyed landmarks in the map."""
    from semslam.cli.main import main
    from semslam.dataset import read_vehicle_toml
    from semslam.dataset.rosbag import read_topic_map
    from semslam.run import open_dive, run_stream
    from semslam.run.dive import adopt_survey_frame
    from semslam.run.ros1.decode import LiveDecoder
    from semslam.run.ros1.live import LiveSlam
    from semslam.run.ros1.node import _prior_map
    from tests._support.ros1 import raw_bag_messages

    bag = tmp_path / "fixes.bag"
    assert main(["--json", "simulate", "--out", str(bag), "--format", "ros1", "--quick", "--seed", "5", "--gps", "5",
                 "--usbl-rate", "0.5"]) == 0
    tmap, vehicle = read_topic_map(f"{bag}.topics.toml"), read_vehicle_toml(f"{bag}.vehicle.toml")
    assert tmap.gps and tmap.usbl and tmap.origin is not None
    csv_path = tmp_path / "survey.csv"
    csv_path.write_text("name,label,x_m,y_m,z_m,roll_rad,pitch_rad,yaw_rad\nv1,ball_valve,3.0,1.0,4.0,0,0,0.5\n"
                        "t1,tee,-2.0,5.0,4.5,0,0,0\n", encoding="utf-8")
    survey, origin, origin_from = _prior_map(csv_path, tmap)
    assert origin_from == "the topic map" and len(survey) == 2
    dive = open_dive(bag, scans=False)
    adopt_survey_frame(dive, survey)
    ref = run_stream(dive, modes=("position",), survey=survey).results["position"]

    dec = LiveDecoder(tmap, vehicle)
    msgs = [dec.decode(t, ty, raw, md5sum=md5, definition=d, receive_ns=ns) for t, ty, md5, d, raw, ns
            in raw_bag_messages(bag, [tmap.attitude, tmap.dvl, tmap.depth, tmap.gps, tmap.usbl])]
    assert sum(m.kind == "fix" for m in msgs) > 5
    t0 = min(m.stamp_ns for m in msgs)
    origin_ns = t0 - t0 % 1_000_000_000
    live = LiveSlam(vehicle, None, mode="position", survey=survey, geodetic_origin=origin)
    for m in msgs:
        live.add((m.stamp_ns - origin_ns) / 1e9, m.kind, m.payload)
    res = live.close().results["position"]
    assert res.metrics["fix_updates"] == ref.metrics["fix_updates"] > 0
    np.testing.assert_allclose(res.position_ned_m, ref.position_ned_m, rtol=0, atol=1e-9)
    assert sorted(lm.name for lm in res.landmarks) == ["t1", "v1"]


def test_a_prior_map_about_another_geodetic_origin_is_refused(tmp_path):
    import dataclasses

    from semslam.dataset.rosbag import TopicMap
    from semslam.run.ros1.node import _prior_map
    from semslam.slam.survey import read_survey

    csv_path = tmp_path / "survey.csv"
    csv_path.write_text("name,label,x_m,y_m,z_m,roll_rad,pitch_rad,yaw_rad\nv1,ball_valve,3.0,1.0,4.0,0,0,0.5\n",
                        encoding="utf-8")
    survey = dataclasses.replace(read_survey(csv_path), geodetic_origin={"latitude_deg": 41.0, "longitude_deg": 2.0,
                                                                         "height_m": 0.0})
    here = TopicMap(attitude="/imu", origin={"latitude_deg": 41.001, "longitude_deg": 2.0})
    with pytest.raises(InputError, match="another geodetic origin"):
        _prior_map(survey, here)
    _, origin, origin_from = _prior_map(survey, TopicMap(attitude="/imu"))  # no origin of its own: the map's
    assert origin.latitude_deg == 41.0 and origin_from.startswith("the prior map")


class _SlowRecognizer:
    """A recogniser slower than the messages come (they are fed at once): one detection per scan, 3 m ahead of the
    scanner, stamped at the scan's middle, after 20 ms."""

    config = None

    def recognize(self, cloud, *, seed, stamp_s, scan_id, point_stamps_s=None, up_scanner=None):
        import time
        from types import SimpleNamespace

        from semslam.detection import Detection
        from semslam.geometry import RigidTransform

        time.sleep(0.02)
        t = float(np.median(point_stamps_s)) if point_stamps_s is not None else float(stamp_s)
        det = Detection("ball_valve", 1.0, RigidTransform.from_xyz_rpy([0.0, 0.0, 3.0], [0.0, 0.0, 0.0]),
                        np.diag([1e-3] * 3 + [1e-2] * 3), stamp_s=t, n_points=100)
        return SimpleNamespace(detections=[det], clusters=[None], timings_ms={"total": 20.0})


def test_scans_slower_than_the_messages_still_give_semslam_runs_result(ros1_bag):
    """Every message fed at once while each scan takes 20 ms to recognise (scan_queue "all"): navigation and later
    scans wait behind the scans in recognition, so every detection enters the runner in time and the pose run is
    the runner's own result on the same bag (to 1e-9 m), nothing late."""
    from semslam.run import open_dive, run_stream
    from semslam.run.ros1.decode import LiveDecoder
    from semslam.run.ros1.live import LiveSlam
    from tests._support.ros1 import raw_bag_messages

    bag, tmap, vehicle = ros1_bag
    ref = run_stream(open_dive(bag, topics=tmap, vehicle=vehicle), modes=("pose",), recognizer=_SlowRecognizer())
    dec = LiveDecoder(tmap, vehicle)
    msgs = [dec.decode(t, ty, raw, md5sum=md5, definition=d, receive_ns=ns) for t, ty, md5, d, raw, ns
            in raw_bag_messages(bag, [tmap.attitude, tmap.dvl, tmap.depth, tmap.scans])]
    origin = msgs[0].stamp_ns - msgs[0].stamp_ns % 1_000_000_000
    live = LiveSlam(vehicle, _SlowRecognizer(), mode="pose", scan_queue="all", max_hold_s=1e6)
    for m in msgs:
        live.add((m.stamp_ns - origin) / 1e9, m.kind, m.payload)
    assert live.stats["held_max"] > 100  # the messages really waited for the recogniser
    out = live.close()
    assert live.dropped_late == {} and live.stats["scans_late"] == 0
    res, r0 = out.results["pose"], ref.results["pose"]
    assert len(out.detections_by_scan) == len(ref.detections_by_scan) == sum(m.kind == "scan" for m in msgs)
    assert res.metrics["n_landmarks"] == r0.metrics["n_landmarks"] >= 1
    np.testing.assert_allclose(res.position_ned_m, r0.position_ned_m, rtol=0, atol=1e-9)


class _SignallingRecognizer(_SlowRecognizer):
    """:class:`_SlowRecognizer` that signals when a scan reaches it."""

    def __init__(self) -> None:
        import threading

        self.started = threading.Event()

    def recognize(self, cloud, **kw):
        self.started.set()
        return super().recognize(cloud, **kw)


def test_a_scan_is_recognised_as_it_arrives_not_after_the_reorder_window(ros1_bag):
    """Messages up to the first scan, nothing after it: the reorder window (2 s here) has not released the scan,
    yet its recognition starts (latency is recognition time, not the window's); the filter still takes it in stamp
    order, and the run is the runner's own result (to 1e-9 m)."""
    from semslam.run import open_dive, run_stream
    from semslam.run.ros1.decode import LiveDecoder
    from semslam.run.ros1.live import LiveSlam
    from tests._support.ros1 import raw_bag_messages

    bag, tmap, vehicle = ros1_bag
    dec = LiveDecoder(tmap, vehicle)
    msgs = [dec.decode(t, ty, raw, md5sum=md5, definition=d, receive_ns=ns) for t, ty, md5, d, raw, ns
            in raw_bag_messages(bag, [tmap.attitude, tmap.dvl, tmap.depth, tmap.scans])]
    origin = msgs[0].stamp_ns - msgs[0].stamp_ns % 1_000_000_000
    first_scan = next(i for i, m in enumerate(msgs) if m.kind == "scan")
    rec = _SignallingRecognizer()
    live = LiveSlam(vehicle, rec, mode="pose", scan_queue="all", max_hold_s=1e6, reorder_window_s=2.0)
    for m in msgs[:first_scan + 1]:
        live.add((m.stamp_ns - origin) / 1e9, m.kind, m.payload)
    assert len(live.buffer) > 0  # the scan is still in the window
    assert rec.started.wait(10.0), "the scan waited for the reorder window before recognition"
    for m in msgs[first_scan + 1:]:
        live.add((m.stamp_ns - origin) / 1e9, m.kind, m.payload)
    out = live.close()
    ref = run_stream(open_dive(bag, topics=tmap, vehicle=vehicle), modes=("pose",), recognizer=_SlowRecognizer())
    assert live.dropped_late == {} and live.stats["scans_late"] == 0
    np.testing.assert_allclose(out.results["pose"].position_ned_m, ref.results["pose"].position_ned_m,
                               rtol=0, atol=1e-9)


class _PriorRecorder:
    """A recogniser that tracks (``track_border_cut_m``) and deskews: one detection per scan 3 m ahead of the
    scanner; it records the priors each scan is given (the scan before's detection, carried by the navigation)."""

    def __init__(self) -> None:
        from semslam.pipeline import PipelineConfig

        self.config = PipelineConfig(verify_min_fitness=0.9, track_border_cut_m=0.03)
        self.seen = {}

    def recognize(self, cloud, *, seed, stamp_s, scan_id, point_stamps_s=None, up_scanner=None, measured=None,
                  priors=None, keep_context=False):
        from semslam.detection import Detection
        from semslam.geometry import RigidTransform
        from semslam.pipeline.scan import RecognitionResult

        self.seen[scan_id] = [] if priors is None else [(p.scan_id, p.T_sensor_object) for p in priors()]
        det = Detection("ball_valve", 1.0, RigidTransform.from_xyz_rpy([0.0, 0.0, 3.0], [0.0, 0.0, 0.0]),
                        np.diag([1e-3] * 3 + [1e-2] * 3), stamp_s=float(stamp_s), scan_id=scan_id, n_points=100)
        return RecognitionResult([det], [], None, {"total": 0.0})


def test_the_node_tracks_from_the_scan_before_as_semslam_run_does(ros1_bag):
    """Every scan of the bag through the node (scan_queue "all") and through `semslam run`'s runner: each scan but
    the first is given the scan before's object, carried by the same navigation to the same place (to 1e-9 m)."""
    from semslam.run import open_dive, run_stream
    from semslam.run.ros1.decode import LiveDecoder
    from semslam.run.ros1.live import LiveSlam
    from tests._support.ros1 import raw_bag_messages

    bag, tmap, vehicle = ros1_bag
    ref = _PriorRecorder()
    run_stream(open_dive(bag, topics=tmap, vehicle=vehicle), modes=("dr",), recognizer=ref)
    dec = LiveDecoder(tmap, vehicle)
    msgs = [dec.decode(t, ty, raw, md5sum=md5, definition=d, receive_ns=ns) for t, ty, md5, d, raw, ns
            in raw_bag_messages(bag, [tmap.attitude, tmap.dvl, tmap.depth, tmap.scans])]
    origin = msgs[0].stamp_ns - msgs[0].stamp_ns % 1_000_000_000
    rec = _PriorRecorder()
    live = LiveSlam(vehicle, rec, mode="pose", scan_queue="all", max_hold_s=1e6)
    for m in msgs:
        live.add((m.stamp_ns - origin) / 1e9, m.kind, m.payload)
    live.close()
    first, *rest = sorted(ref.seen)
    assert sorted(rec.seen) == sorted(ref.seen) and len(rest) >= 5
    assert ref.seen[first] == rec.seen[first] == []
    for sid in rest:
        (got,), (want,) = rec.seen[sid], ref.seen[sid]
        assert got[0] == want[0] == sid - 1
        np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-9)
        assert np.linalg.norm(want[1][:3, 3] - [0.0, 0.0, 3.0]) > 1e-3  # the vehicle moved between the two scans


class _ContextRecorder(_PriorRecorder):
    """``_PriorRecorder`` whose results keep what the backward step reads of a scan's context (its stamp, id)."""

    def recognize(self, cloud, **kw):
        from dataclasses import replace
        from types import SimpleNamespace

        context = SimpleNamespace(stamp_s=float(kw["stamp_s"]), scan_id=kw["scan_id"])
        return replace(super().recognize(cloud, **kw), context=context)


def test_the_node_makes_a_scan_final_from_the_scan_after_as_semslam_run_does(ros1_bag, monkeypatch):
    """The tracking stage standing in (every prior verifies, as in tests/pipeline/test_tracking.py): through the
    node and through `semslam run`, each scan followed closely by the next gains the next scan's object carried back
    to the same place (to 1e-9 m); the node publishes such a scan a second time, with it, and counts it."""
    from semslam.pipeline import tracking
    from semslam.run import open_dive, run_stream
    from semslam.run.ros1.decode import LiveDecoder
    from semslam.run.ros1.live import LiveSlam
    from tests._support.ros1 import raw_bag_messages
    from tests.pipeline.test_tracking import _tracks_every_prior

    monkeypatch.setattr(tracking, "track_rejected", _tracks_every_prior)
    bag, tmap, vehicle = ros1_bag

    def back(result):
        return [d.T_sensor_object.matrix for d in result.detections if "tracked_from_scan" in d.extras]

    ref = {}
    run_stream(open_dive(bag, topics=tmap, vehicle=vehicle), modes=("dr",), recognizer=_ContextRecorder(),
               on_scan=lambda msg, kept, stats, result: ref.setdefault(msg.scan_id, back(result)))
    dec = LiveDecoder(tmap, vehicle)
    msgs = [dec.decode(t, ty, raw, md5sum=md5, definition=d, receive_ns=ns) for t, ty, md5, d, raw, ns
            in raw_bag_messages(bag, [tmap.attitude, tmap.dvl, tmap.depth, tmap.scans])]
    origin = msgs[0].stamp_ns - msgs[0].stamp_ns % 1_000_000_000
    published = []
    live = LiveSlam(vehicle, _ContextRecorder(), mode="pose", scan_queue="all", max_hold_s=1e6,
                    on_detections=lambda job, result, lat: published.append((job.scan_id, back(result))))
    for m in msgs:
        live.add((m.stamp_ns - origin) / 1e9, m.kind, m.payload)
    live.close()
    gained = sorted(sid for sid, v in ref.items() if v)
    assert len(gained) >= 5 and live.stats["tracked_from_scan_after"] == len(gained)
    last = {}
    for sid, mats in published:  # a scan published again: the second is final
        assert sid not in last or (not last[sid] and mats), sid
        last[sid] = mats
    assert sorted(last) == sorted(ref) and len(published) == len(ref) + len(gained)
    for sid in gained:
        (got,), (want,) = last[sid], ref[sid]
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


def test_the_node_publishes_a_scan_before_tracking_back_into_the_scan_before(ros1_bag, monkeypatch):
    """The backward step (the scan before made final from a scan's objects, up to a few hundred ms) runs after the
    scan is published, not before: when it runs for scan k, scan k + 1 is out. The filter still waits for what it
    gains: with ``keep_unreliable`` the tracked detections enter it, none late, and the node's odometry is
    `semslam run`'s (to 1e-9 m)."""
    from semslam.pipeline import tracking
    from semslam.run import open_dive, run_stream
    from semslam.run.ros1.decode import LiveDecoder
    from semslam.run.ros1.live import LiveSlam
    from tests._support.ros1 import raw_bag_messages
    from tests.pipeline.test_tracking import _tracks_every_prior

    published, backward = [], []

    def tracked_back(rec, ctx, *args):
        backward.append((ctx.scan_id, list(published)))
        return _tracks_every_prior(rec, ctx, *args)

    monkeypatch.setattr(tracking, "track_rejected", tracked_back)
    bag, tmap, vehicle = ros1_bag
    ref = run_stream(open_dive(bag, topics=tmap, vehicle=vehicle), modes=("pose",), recognizer=_ContextRecorder(),
                     keep_unreliable=True)
    backward.clear()
    dec = LiveDecoder(tmap, vehicle)
    msgs = [dec.decode(t, ty, raw, md5sum=md5, definition=d, receive_ns=ns) for t, ty, md5, d, raw, ns
            in raw_bag_messages(bag, [tmap.attitude, tmap.dvl, tmap.depth, tmap.scans])]
    origin = msgs[0].stamp_ns - msgs[0].stamp_ns % 1_000_000_000
    live = LiveSlam(vehicle, _ContextRecorder(), mode="pose", scan_queue="all", max_hold_s=1e6, keep_unreliable=True,
                    on_detections=lambda job, result, lat: published.append(job.scan_id))
    for m in msgs:
        live.add((m.stamp_ns - origin) / 1e9, m.kind, m.payload)
    out = live.close()
    assert len(backward) >= 5
    for scan_id, out_then in backward:
        assert scan_id + 1 in out_then, (scan_id, out_then)
    assert live.stats["tracked_from_scan_after"] >= 5
    assert out.counts["late_dropped"] == {} == ref.counts["late_dropped"]
    np.testing.assert_allclose(out.results["pose"].position_ned_m, ref.results["pose"].position_ned_m,
                               rtol=0, atol=1e-9)


def test_a_scan_the_node_makes_final_replaces_what_it_fed_as_semslam_run_does(ros1_bag, monkeypatch):
    """The tracking stage standing in so that every scan followed closely has its own detection replaced by the scan
    after's object carried back (a cluster recognised alone as one class, tracked as another): the node, which fed
    the scan before it was final, withdraws what it replaced; with ``keep_unreliable`` its odometry, detections per
    scan and scan records are `semslam run`'s, nothing dropped late."""
    from semslam.pipeline import tracking
    from semslam.run import open_dive, run_stream
    from semslam.run.ros1.decode import LiveDecoder
    from semslam.run.ros1.live import LiveSlam
    from tests._support.ros1 import raw_bag_messages
    from tests.pipeline.test_tracking import _tracks_every_prior

    def replaces(rec, ctx, seg, outcomes, detections, priors, timings):
        outcomes, with_new = _tracks_every_prior(rec, ctx, seg, outcomes, detections, priors, timings)
        return outcomes, with_new[len(detections):] or detections

    monkeypatch.setattr(tracking, "track_rejected", replaces)
    bag, tmap, vehicle = ros1_bag
    ref = run_stream(open_dive(bag, topics=tmap, vehicle=vehicle), modes=("pose",), recognizer=_ContextRecorder(),
                     keep_unreliable=True)
    dec = LiveDecoder(tmap, vehicle)
    msgs = [dec.decode(t, ty, raw, md5sum=md5, definition=d, receive_ns=ns) for t, ty, md5, d, raw, ns
            in raw_bag_messages(bag, [tmap.attitude, tmap.dvl, tmap.depth, tmap.scans])]
    origin = msgs[0].stamp_ns - msgs[0].stamp_ns % 1_000_000_000
    live = LiveSlam(vehicle, _ContextRecorder(), mode="pose", scan_queue="all", max_hold_s=1e6, keep_unreliable=True)
    for m in msgs:
        live.add((m.stamp_ns - origin) / 1e9, m.kind, m.payload)
    out = live.close()

    def labelled(by_scan):
        return {sid: [(d.extras.get("tracked_from_scan"), d.reliable) for d in v] for sid, v in by_scan.items()}

    replaced = [sid for sid, v in ref.detections_by_scan.items() if "tracked_from_scan" in v[0].extras]
    assert len(replaced) >= 5 and live.stats["tracked_from_scan_after"] == len(replaced)
    assert labelled(out.detections_by_scan) == labelled(ref.detections_by_scan)
    assert [st["n_tracked"] for st in live.runner.scans] == [st["n_tracked"] for st in ref.scans]
    assert out.counts["late_dropped"] == {} == ref.counts["late_dropped"]
    np.testing.assert_allclose(out.results["pose"].position_ned_m, ref.results["pose"].position_ned_m,
                               rtol=0, atol=1e-9)
