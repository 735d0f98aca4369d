"""``/semslam/detections`` as ``semslam_msgs/DetectionArray`` (no rospy here).

Debian 12 ships no ``vision_msgs`` (neither ``python3-vision-msgs`` nor ``ros-vision-msgs``), so the node
publishes semslam's own message, whose definitions are packaged in ``semslam/io/ros/msg/semslam_msgs/msg/``
(``Detection.msg``, ``DetectionArray.msg``). genmsg-generated Python classes cannot be built for a package that is
not in Debian's ROS, so the message is serialized with rosbags (``serialize_ros1``) and published raw, with the
type, md5sum and full definition rosbags computes from those files: any subscriber (``rospy.AnyMsg``,
``rosbag record``, rosbags, a C++ node built with the packaged definitions) decodes it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["DETECTION_ARRAY", "detection_array_bytes", "detection_array_spec"]

#: the rosbags name of the message
DETECTION_ARRAY = "semslam_msgs/msg/DetectionArray"
_STORE: list = []


def _store():
    if not _STORE:
        from ...io.ros._types import semslam_typestore

        _STORE.append(semslam_typestore(ros1=True))
    return _STORE[0]


def detection_array_spec() -> tuple[str, str, str]:
    """``(ROS 1 type "semslam_msgs/DetectionArray", md5sum, full message definition)``: a publisher's connection
    header."""
    full_text, md5 = _store().generate_msgdef(DETECTION_ARRAY)
    return "semslam_msgs/DetectionArray", md5, full_text


def detection_array_bytes(stamp_ns: int, frame_id: str, scan_id: int, detections, seq: int = 0) -> bytes:
    """The ROS 1 serialization of one scan's detections (:class:`semslam.detection.Detection`, poses in the
    scanner frame ``frame_id``) stamped ``stamp_ns``."""
    store = _store()
    T = store.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    PoseCov, Pose = T["geometry_msgs/msg/PoseWithCovariance"], T["geometry_msgs/msg/Pose"]
    Point, Quat = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]
    Det, Arr = T["semslam_msgs/msg/Detection"], T["semslam_msgs/msg/DetectionArray"]
    items: list[Any] = []
    for d in detections:
        p = np.asarray(d.T_sensor_object.translation_m, dtype=float)
        w, x, y, z = (float(v) for v in d.T_sensor_object.as_quat_wxyz())
        cov = np.asarray(d.covariance_6x6, dtype=np.float64).reshape(36)
        items.append(Det(label=str(d.label), score=float(d.score), score_kind=str(d.score_kind),
                         pose=PoseCov(pose=Pose(position=Point(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                                                orientation=Quat(x=x, y=y, z=z, w=w)), covariance=cov.copy()),
                         reliable=bool(d.reliable), n_points=int(d.n_points)))
    ns = int(stamp_ns)
    msg = Arr(header=Header(seq=int(seq), stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000),
                            frame_id=str(frame_id)), scan_id=int(scan_id), detections=items)
    return bytes(store.serialize_ros1(msg, DETECTION_ARRAY))
