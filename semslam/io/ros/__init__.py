"""ROS bags without a ROS install: bag reading, PointCloud2 decoding and REP-103 frame conversions.

>>> from semslam.io.ros import open_bag, decode_pointcloud2                # doctest: +SKIP
>>> with open_bag("dive.bag", msg_dirs=["my_msgs_ws/src"]) as bag:         # doctest: +SKIP
...     bag.require_topic("/points", ["sensor_msgs/msg/PointCloud2"])
...     for m in bag.messages(["/points"]):
...         cloud = decode_pointcloud2(m.msg, source=f"topic {m.topic}").to_point_cloud()

rosbags (pure Python) is imported only when a bag is opened or a message is encoded, so that
``import semslam.io`` stays fast.
"""

from __future__ import annotations

from .bag import Bag, BagMessage, TopicRecord, open_bag
from .frames import (
    C_FRD_FLU,
    C_NED_ENU,
    R_world_enu_vehicle_flu_from_R_world_ned_vehicle_frd,
    R_world_ned_vehicle_frd_from_quat_xyzw,
    R_world_ned_vehicle_frd_from_R_world_enu_vehicle_flu,
    imu_rpy_ned_frd,
    imu_to_ned_frd,
    quat_xyzw_from_R_world_ned_vehicle_frd,
    rates_flu_from_frd,
    rates_frd_from_flu,
    rpy_ned_frd_from_quat_xyzw,
    vectors_enu_from_ned,
    vectors_flu_from_frd,
    vectors_frd_from_flu,
    vectors_ned_from_enu,
)
from .pointcloud2 import PointCloud2Data, decode_pointcloud2, encode_pointcloud2

__all__ = [
    "Bag",
    "BagMessage",
    "C_FRD_FLU",
    "C_NED_ENU",
    "PointCloud2Data",
    "R_world_enu_vehicle_flu_from_R_world_ned_vehicle_frd",
    "R_world_ned_vehicle_frd_from_R_world_enu_vehicle_flu",
    "R_world_ned_vehicle_frd_from_quat_xyzw",
    "TopicRecord",
    "decode_pointcloud2",
    "encode_pointcloud2",
    "imu_rpy_ned_frd",
    "imu_to_ned_frd",
    "open_bag",
    "quat_xyzw_from_R_world_ned_vehicle_frd",
    "rates_flu_from_frd",
    "rates_frd_from_flu",
    "rpy_ned_frd_from_quat_xyzw",
    "vectors_enu_from_ned",
    "vectors_flu_from_frd",
    "vectors_frd_from_flu",
    "vectors_ned_from_enu",
]
