"""The topic map of a bag or of the ROS node: which topic is which sensor, the frames their messages are in and the
world frame's geodetic origin (the TOML layout: :mod:`semslam.dataset.rosbag`), and the message types each sensor
accepts."""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from .._tables import read_table
from ..errors import DatasetError

__all__ = ["ATTITUDE_TYPES", "DEPTH_TYPES", "DVL_TYPES", "FIX_TYPES", "SCAN_TYPES", "TWIST_TYPES", "TopicMap",
           "read_topic_map", "suggest_topic_map"]

SCAN_TYPES = ("sensor_msgs/msg/PointCloud2",)
FIX_TYPES = ("sensor_msgs/msg/NavSatFix",)
ATTITUDE_TYPES = ("sensor_msgs/msg/Imu",)
TWIST_TYPES = ("geometry_msgs/msg/TwistWithCovarianceStamped", "geometry_msgs/msg/TwistStamped",
               "nav_msgs/msg/Odometry")
#: DVL message types whose frame convention the type documents (semslam.io.ros.dvl)
DVL_TYPES = ("semslam_msgs/msg/Dvl", "waterlinked_a50_ros_driver/msg/DVL", "dvl_msgs/msg/DVL", "cola2_msgs/msg/DVL",
             "uuv_sensor_ros_plugins_msgs/msg/DVL", "marine_acoustic_msgs/msg/Dvl")
DEPTH_TYPES = ("sensor_msgs/msg/FluidPressure", "nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseWithCovarianceStamped",
               "geometry_msgs/msg/PoseStamped")


@dataclass(frozen=True)
class TopicMap:
    """Which topic is which sensor, and the frames their messages are in (see the module docstring)."""

    scans: str | None = None
    attitude: str | None = None
    dvl: str | None = None
    depth: str | None = None
    gps: str | None = None
    usbl: str | None = None
    attitude_frame: str = "enu"
    #: the DVL's axes ("frd" or "flu"); None: the ones its message type documents (an error when it documents none)
    dvl_frame: str | None = None
    depth_frame: str = "enu"
    #: the vehicle's frame in the bag's /tf_static tree (its axes: FLU, or FRD when ``attitude_frame`` is "ned")
    vehicle_frame_id: str = "base_link"
    #: the world frame's geodetic origin ({latitude_deg, longitude_deg[, height_m]}), None: the first usable fix
    origin: dict | None = None

    def __post_init__(self) -> None:
        if self.origin is not None:
            from ..geodesy import GeodeticOrigin

            GeodeticOrigin.from_dict(self.origin, source="topic map's [origin]")  # checked here, one line if bad
        for name, allowed in (("attitude_frame", ("enu", "ned")), ("dvl_frame", ("flu", "frd", None)),
                              ("depth_frame", ("enu", "ned"))):
            if getattr(self, name) not in allowed:
                raise DatasetError(f"The topic map's frames.{name.removesuffix('_frame')} must be one of {allowed}. "
                                   f"Got {getattr(self, name)!r} instead.")
        for name in ("scans", "attitude", "dvl", "depth", "gps", "usbl"):
            v = getattr(self, name)
            if v is not None and (not isinstance(v, str) or not v.startswith("/")):
                raise DatasetError(f"The topic map's topics.{name} must be a topic name starting with '/'. "
                                   f"Got {v!r} instead.")
        if not isinstance(self.vehicle_frame_id, str) or not self.vehicle_frame_id.strip("/ "):
            raise DatasetError(f"The topic map's frames.vehicle_frame_id must be a frame name (a non-empty string). "
                               f"Got {self.vehicle_frame_id!r} instead.")
        named = [
            (n, getattr(self, n)) for n in ("scans", "attitude", "dvl", "depth", "gps", "usbl") if getattr(self, n)
        ]
        for i, (a, ta) in enumerate(named):  # one sensor per topic: a second one was silently dropped
            for b, tb in named[i + 1:]:
                if ta == tb:
                    raise DatasetError(f"The topic map's topics.{a} and topics.{b} name the same topic {ta!r}: "
                                       "semslam reads one sensor per topic.")

    def to_toml(self) -> str:
        d = asdict(self)
        lines = ["[topics]"] + [f'{k} = "{d[k]}"' for k in ("scans", "attitude", "dvl", "depth", "gps", "usbl") if d[k]]
        lines += ["", "[frames]"] + [f'{k} = "{d[k + "_frame"]}"' for k in ("attitude", "dvl", "depth")
                                     if d[k + "_frame"] is not None]
        lines.append(f'vehicle_frame_id = "{self.vehicle_frame_id}"')
        if self.origin is not None:
            lines += ["", "[origin]"] + [f"{k} = {float(v)!r}" for k, v in self.origin.items()]
        return "\n".join(lines) + "\n"

    @classmethod
    def from_dict(cls, d: Any, *, source: str = "topic map") -> "TopicMap":
        if not isinstance(d, dict) or not set(d) <= {"topics", "frames", "origin"}:
            raise DatasetError(f"The {source} must have the tables [topics], [frames] and [origin] only. Got "
                               f"{sorted(d) if isinstance(d, dict) else type(d).__name__} instead.")
        topics, frames = d.get("topics", {}), d.get("frames", {})
        if not isinstance(topics, dict) or not isinstance(frames, dict):
            raise DatasetError(f"The {source}'s [topics] and [frames] must be tables.")
        known = {"scans", "attitude", "dvl", "depth"}
        for table, keys in (
            ("topics", known | {"gps", "usbl"}),
            ("frames", (known - {"scans"}) | {"vehicle_frame_id"}),
        ):
            extra = sorted(set(d.get(table, {})) - keys)
            if extra:
                raise DatasetError(f"The {source} has unknown key(s) {[f'{table}.{k}' for k in extra]}. Expected "
                                   f"some of {sorted(f'{table}.{k}' for k in keys)}.")
        origin = d.get("origin")
        if origin is not None:
            from ..geodesy import GeodeticOrigin
            from ..errors import SemslamError

            try:
                origin = GeodeticOrigin.from_dict(origin, source=f"{source}'s [origin]").as_dict()
            except SemslamError as exc:
                raise DatasetError(str(exc)) from None
        try:
            return cls(**topics, **{k if k == "vehicle_frame_id" else f"{k}_frame": v for k, v in frames.items()},
                       origin=origin)
        except DatasetError as exc:  # __post_init__'s one line, naming the file
            raise DatasetError(str(exc).replace("The topic map's ", f"The {source}: ", 1)) from None


def read_topic_map(path: str | os.PathLike) -> TopicMap:
    d = read_table(path, "topic map", DatasetError)
    return TopicMap.from_dict(d, source=f"topic map {str(Path(path))!r}")


def suggest_topic_map(bag) -> TopicMap:
    """The busiest topic of each sensor's accepted types. The DVL: a DVL message type semslam knows
    (:data:`DVL_TYPES`, its frame set from the type), else a vendor type whose name contains 'dvl', else a
    twist (frame left at the default: the type does not say)."""
    from ..io.ros.dvl import topic_dvl_convention

    recs = bag.topics()

    def pick(types, also=lambda r: False):
        cands = [r for r in recs if r.msgtype in types or also(r)]
        return max(cands, key=lambda r: r.count).topic if cands else None

    dvl = (pick(DVL_TYPES) or pick((), lambda r: "dvl" in r.msgtype.lower() and r.msgtype not in DVL_TYPES)
           or pick(TWIST_TYPES[:2]))
    dvl_frame = topic_dvl_convention(bag, dvl) if dvl is not None else None
    return TopicMap(scans=pick(SCAN_TYPES), attitude=pick(ATTITUDE_TYPES), dvl=dvl,
                    depth=pick(DEPTH_TYPES[:1]), gps=pick(FIX_TYPES), **({"dvl_frame": dvl_frame} if dvl_frame else {}))
