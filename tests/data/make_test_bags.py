"""Write the small ROS bags under ``tests/data/bags/`` with rosbags' writers (no ROS install needed).

    python tests/data/make_test_bags.py            # rewrites tests/data/bags/{sensors_ros1.bag,sensors_ros2_*}

Every bag holds the same 0.5 s of a made-up dive, written topic after topic (not in time order, so that
readers must merge): a ``sensor_msgs/PointCloud2`` (16 points, intensity, per-point time), a
``sensor_msgs/Imu`` (REP-103: ENU/FLU), a ``geometry_msgs/TwistWithCovarianceStamped`` (DVL velocity), a
``sensor_msgs/FluidPressure`` and the custom ``semslam_msgs/msg/Dvl`` defined in
``bags/msg/semslam_msgs/msg/Dvl.msg``. The ROS 1 bag embeds every definition (as ROS 1 does); the ROS 2
sqlite3 bag embeds none (as ROS 2 Humble's recorder); the ROS 2 mcap bag embeds all but the Dvl one. So
the ROS 2 bags' ``/dvl/raw`` is read with ``msg_dirs=[MSG_DIR]`` or semslam's packaged definition
(``semslam/io/ros/msg``, the same fields). Deterministic: seed 14.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
BAGS = HERE / "bags"
MSG_DIR = BAGS / "msg"
DVL_TYPE = "semslam_msgs/msg/Dvl"
T0_NS = 1_700_000_000_000_000_000
SEED = 14

#: topic -> (type, number of messages, period in ns, first stamp offset in ns)
TOPICS = {
    "/velodyne_points": ("sensor_msgs/msg/PointCloud2", 5, 100_000_000, 40_000_000),
    "/imu/data": ("sensor_msgs/msg/Imu", 10, 50_000_000, 10_000_000),
    "/dvl/twist": ("geometry_msgs/msg/TwistWithCovarianceStamped", 5, 100_000_000, 20_000_000),
    "/pressure": ("sensor_msgs/msg/FluidPressure", 5, 100_000_000, 30_000_000),
    "/dvl/raw": (DVL_TYPE, 5, 100_000_000, 25_000_000),
}
N_POINTS = 16


def stamps_ns(topic: str) -> list[int]:
    """Bag (and header) stamps of ``topic``'s messages."""
    _, count, period, first = TOPICS[topic]
    return [T0_NS + first + k * period for k in range(count)]


def cloud_points(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (16, 3) m, intensity (16,) and time offsets (16,) s of cloud ``k``; point 5 is NaN."""
    rng = np.random.default_rng(SEED + k)
    pts = rng.uniform(-5.0, 5.0, size=(N_POINTS, 3)).round(3)
    pts[5] = np.nan
    return pts, np.arange(N_POINTS, dtype=np.float64) + k, np.linspace(0.0, 0.099, N_POINTS)


def _store(ros1: bool):
    from rosbags.typesys import get_types_from_msg

    from semslam.io.ros._encode import default_typestore

    store = default_typestore(ros1=ros1)
    text = (MSG_DIR / "semslam_msgs" / "msg" / "Dvl.msg").read_text()
    store.register(get_types_from_msg(text, DVL_TYPE))
    return store


def _message(store, topic: str, k: int, stamp_ns: int, *, ros1: bool):
    from semslam.io.ros._encode import encode_pointcloud2, ros_header

    T = store.types
    header = ros_header(store, stamp_ns, "base_link")
    vec = lambda x, y, z: T["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))  # noqa: E731
    if topic == "/velodyne_points":
        pts, inten, t = cloud_points(k)
        return encode_pointcloud2(pts, intensity=inten, time_offset_s=t, frame_id="velodyne", stamp_ns=stamp_ns,
                                  time_field="t" if ros1 else "time",
                                  time_encoding="uint32_ns" if ros1 else "float32_s",
                                  point_padding_bytes=4, typestore=store)
    if topic == "/imu/data":
        yaw = 0.1 * k  # ENU yaw, slowly turning left
        quat = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2)))
        cov = np.diag([1e-4, 1e-4, 4e-4]).reshape(-1)
        return T["sensor_msgs/msg/Imu"](header=header, orientation=quat, orientation_covariance=cov,
                                        angular_velocity=vec(0.0, 0.0, 2.0), angular_velocity_covariance=cov,
                                        linear_acceleration=vec(0.0, 0.0, 9.81), linear_acceleration_covariance=cov)
    if topic == "/dvl/twist":
        twist = T["geometry_msgs/msg/Twist"](linear=vec(0.3, 0.01 * k, 0.0), angular=vec(0.0, 0.0, 0.0))
        cov = np.diag([1e-4, 1e-4, 1e-4, -1.0, -1.0, -1.0]).reshape(-1)
        twc = T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov)
        return T["geometry_msgs/msg/TwistWithCovarianceStamped"](header=header, twist=twc)
    if topic == "/pressure":
        return T["sensor_msgs/msg/FluidPressure"](header=header, fluid_pressure=101325.0 + 10_000.0 * (1 + 0.1 * k),
                                                  variance=25.0)
    return T[DVL_TYPE](header=header, velocity=vec(0.3, 0.01 * k, 0.0),
                       beam_ranges_m=np.array([2.0, 2.1, 2.05, 1.95]) + 0.01 * k,
                       beam_valid=np.array([True, True, k != 2, True]), figure_of_merit=0.002 * (k + 1))


def write_ros1_bag(path: str | Path) -> Path:
    """Write the ROS 1 bag (every definition embedded) to ``path`` (must not exist)."""
    from rosbags.rosbag1 import Writer

    store = _store(ros1=True)
    with Writer(Path(path)) as writer:
        for topic, (msgtype, *_rest) in TOPICS.items():
            conn = writer.add_connection(topic, msgtype, typestore=store)
            for k, stamp in enumerate(stamps_ns(topic)):
                writer.write(conn, stamp, store.serialize_ros1(_message(store, topic, k, stamp, ros1=True), msgtype))
    return Path(path)


def write_ros2_bag(path: str | Path, storage: str = "sqlite3") -> Path:
    """Write a ROS 2 bag directory with ``storage`` "sqlite3" (no definition embedded, like Humble) or
    "mcap" (every definition but the custom Dvl one embedded). ``path`` must not exist."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = _store(ros1=False)
    plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
    with Writer(Path(path), version=9, storage_plugin=plugin) as writer:
        for topic, (msgtype, *_rest) in TOPICS.items():
            if storage == "sqlite3" or msgtype == DVL_TYPE:
                conn = writer.add_connection(topic, msgtype, msgdef="", rihs01=store.hash_rihs01(msgtype))
            else:
                conn = writer.add_connection(topic, msgtype, typestore=store)
            for k, stamp in enumerate(stamps_ns(topic)):
                writer.write(conn, stamp, store.serialize_cdr(_message(store, topic, k, stamp, ros1=False), msgtype))
    return Path(path)


def write_all(out_dir: str | Path = BAGS) -> dict[str, Path]:
    """(Re)write the three bags into ``out_dir``; returns {"ros1", "sqlite3", "mcap"} -> path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"ros1": out / "sensors_ros1.bag", "sqlite3": out / "sensors_ros2_sqlite3",
             "mcap": out / "sensors_ros2_mcap"}
    for p in paths.values():
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()
    write_ros1_bag(paths["ros1"])
    write_ros2_bag(paths["sqlite3"], "sqlite3")
    write_ros2_bag(paths["mcap"], "mcap")
    return paths


if __name__ == "__main__":
    sys.path.insert(0, str(HERE.parents[1]))  # semslam from this checkout
    for name, p in write_all().items():
        size = sum(f.stat().st_size for f in ([p] if p.is_file() else p.iterdir()))
        print(f"{name}: {p} ({size} bytes)")
