"""Bag reading: a real ROS 1 bag, small generated ROS 1 / ROS 2 sqlite3 / ROS 2 mcap bags, and every way a
file can fail to be a bag (each a BagError, quickly: a watchdog fails any test that blocks)."""

from __future__ import annotations

import importlib.util
import os
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest

from semslam.errors import BagError
from semslam.io.ros import TopicRecord, decode_pointcloud2, imu_to_ned_frd, open_bag

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared"
REAL_BAG = SHARED / "data" / "bags" / "pointcloud2_ros1.bag"
BAGS = Path(__file__).resolve().parents[1] / "data" / "bags"
MSG_DIR = BAGS / "msg"

_spec = importlib.util.spec_from_file_location("make_test_bags", ROOT / "tests" / "data" / "make_test_bags.py")
mtb = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(mtb)

GENERATED = {"ros1": BAGS / "sensors_ros1.bag", "sqlite3": BAGS / "sensors_ros2_sqlite3",
             "mcap": BAGS / "sensors_ros2_mcap", "bare_mcap": BAGS / "sensors_ros2_mcap" / "sensors_ros2_mcap.mcap",
             "bare_db3": BAGS / "sensors_ros2_sqlite3" / "sensors_ros2_sqlite3.db3"}


@pytest.fixture(autouse=True)
def _watchdog():
    """Turn a blocking call (FIFO, device, endless loop) into a failure instead of a hung suite."""
    if not hasattr(signal, "SIGALRM"):  # not on Windows: run unguarded
        yield
        return

    def fire(signum, frame):
        raise TimeoutError("test blocked for more than 30 s")

    old = signal.signal(signal.SIGALRM, fire)
    signal.alarm(30)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


# -- the real ROS 1 bag (../shared/data/bags/README.md) ------------------------------------------------------------

@pytest.fixture(scope="module")
def real_bag() -> Path:
    from tests._support.shared import require_shared

    return require_shared(REAL_BAG, "real ROS 1 bag (../shared/data/bags)")


def test_real_ros1_bag_topics(real_bag: Path) -> None:
    with open_bag(real_bag) as bag:
        (rec,) = bag.topics()
        assert rec.topic == "/points_concat_downsampled" and rec.msgtype == "sensor_msgs/msg/PointCloud2"
        assert rec.count == 4
        assert 0.29 < (rec.last_stamp_ns - rec.first_stamp_ns) * 1e-9 < 0.31  # "0.3 s"
        assert rec.rate_hz == pytest.approx(3 / ((rec.last_stamp_ns - rec.first_stamp_ns) * 1e-9))
        assert bag.require_topic("/points_concat_downsampled", ["sensor_msgs/PointCloud2"]) .count == 4


def test_real_ros1_bag_clouds(real_bag: Path) -> None:
    widths, stamps = [], []
    with open_bag(real_bag) as bag:
        for i, (topic, msgtype, stamp_ns, msg) in enumerate(bag.messages("/points_concat_downsampled")):
            assert msg.height == 1 and msg.point_step == 32 and msg.row_step == 32 * msg.width
            assert not msg.is_bigendian and msg.is_dense
            assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
                ("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("intensity", 16, 7, 1)]
            d = decode_pointcloud2(msg, source=f"{real_bag.name} message {i}")
            assert d.frame_id == "velodyne" and d.n_dropped == 0 and d.n_points == msg.width
            assert d.intensity.shape == (msg.width,) and d.time_offset_s is None
            assert np.isfinite(d.points_xyz_m).all() and np.abs(d.points_xyz_m).max() < 200.0
            assert d.points_xyz_m[:, 2].min() > -5.0 and d.points_xyz_m[:, 2].max() < 15.0
            assert 0.0 <= d.intensity.min() and d.intensity.max() <= 255.0
            assert abs(d.stamp_ns - stamp_ns) < 1_000_000_000  # header stamp close to the receive time
            widths.append(d.n_points)
            stamps.append(stamp_ns)
            cloud = d.to_point_cloud()
            assert cloud.frame_id == "velodyne" and len(cloud) == msg.width
    assert widths == [3122, 3110, 3058, 3055]
    assert stamps == sorted(stamps)


# -- the generated bags ---------------------------------------------------------------------------------------------

def _opened(kind: str, with_msg_dir: bool = True):
    return open_bag(GENERATED[kind], msg_dirs=[MSG_DIR] if with_msg_dir else ())


@pytest.mark.parametrize("kind", list(GENERATED))
def test_generated_topics(kind: str) -> None:
    with _opened(kind) as bag:
        records = bag.topics()
    assert [r.topic for r in records] == sorted(mtb.TOPICS)
    for r in records:
        msgtype, count, period_ns, _ = mtb.TOPICS[r.topic]
        stamps = mtb.stamps_ns(r.topic)
        assert isinstance(r, TopicRecord) and r.msgtype == msgtype and r.count == count
        assert (r.first_stamp_ns, r.last_stamp_ns) == (stamps[0], stamps[-1])
        assert r.rate_hz == pytest.approx(1e9 / period_ns)


@pytest.mark.parametrize("kind", list(GENERATED))
def test_generated_messages_time_ordered_and_decoded(kind: str) -> None:
    with _opened(kind) as bag:
        messages = list(bag.messages())
    stamps = [m.stamp_ns for m in messages]
    assert stamps == sorted(stamps) and len(messages) == sum(v[1] for v in mtb.TOPICS.values())
    expected = sorted((s, t) for t in mtb.TOPICS for s in mtb.stamps_ns(t))
    assert [(m.stamp_ns, m.topic) for m in messages] == expected  # written topic after topic: merged here
    by_topic: dict[str, list] = {}
    for m in messages:
        by_topic.setdefault(m.topic, []).append(m)
        assert m.msg.header.stamp.sec * 10**9 + m.msg.header.stamp.nanosec == m.stamp_ns
    for k, m in enumerate(by_topic["/velodyne_points"]):
        pts, inten, t = mtb.cloud_points(k)
        d = decode_pointcloud2(m.msg)
        keep = np.isfinite(pts).all(axis=1)
        assert d.n_dropped == 1 and d.frame_id == "velodyne" and d.time_field == ("t" if kind == "ros1" else "time")
        np.testing.assert_allclose(d.points_xyz_m, pts[keep], atol=1e-6)
        np.testing.assert_array_equal(d.intensity, inten[keep])
        np.testing.assert_allclose(d.time_offset_s, t[keep], atol=1e-7)
    for k, m in enumerate(by_topic["/imu/data"]):
        rpy, omega_frd, acc_frd = imu_to_ned_frd(m.msg)
        np.testing.assert_allclose(rpy, [0.0, 0.0, np.pi / 2 - 0.1 * k], atol=1e-12)
        np.testing.assert_allclose(omega_frd, [0.0, 0.0, -2.0])
        np.testing.assert_allclose(acc_frd, [0.0, 0.0, -9.81])
    for k, m in enumerate(by_topic["/dvl/twist"]):
        v = m.msg.twist.twist.linear
        assert (v.x, v.y, v.z) == (0.3, 0.01 * k, 0.0) and m.msg.twist.covariance.shape == (36,)
    for k, m in enumerate(by_topic["/pressure"]):
        assert m.msg.fluid_pressure == pytest.approx(101325.0 + 10_000.0 * (1 + 0.1 * k))
    for k, m in enumerate(by_topic["/dvl/raw"]):
        assert m.msgtype == "semslam_msgs/msg/Dvl"
        np.testing.assert_allclose(m.msg.beam_ranges_m, np.array([2.0, 2.1, 2.05, 1.95]) + 0.01 * k)
        assert m.msg.beam_valid.tolist() == [True, True, k != 2, True]
        assert m.msg.figure_of_merit == pytest.approx(0.002 * (k + 1)) and m.msg.velocity.x == 0.3


@pytest.mark.parametrize("kind", ["sqlite3", "mcap", "bare_mcap", "bare_db3"])
def test_ros2_semslam_dvl_reads_without_msg_dir(kind: str) -> None:
    """The ROS 2 bags do not embed semslam_msgs/Dvl: its packaged definition reads it (a type nobody defines
    still needs --msg-dir: tests/io/test_ros_dvl_messages.py)."""
    with _opened(kind, with_msg_dir=False) as bag:
        dvl = list(bag.messages(["/dvl/raw"]))
    assert len(dvl) == 5 and dvl[0].msgtype == "semslam_msgs/msg/Dvl"
    np.testing.assert_allclose(dvl[1].msg.beam_ranges_m, np.array([2.0, 2.1, 2.05, 1.95]) + 0.01)
    assert dvl[2].msg.beam_valid.tolist() == [True, True, False, True]


def test_ros1_custom_type_travels_in_the_bag() -> None:
    with _opened("ros1", with_msg_dir=False) as bag:
        dvl = list(bag.messages("/dvl/raw"))
    assert len(dvl) == 5 and dvl[0].msg.beam_valid.dtype == bool


def test_require_topic_and_unknown_topics() -> None:
    with _opened("ros1") as bag:
        rec = bag.require_topic("/imu/data", ["sensor_msgs/Imu"])
        assert rec.count == 10 and rec.msgtype == "sensor_msgs/msg/Imu"
        assert bag.require_topic("/pressure").count == 5
        with pytest.raises(BagError, match=r"^Bag '.*sensors_ros1\.bag': topic '/points' not found\. The bag's topics "
                                           r"are: '/dvl/raw' \(semslam_msgs/msg/Dvl\), .*'/velodyne_points' "
                                           r"\(sensor_msgs/msg/PointCloud2\)\.$"):
            bag.require_topic("/points", ["sensor_msgs/msg/PointCloud2"])
        with pytest.raises(BagError, match=r"topic '/imu/data' must have type sensor_msgs/msg/PointCloud2 or "
                                           r"sensor_msgs/msg/LaserScan\. Got sensor_msgs/msg/Imu instead\."):
            bag.require_topic("/imu/data", ["sensor_msgs/PointCloud2", "sensor_msgs/msg/LaserScan"])
        with pytest.raises(BagError, match=r"topic '/nope' not found\. The bag's topics are: '/dvl/raw'"):
            bag.messages(["/imu/data", "/nope"])
    with pytest.raises(BagError, match="is closed"):
        bag.messages()


def test_script_regenerates_the_committed_bags(tmp_path: Path) -> None:
    paths = mtb.write_all(tmp_path)
    for kind, path in paths.items():
        size = path.stat().st_size if path.is_file() else sum(f.stat().st_size for f in path.iterdir())
        assert size < 64_000, f"{kind} bag grew to {size} bytes"
        with open_bag(path, msg_dirs=[MSG_DIR]) as new, _opened(kind) as old:
            assert new.topics() == old.topics()
            for a, b in zip(new.messages(), old.messages(), strict=True):
                assert (a.topic, a.stamp_ns) == (b.topic, b.stamp_ns)
                assert repr(a.msg) == repr(b.msg)


# -- files that are not (or no longer) bags -------------------------------------------------------------------------

def _cut(src: Path, dst: Path, fraction: float) -> Path:
    data = src.read_bytes()
    dst.write_bytes(data[: int(len(data) * fraction)])
    return dst


def _read_all(path: Path) -> int:
    with open_bag(path, msg_dirs=[MSG_DIR]) as bag:
        bag.topics()
        return sum(1 for _ in bag.messages())


@pytest.mark.parametrize("fraction", [0.0001, 0.01, 0.3, 0.5, 0.9, 0.999])
def test_truncated_ros1_bag(tmp_path: Path, fraction: float) -> None:
    path = _cut(GENERATED["ros1"], tmp_path / "cut.bag", fraction)
    with pytest.raises(BagError, match=r"^Bag '.*cut\.bag': "):
        _read_all(path)


@pytest.mark.parametrize("kind", ["sqlite3", "mcap"])
def test_truncated_ros2_bag(tmp_path: Path, kind: str) -> None:
    bag_dir = shutil.copytree(GENERATED[kind], tmp_path / "bag")
    storage = next(p for p in bag_dir.iterdir() if p.suffix in (".db3", ".mcap"))
    _cut(storage, storage, 0.5)
    with pytest.raises(BagError, match=r"^Bag '.*bag': cannot be opened as a ROS 2 bag"):
        _read_all(bag_dir)


@pytest.mark.parametrize("name", ["random.bag", "random.mcap", "random.db3"])
def test_random_bytes(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    path.write_bytes(np.random.default_rng(0).bytes(4096))
    with pytest.raises(BagError, match=rf"^Bag '.*{name}': cannot be opened as a ROS [12] bag \(.*\)\.$"):
        _read_all(path)


@pytest.mark.parametrize("name", ["empty.bag", "empty.mcap"])
def test_empty_file(tmp_path: Path, name: str) -> None:
    (tmp_path / name).touch()
    with pytest.raises(BagError, match=rf"^Bag '.*{name}': the file is empty \(0 bytes\)\.$"):
        open_bag(tmp_path / name)


def test_directory_without_metadata(tmp_path: Path) -> None:
    shutil.copy(GENERATED["sqlite3"] / "sensors_ros2_sqlite3.db3", tmp_path)
    with pytest.raises(BagError, match=r"a directory must be a ROS 2 bag holding metadata\.yaml\. Got none instead\."):
        open_bag(tmp_path)


def test_bad_metadata(tmp_path: Path) -> None:
    bag_dir = shutil.copytree(GENERATED["sqlite3"], tmp_path / "bag")
    (bag_dir / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    with pytest.raises(BagError, match=r"^Bag '.*bag': cannot be opened as a ROS 2 bag"):
        open_bag(bag_dir)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs os.mkfifo")
@pytest.mark.parametrize("name", ["fifo.bag", "fifo.mcap"])
def test_fifo_does_not_block(tmp_path: Path, name: str) -> None:
    os.mkfifo(tmp_path / name)
    with pytest.raises(BagError, match="must be a regular file or a ROS 2 bag directory. Got a special file"):
        open_bag(tmp_path / name)


@pytest.mark.skipif(not Path("/dev/urandom").exists(), reason="needs /dev/urandom")
def test_device_symlink_does_not_block(tmp_path: Path) -> None:
    os.symlink("/dev/urandom", tmp_path / "urandom.bag")
    with pytest.raises(BagError, match="Got a special file"):
        open_bag(tmp_path / "urandom.bag")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs os.mkfifo")
def test_fifo_inside_ros2_directory(tmp_path: Path) -> None:
    bag_dir = shutil.copytree(GENERATED["sqlite3"], tmp_path / "bag")
    (bag_dir / "sensors_ros2_sqlite3.db3").unlink()
    os.mkfifo(bag_dir / "sensors_ros2_sqlite3.db3")
    with pytest.raises(BagError, match="'sensors_ros2_sqlite3.db3' must be a regular file"):
        open_bag(bag_dir)


def test_missing_path_and_wrong_suffix(tmp_path: Path) -> None:
    with pytest.raises(BagError, match=r"^Bag '.*nothing\.bag': no such file or directory\.$"):
        open_bag(tmp_path / "nothing.bag")
    (tmp_path / "notes.txt").write_text("not a bag")
    with pytest.raises(BagError, match=r"must be a ROS 1 \.bag, a \.mcap or \.db3 file.*Got suffix '\.txt'"):
        open_bag(tmp_path / "notes.txt")


def test_bad_msg_dirs(tmp_path: Path) -> None:
    with pytest.raises(BagError, match=r"'msg_dirs' argument of open_bag must list directories .*not a directory"):
        open_bag(GENERATED["sqlite3"], msg_dirs=[tmp_path / "absent"])
    with pytest.raises(BagError, match=r"'msg_dirs' argument of open_bag .*which holds none"):
        open_bag(GENERATED["sqlite3"], msg_dirs=[tmp_path])
    bad = tmp_path / "pkg" / "msg"
    bad.mkdir(parents=True)
    (bad / "Broken.msg").write_text("float64[ oops\n")
    with pytest.raises(BagError, match=r"Message definition '.*Broken\.msg' \(pkg/msg/Broken\) cannot be parsed"):
        open_bag(GENERATED["sqlite3"], msg_dirs=[tmp_path])


@pytest.mark.parametrize("name", ["sensors_ros1.bag", "sensors_ros2_mcap/sensors_ros2_mcap.mcap"])
def test_seeded_corruption_only_bag_error(tmp_path: Path, name: str) -> None:
    rng = np.random.default_rng(140)
    original = (BAGS / name).read_bytes()
    path = tmp_path / Path(name).name
    outcomes = {"ok": 0, "error": 0}
    for _ in range(30):
        data = np.frombuffer(original, dtype=np.uint8).copy()
        for _ in range(int(rng.integers(1, 5))):
            i = int(rng.integers(0, len(data)))
            data[i : i + 4] = rng.integers(0, 256, len(data[i : i + 4]))
        path.write_bytes(data.tobytes())
        try:
            with open_bag(path, msg_dirs=[MSG_DIR]) as bag:
                bag.topics()
                for m in bag.messages():
                    if m.topic == "/velodyne_points":
                        decode_pointcloud2(m.msg, source="fuzz")
            outcomes["ok"] += 1
        except BagError as err:
            assert "\n" not in str(err)
            outcomes["error"] += 1
    assert outcomes["error"] > 0
