"""The DVL messages vehicles record (COLA2, Water Linked ROS 1 / ROS 2, UUV Simulator, marine_acoustic_msgs) and
semslam's own, each written into a small bag with rosbags and read back through ``open_bag`` + ``decode_dvl`` and
through ``stream_bag``: velocity in the frame the driver documents (given as FRD), validity and beam ranges. The
definitions come from ``semslam/io/ros/msg`` (packaged): no ``msg_dirs`` anywhere below."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from semslam.dataset import VehicleDescription
from semslam.dataset.rosbag import TopicMap, stream_bag, suggest_topic_map
from semslam.errors import BagError
from semslam.io.ros import open_bag
from semslam.io.ros._encode import ros_header
from semslam.io.ros._types import PACKAGED_MSG_DIR, packaged_types, semslam_typestore
from semslam.io.ros.dvl import DVL_MESSAGE_TYPES, decode_dvl, dvl_convention, topic_dvl_convention

T0_NS = 1_700_000_000 * 1_000_000_000
#: the velocity each message holds, in its own DVL frame (m/s), and the beams' slant ranges (m)
V_SENSOR = [np.array([0.5, 0.1, -0.05]), np.array([0.45, -0.2, 0.03]), np.array([0.0, 0.0, 0.0])]
RANGES = [np.array([2.0, 2.1, 2.2, 2.3]), np.array([2.4, 2.5, 2.6, 2.7]), np.array([3.0, 3.1, 3.2, 3.3])]
#: message k: 0 valid, 1 valid with beam 2 lost, 2 velocity invalid (every beam lost)
BEAM_OK = [[True] * 4, [True, True, False, True], [False] * 4]
VALID = [True, True, False]
FLU_TO_FRD = np.array([1.0, -1.0, -1.0])


def _vec(T, v):
    return T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _dvl_message(store, msgtype: str, k: int, frame_id: str):
    T = store.types
    h = ros_header(store, T0_NS + k * 100_000_000, frame_id)
    v, r, ok = V_SENSOR[k], RANGES[k], BEAM_OK[k]
    if msgtype == "semslam_msgs/msg/Dvl":
        return T[msgtype](header=h, velocity=_vec(T, v), beam_ranges_m=r.copy(), beam_valid=np.array(ok),
                          figure_of_merit=0.002)
    if msgtype in ("waterlinked_a50_ros_driver/msg/DVL", "dvl_msgs/msg/DVL"):
        Beam = T[msgtype.replace("/DVL", "/DVLBeam")]
        beams = [Beam(id=i, velocity=0.1 * i, distance=float(r[i]), rssi=-30.0, nsd=-90.0, valid=ok[i])
                 for i in range(4)]
        extra = ({"covariance": np.eye(3).reshape(-1) * 1e-6, "time_of_validity": 0, "time_of_transmission": 0}
                 if msgtype == "dvl_msgs/msg/DVL" else {})
        return T[msgtype](header=h, time=100.0, velocity=_vec(T, v), fom=0.002, altitude=float(r.mean()),
                          beams=beams, velocity_valid=VALID[k], status=0, form="json_v3", **extra)
    if msgtype in ("cola2_msgs/msg/DVL", "uuv_sensor_ros_plugins_msgs/msg/DVL"):
        Beam = T[msgtype.replace("/DVL", "/DVLBeam")]
        pose = T["geometry_msgs/msg/PoseStamped"](
            header=ros_header(store, 0, frame_id),
            pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
                                             orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0,
                                                                                           w=1.0)))
        beams = [Beam(range=float(r[i]) if ok[i] else -1.0, range_covariance=1e-4, velocity=0.0,
                      velocity_covariance=1e-4, pose=pose) for i in range(4)]
        cov = np.diag([1e-6] * 3).reshape(-1) if VALID[k] else np.full(9, -1.0)  # -1: invalid (the message's rule)
        return T[msgtype](header=h, velocity=_vec(T, v), velocity_covariance=cov, altitude=float(r.mean()),
                          beams=beams)
    assert msgtype == "marine_acoustic_msgs/msg/Dvl"
    return T[msgtype](header=h, velocity_mode=1, dvl_type=0, velocity=_vec(T, v), velocity_covar=np.full(9, -1.0),
                      altitude=float(r.mean()), course_gnd=0.0, speed_gnd=0.0, num_good_beams=int(sum(ok)),
                      sound_speed=np.float32(1500.0), beam_ranges_valid=True, beam_velocities_valid=True,
                      beam_unit_vec=[_vec(T, (0.0, 0.0, 1.0))] * 4,
                      range=np.where(ok, r, 0.0), range_covar=np.zeros(4, np.float32),
                      beam_quality=np.ones(4, np.float32), beam_velocity=np.zeros(4, np.float32),
                      beam_velocity_covar=np.full(4, -1.0, np.float32))


def _imu(store, k: int):
    T = store.types
    return T["sensor_msgs/msg/Imu"](
        header=ros_header(store, T0_NS + k * 100_000_000 + 1, "base_link"),
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.eye(3).reshape(-1) * 1e-4, angular_velocity=_vec(T, (0, 0, 0)),
        angular_velocity_covariance=np.r_[-1.0, np.zeros(8)], linear_acceleration=_vec(T, (0, 0, 0)),
        linear_acceleration_covariance=np.r_[-1.0, np.zeros(8)])


def write_dvl_bag(path: Path, msgtype: str, fmt: str, *, frame_id: str = "dvl", embed: bool = True) -> Path:
    """A bag with 3 DVL messages on ``/dvl`` and 3 IMU messages on ``/imu``. ``fmt``: "ros1" or "ros2-mcap";
    ``embed=False`` leaves the DVL definition out of a ROS 2 bag (as ROS 2 Humble's recorders may)."""
    ros1 = fmt == "ros1"
    store = semslam_typestore(ros1=ros1)
    if ros1:
        from rosbags.rosbag1 import Writer

        with Writer(path) as w:
            c_dvl = w.add_connection("/dvl", msgtype, typestore=store)
            c_imu = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=store)
            for k in range(3):
                w.write(c_dvl, T0_NS + k * 100_000_000, store.serialize_ros1(_dvl_message(store, msgtype, k, frame_id),
                                                                             msgtype))
                w.write(c_imu, T0_NS + k * 100_000_000 + 1, store.serialize_ros1(_imu(store, k), "sensor_msgs/msg/Imu"))
        return path
    from rosbags.rosbag2 import StoragePlugin, Writer

    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c_dvl = (w.add_connection("/dvl", msgtype, typestore=store) if embed else
                 w.add_connection("/dvl", msgtype, msgdef="", rihs01=store.hash_rihs01(msgtype)))
        c_imu = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=store)
        for k in range(3):
            w.write(c_dvl, T0_NS + k * 100_000_000, store.serialize_cdr(_dvl_message(store, msgtype, k, frame_id),
                                                                        msgtype))
            w.write(c_imu, T0_NS + k * 100_000_000 + 1, store.serialize_cdr(_imu(store, k), "sensor_msgs/msg/Imu"))
    return path


def _expected_ranges(k: int) -> np.ndarray:
    return np.where(BEAM_OK[k], RANGES[k], np.nan)


# (type, bag format, frame_id, embed the definition, the convention the driver documents)
CASES = [
    ("waterlinked_a50_ros_driver/msg/DVL", "ros1", "dvl_link", True, "frd"),
    ("dvl_msgs/msg/DVL", "ros2-mcap", "dvl_A50_report_link", True, "frd"),
    ("dvl_msgs/msg/DVL", "ros2-mcap", "dvl_A50_report_link", False, "frd"),
    ("cola2_msgs/msg/DVL", "ros1", "girona500/dvl", True, "frd"),
    ("cola2_msgs/msg/DVL", "ros2-mcap", "girona500/dvl", False, "frd"),
    ("uuv_sensor_ros_plugins_msgs/msg/DVL", "ros1", "rexrov/dvl_link", True, "flu"),
    ("uuv_sensor_ros_plugins_msgs/msg/DVL", "ros1", "rexrov/dvl_link_ned", True, "frd"),
    ("marine_acoustic_msgs/msg/Dvl", "ros1", "dvl", True, "frd"),
    ("marine_acoustic_msgs/msg/Dvl", "ros2-mcap", "dvl", False, "frd"),
    ("semslam_msgs/msg/Dvl", "ros2-mcap", "dvl", False, "frd"),
]


@pytest.mark.parametrize("msgtype, fmt, frame_id, embed, convention", CASES,
                         ids=[f"{c[0].split('/')[0]}-{c[1]}-{c[2].split('/')[-1]}-{'embedded' if c[3] else 'packaged'}"
                              for c in CASES])
def test_dvl_message_decodes_velocity_validity_and_ranges_in_its_documented_frame(
        tmp_path, msgtype, fmt, frame_id, embed, convention):
    path = write_dvl_bag(tmp_path / ("d.bag" if fmt == "ros1" else "d"), msgtype, fmt, frame_id=frame_id, embed=embed)
    with open_bag(path) as bag:  # no msg_dirs: the packaged definitions (or the bag's own)
        assert bag.require_topic("/dvl").msgtype == msgtype
        readings = [decode_dvl(m.msg, m.msgtype) for m in bag.messages(["/dvl"])]
        suggested = suggest_topic_map(bag)
        assert topic_dvl_convention(bag, "/dvl") == convention and topic_dvl_convention(bag, "/nope") is None
        assert topic_dvl_convention(bag, "/imu") is None  # not a DVL type
    assert suggested.dvl == "/dvl" and suggested.dvl_frame == convention
    assert [r.valid for r in readings] == VALID
    for k, r in enumerate(readings):
        assert r.convention == convention and r.frame_id == frame_id
        np.testing.assert_allclose(r.velocity_mps, V_SENSOR[k], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(r.beam_ranges_m, _expected_ranges(k))

    # the dataset border: FRD velocity in the frame the type documents when the topic map states none; a frame the
    # map states is the user's word and overrides the type's (a wrong one is then caught by the run's health verdict)
    for stated in (None, "frd" if convention == "flu" else "flu"):
        tmap = TopicMap(attitude="/imu", dvl="/dvl", dvl_frame=stated)
        with open_bag(path) as bag:
            out = [p for _, kind, p in stream_bag(bag, tmap, VehicleDescription.girona500()) if kind == "dvl"]
        assert [p[1] for p in out] == VALID
        for k, (v_frd, valid, ranges) in enumerate(out):
            want = V_SENSOR[k] * (FLU_TO_FRD if (stated or convention) == "flu" else 1.0)
            np.testing.assert_allclose(v_frd, want if valid else np.full(3, np.nan), rtol=0, atol=1e-12)
            np.testing.assert_array_equal(ranges, _expected_ranges(k))


def test_a_twist_declares_no_frame_and_the_topic_map_decides(tmp_path):
    store = semslam_typestore(ros1=True)
    T = store.types
    twist = T["geometry_msgs/msg/TwistWithCovarianceStamped"](
        header=ros_header(store, T0_NS, "dvl"),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=_vec(T, (0.4, 0.2, -0.1)), angular=_vec(T, (0, 0, 0))),
            covariance=np.zeros(36)))
    r = decode_dvl(twist, "geometry_msgs/msg/TwistWithCovarianceStamped")
    assert r.convention is None and r.valid and r.beam_ranges_m is None
    with pytest.raises(BagError, match=r"does not document its frame.*\[frames\] dvl"):
        r.velocity_frd_mps()  # never a guess
    np.testing.assert_allclose(r.velocity_frd_mps("flu"), [0.4, -0.2, 0.1])
    np.testing.assert_allclose(r.velocity_frd_mps("frd"), [0.4, 0.2, -0.1])
    assert dvl_convention("geometry_msgs/msg/TwistWithCovarianceStamped") is None
    assert dvl_convention("uuv_sensor_ros_plugins_msgs/msg/DVL") is None  # needs the frame_id
    assert dvl_convention("uuv_sensor_ros_plugins_msgs/msg/DVL", "rexrov/dvl_link_ned") == "frd"


def test_unknown_types_are_refused_with_the_type_named(tmp_path):
    store = semslam_typestore(ros1=True)
    imu = _imu(store, 0)
    with pytest.raises(BagError, match=r"DVL topic '/x' has type sensor_msgs/msg/Imu: expected one of "
                                       r"semslam_msgs/msg/Dvl, .*'velocity'"):
        decode_dvl(imu, "sensor_msgs/msg/Imu", source="DVL topic '/x'")
    # a definition variant without a field semslam reads: named, not an AttributeError
    from types import SimpleNamespace

    v = SimpleNamespace(x=0.1, y=0.0, z=0.0)
    with pytest.raises(BagError, match=r"dvl_msgs/msg/DVL lacks the field 'velocity_valid'"):
        decode_dvl(SimpleNamespace(header=None, velocity=v, beams=[]), "dvl_msgs/msg/DVL")


def test_a_type_nobody_defines_still_needs_msg_dir(tmp_path):
    """A ROS 2 bag without the definition of a vendor type semslam does not ship: one line asking for it."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_types_from_msg

    store = semslam_typestore(ros1=False)
    store.register(get_types_from_msg("std_msgs/Header header\ngeometry_msgs/Vector3 velocity\n",
                                      "acme_msgs/msg/Dvl"))
    msg = store.types["acme_msgs/msg/Dvl"](header=ros_header(store, T0_NS, "dvl"),
                                           velocity=_vec(store.types, (0.1, 0.2, 0.3)))
    with Writer(tmp_path / "b", version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/dvl", "acme_msgs/msg/Dvl", msgdef="", rihs01=store.hash_rihs01("acme_msgs/msg/Dvl"))
        w.write(c, T0_NS, store.serialize_cdr(msg, "acme_msgs/msg/Dvl"))
    with open_bag(tmp_path / "b") as bag:
        with pytest.raises(BagError, match=r"'acme_msgs/msg/Dvl' with no definition.*--msg-dir"):
            bag.messages(["/dvl"])
    msg_dir = tmp_path / "ws" / "acme_msgs" / "msg"
    msg_dir.mkdir(parents=True)
    (msg_dir / "Dvl.msg").write_text("std_msgs/Header header\ngeometry_msgs/Vector3 velocity\n")
    with open_bag(tmp_path / "b", msg_dirs=[tmp_path / "ws"]) as bag:
        (m,) = list(bag.messages(["/dvl"]))
    r = decode_dvl(m.msg, m.msgtype)  # a vendor message with a velocity: read, but its frame is not documented
    assert r.convention is None and r.valid
    np.testing.assert_allclose(r.velocity_mps, [0.1, 0.2, 0.3])


def test_packaged_definitions_cover_every_documented_type_and_match_the_writer():
    from rosbags.typesys import get_types_from_msg

    from semslam.dataset.rosbag_write import DVL_MSG, DVL_TYPE

    types = packaged_types()
    for msgtype in DVL_MESSAGE_TYPES:
        assert msgtype in types, msgtype
    # the simulator's bags and the packaged definition cannot drift apart
    assert types[DVL_TYPE] == get_types_from_msg(DVL_MSG, DVL_TYPE)[DVL_TYPE]
    # every file is where pyproject's package-data globs ("io/ros/msg/*.md", "io/ros/msg/*/msg/*.msg") find it
    files = sorted(p.relative_to(PACKAGED_MSG_DIR) for p in PACKAGED_MSG_DIR.rglob("*") if p.is_file())
    assert all(len(f.parts) == 3 and f.parts[1] == "msg" and f.suffix == ".msg" or f == Path("SOURCES.md")
               for f in files), files
    pyproject = (Path(__file__).resolve().parents[2] / "pyproject.toml").read_text()
    assert '"io/ros/msg/*/msg/*.msg"' in pyproject and '"io/ros/msg/*.md"' in pyproject
