"""ROS 1 / ROS 2 bags as datasets: a topic map says which topic is which sensor, messages are converted to
semslam's frames at this border (REP-103/105: ROS world ENU and body FLU -> world NED and body FRD), and a bag
is streamed into a mission directory (scans written one by one: bounded memory on a dive of any length).

Topic map (TOML; ``semslam bag info BAG`` prints a suggestion)::

    [topics]
    scans = "/laser/points"          # sensor_msgs/PointCloud2 (scanner frame; per-point time fields honoured)
    attitude = "/imu/data"           # sensor_msgs/Imu orientation
    dvl = "/dvl/twist"               # geometry_msgs/TwistWithCovarianceStamped, nav_msgs/Odometry (twist), or a
                                     # vendor message with `velocity` and optional `beam_ranges_m`/`beam_valid`
    depth = "/pressure"              # sensor_msgs/FluidPressure (Pa), or nav_msgs/Odometry /
                                     # geometry_msgs/PoseWithCovarianceStamped (z)

    [frames]
    vehicle_frame_id = "base_link"   # the vehicle in /tf_static: T_vehicle_scanner is read from it when present
    attitude = "enu"                 # "enu": REP-103 (ENU world, FLU body); "ned": NED world, FRD body (COLA2)
    dvl = "flu"                      # "flu" (REP-103 body) or "frd"
    depth = "enu"                    # for pose/odometry depth topics: "enu" (depth = -z) or "ned" (depth = z)

Stamps are the messages' header stamps, or the bag's receive time where a header stamp is zero, in seconds from
the whole second before the first message (``metadata["source"]["time_origin_ns"]`` gives it back). A twist with a non-finite velocity, or a vendor message whose beams are all invalid, is a DVL
dropout.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from .._progress import Progress, progress_steps
from .._tables import read_table
from ..errors import BagError, DatasetError
from .vehicle import VehicleDescription

SCAN_TYPES = ("sensor_msgs/msg/PointCloud2",)
ATTITUDE_TYPES = ("sensor_msgs/msg/Imu",)
TWIST_TYPES = ("geometry_msgs/msg/TwistWithCovarianceStamped", "geometry_msgs/msg/TwistStamped",
               "nav_msgs/msg/Odometry")
DEPTH_TYPES = ("sensor_msgs/msg/FluidPressure", "nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseWithCovarianceStamped",
               "geometry_msgs/msg/PoseStamped")
_G = 9.80665


@dataclass(frozen=True)
class TopicMap:
    """Which topic is which sensor, and the frames their messages are in (see the module docstring)."""

    scans: str | None = None
    attitude: str | None = None
    dvl: str | None = None
    depth: str | None = None
    attitude_frame: str = "enu"
    dvl_frame: str = "flu"
    depth_frame: str = "enu"
    #: the vehicle's frame in the bag's /tf_static tree (its axes: FLU, or FRD when ``attitude_frame`` is "ned")
    vehicle_frame_id: str = "base_link"

    def __post_init__(self) -> None:
        for name, allowed in (("attitude_frame", ("enu", "ned")), ("dvl_frame", ("flu", "frd")),
                              ("depth_frame", ("enu", "ned"))):
            if getattr(self, name) not in allowed:
                raise DatasetError(f"The topic map's frames.{name.removesuffix('_frame')} must be one of {allowed}. "
                                   f"Got {getattr(self, name)!r} instead.")
        for name in ("scans", "attitude", "dvl", "depth"):
            v = getattr(self, name)
            if v is not None and (not isinstance(v, str) or not v.startswith("/")):
                raise DatasetError(f"The topic map's topics.{name} must be a topic name starting with '/'. "
                                   f"Got {v!r} instead.")

    def to_toml(self) -> str:
        d = asdict(self)
        lines = ["[topics]"] + [f'{k} = "{d[k]}"' for k in ("scans", "attitude", "dvl", "depth") if d[k]]
        lines += ["", "[frames]"] + [f'{k} = "{d[k + "_frame"]}"' for k in ("attitude", "dvl", "depth")]
        lines.append(f'vehicle_frame_id = "{self.vehicle_frame_id}"')
        return "\n".join(lines) + "\n"

    @classmethod
    def from_dict(cls, d: Any, *, source: str = "topic map") -> "TopicMap":
        if not isinstance(d, dict) or not set(d) <= {"topics", "frames"}:
            raise DatasetError(f"The {source} must have the tables [topics] and [frames] only. Got "
                               f"{sorted(d) if isinstance(d, dict) else type(d).__name__} instead.")
        topics, frames = d.get("topics", {}), d.get("frames", {})
        if not isinstance(topics, dict) or not isinstance(frames, dict):
            raise DatasetError(f"The {source}'s [topics] and [frames] must be tables.")
        known = {"scans", "attitude", "dvl", "depth"}
        for table, keys in (("topics", known), ("frames", (known - {"scans"}) | {"vehicle_frame_id"})):
            extra = sorted(set(d.get(table, {})) - keys)
            if extra:
                raise DatasetError(f"The {source} has unknown key(s) {[f'{table}.{k}' for k in extra]}. Expected "
                                   f"some of {sorted(f'{table}.{k}' for k in keys)}.")
        return cls(**topics, **{k if k == "vehicle_frame_id" else f"{k}_frame": v for k, v in frames.items()})


def read_topic_map(path: str | os.PathLike) -> TopicMap:
    d = read_table(path, "topic map", DatasetError)
    return TopicMap.from_dict(d, source=f"topic map {str(Path(path))!r}")


def suggest_topic_map(bag) -> TopicMap:
    """The busiest topic of each sensor's accepted types (a vendor DVL: a type whose name contains 'dvl')."""
    recs = bag.topics()

    def pick(types, also=lambda r: False):
        cands = [r for r in recs if r.msgtype in types or also(r)]
        return max(cands, key=lambda r: r.count).topic if cands else None

    return TopicMap(scans=pick(SCAN_TYPES), attitude=pick(ATTITUDE_TYPES),
                    dvl=pick(TWIST_TYPES[:2], lambda r: "dvl" in r.msgtype.lower()),
                    depth=pick(DEPTH_TYPES[:1]))


def _stamp_ns(msg, stamp_ns: int) -> int:
    h = getattr(msg, "header", None)
    if h is not None and (h.stamp.sec or h.stamp.nanosec):
        return int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)
    return int(stamp_ns)


def _vec(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z], dtype=np.float64)


class BagDecoder:
    """Turns the mapped topics' messages into semslam's units and frames (one method per sensor)."""

    def __init__(self, topic_map: TopicMap, vehicle: VehicleDescription) -> None:
        self.map, self.vehicle = topic_map, vehicle

    def attitude(self, msg) -> np.ndarray:
        from ..geometry import rpy_from_rotation
        from ..io.ros import imu_to_ned_frd

        if self.map.attitude_frame == "enu":
            return imu_to_ned_frd(msg)[0]
        o = msg.orientation
        from ..geometry import rotation_from_quat_wxyz

        return rpy_from_rotation(rotation_from_quat_wxyz([o.w, o.x, o.y, o.z]))

    def dvl(self, msg, msgtype: str) -> tuple[np.ndarray, bool, np.ndarray | None]:
        ranges = None
        if msgtype == "nav_msgs/msg/Odometry":
            v = _vec(msg.twist.twist.linear)
        elif msgtype == "geometry_msgs/msg/TwistWithCovarianceStamped":
            v = _vec(msg.twist.twist.linear)
        elif msgtype == "geometry_msgs/msg/TwistStamped":
            v = _vec(msg.twist.linear)
        elif hasattr(msg, "velocity"):
            v = _vec(msg.velocity)
            if hasattr(msg, "beam_ranges_m"):
                ranges = np.asarray(msg.beam_ranges_m, dtype=np.float64).copy()
                if hasattr(msg, "beam_valid"):
                    ranges[~np.asarray(msg.beam_valid, dtype=bool)] = np.nan
        else:
            raise BagError(f"The DVL topic {self.map.dvl!r} has type {msgtype}: expected one of {TWIST_TYPES} or a "
                           "vendor message with a 'velocity' field.")
        if self.map.dvl_frame == "flu":
            v = np.array([v[0], -v[1], -v[2]])
        valid = bool(np.isfinite(v).all()) and (ranges is None or bool(np.isfinite(ranges).any()))
        return (v if valid else np.full(3, np.nan)), valid, ranges

    def depth(self, msg, msgtype: str) -> float:
        if msgtype == "sensor_msgs/msg/FluidPressure":
            d = self.vehicle.depth
            return (float(msg.fluid_pressure) - d.atmospheric_pressure_pa) / (d.water_density_kg_m3 * _G)
        pose = msg.pose.pose if msgtype in ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseWithCovarianceStamped") \
            else msg.pose
        z = float(pose.position.z)
        return -z if self.map.depth_frame == "enu" else z


def stream_bag(bag, topic_map: TopicMap, vehicle: VehicleDescription,
               time_origin_ns: list | None = None) -> Iterator[tuple[float, str, Any]]:
    """The mapped topics' messages in bag order as ``(stamp_s, kind, payload)``: ``attitude`` -> rpy (3,),
    ``dvl`` -> (velocity (3,) body FRD, valid, beam ranges or None), ``depth`` -> depth_m, ``scan`` ->
    :class:`~semslam.io.ros.PointCloud2Data`. Checks that every mapped topic exists with an accepted type.

    Stamps are seconds from a time origin: the whole second at or before the first message (integer
    nanoseconds until then, so that float64 keeps sub-microsecond resolution on epoch times); it is stored into
    ``time_origin_ns`` (a one-element list) when given."""
    from ..io.ros import decode_pointcloud2

    kinds = {}
    for kind, types in (("scans", SCAN_TYPES), ("attitude", ATTITUDE_TYPES), ("dvl", ()), ("depth", DEPTH_TYPES)):
        topic = getattr(topic_map, kind)
        if topic is not None:
            rec = bag.require_topic(topic, types)
            kinds[topic] = (kind, rec.msgtype)
    if topic_map.attitude is None:
        raise BagError("The topic map names no attitude topic: the filter needs the attitude as input.")
    dec = BagDecoder(topic_map, vehicle)
    origin = None
    for m in bag.messages(list(kinds)):
        kind, msgtype = kinds[m.topic]
        ns = _stamp_ns(m.msg, m.stamp_ns)
        if origin is None:
            origin = ns - ns % 1_000_000_000
            if time_origin_ns is not None:
                time_origin_ns[:] = [origin]
        t = (ns - origin) / 1e9  # a division: correctly rounded (whole seconds stay exact)
        if kind == "attitude":
            rpy = dec.attitude(m.msg)
            if np.isfinite(rpy).all():
                yield t, "attitude", rpy
        elif kind == "dvl":
            yield t, "dvl", dec.dvl(m.msg, msgtype)
        elif kind == "depth":
            yield t, "depth", dec.depth(m.msg, msgtype)
        else:
            yield t, "scan", decode_pointcloud2(m.msg, source=f"topic {m.topic}")


def static_extrinsic(bag, parent_frame: str, child_frame: str):
    """``T_parent_child`` from the bag's ``/tf_static`` (a chain of static transforms up from ``child_frame``),
    None when the bag has no such chain. Axes as the tree gives them (ROS: FLU bodies)."""
    from ..geometry import RigidTransform

    if not any(r.topic == "/tf_static" for r in bag.topics()):
        return None
    up: dict[str, tuple[str, RigidTransform]] = {}
    for m in bag.messages(["/tf_static"]):
        for tf in getattr(m.msg, "transforms", []):
            q, t = tf.transform.rotation, tf.transform.translation
            T = RigidTransform.from_quat_wxyz([q.w, q.x, q.y, q.z], [t.x, t.y, t.z])
            up[tf.child_frame_id.lstrip("/")] = (tf.header.frame_id.lstrip("/"), T)
    T, frame, seen = RigidTransform.identity(), child_frame.lstrip("/"), set()
    while frame != parent_frame.lstrip("/"):
        if frame not in up or frame in seen:
            return None
        seen.add(frame)
        parent, T_pf = up[frame]
        T, frame = T_pf @ T, parent
    return T


def _vehicle_with_tf(bag, tmap: TopicMap, vehicle: VehicleDescription, scan_frame: str):
    """``vehicle`` with ``T_vehicle_scanner`` from /tf_static when the bag has it (FLU vehicle axes converted to
    FRD unless the map says the bag is NED/FRD)."""
    from dataclasses import replace as dc_replace

    from ..geometry import RigidTransform
    from ..io.ros import C_FRD_FLU

    T = static_extrinsic(bag, tmap.vehicle_frame_id, scan_frame) if scan_frame else None
    if T is None:
        return vehicle, "vehicle file"
    if tmap.attitude_frame == "enu":
        T = RigidTransform.from_rotation_translation(C_FRD_FLU, (0.0, 0.0, 0.0)) @ T
    return vehicle.replace(scanner=dc_replace(vehicle.scanner, T_vehicle_scanner=T)), "/tf_static"


def _write_scan(payload, t: float, scratch: Path, index: int):
    """Write one decoded PointCloud2 as ``scans/scan_NNNNN.pcd`` (a per-point ``t`` field, seconds from the scan's
    first point) and return its :class:`ScanRecord`."""
    from dataclasses import replace as dc_replace

    from ..io import write_point_cloud
    from .logs import ScanRecord

    n = len(payload.points_xyz_m)
    offs = payload.time_offset_s if payload.time_offset_s is not None else np.zeros(n)
    cloud = payload.to_point_cloud()
    fields = {k: v for k, v in cloud.fields.items() if k not in ("t", "time", "timestamp", "time_offset_s")}
    fields["t"] = (offs - offs.min()).astype(np.float64)
    cloud = dc_replace(cloud, fields=fields, frame_id="scanner")
    path = f"scans/scan_{index:05d}.pcd"
    write_point_cloud(scratch / path, cloud, encoding="binary_compressed")
    return ScanRecord(index, t + float(offs.min()), t + float(offs.max()), path, cloud.n_points)


def export_bag(bag_path: str | os.PathLike, out_dir: str | os.PathLike, *, topic_map: TopicMap | None = None,
               vehicle: VehicleDescription | None = None, msg_dirs=(), overwrite: bool = False,
               progress: Progress = False) -> Path:
    """Convert a bag into a mission directory (format 2; scans as PCD with a per-point ``t`` field in seconds
    from the scan's start). Scans are written as they come; the directory appears only when complete."""
    import shutil
    import tempfile

    from ..io.ros import open_bag
    from .dataset import Dataset
    from .logs import AttitudeLog, DepthLog, DvlLog
    from .mission_dir import write_mission

    vehicle = VehicleDescription.girona500() if vehicle is None else vehicle
    out = Path(out_dir)
    if out.exists() and not overwrite:
        raise DatasetError(f"The output directory {str(out)!r} exists: choose another, or overwrite it.")
    out.parent.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".scans", dir=out.parent))
    logs: dict[str, list] = {"attitude": [], "dvl": [], "depth": []}
    records = []
    try:
        with open_bag(bag_path, msg_dirs=msg_dirs) as bag:
            tmap = topic_map or suggest_topic_map(bag)
            total = sum(r.count for r in bag.topics() if r.topic in (tmap.scans, tmap.attitude, tmap.dvl, tmap.depth))
            origin: list = [0]
            extrinsics = None
            with progress_steps(progress, total, "bag", "msg") as step:
                for t, kind, payload in stream_bag(bag, tmap, vehicle, origin):
                    step()
                    if kind != "scan":
                        logs[kind].append((t, payload))
                        continue
                    if extrinsics is None:
                        vehicle, extrinsics = _vehicle_with_tf(bag, tmap, vehicle, payload.frame_id)
                    if payload.points_xyz_m.shape[0]:
                        records.append(_write_scan(payload, t, scratch, len(records)))
        att = sorted(logs["attitude"], key=lambda r: r[0])
        dvl = sorted(logs["dvl"], key=lambda r: r[0])
        dep = sorted(logs["depth"], key=lambda r: r[0])
        nb = max((len(r[1][2]) for r in dvl if r[1][2] is not None), default=0)
        beams = None
        if nb and nb == len(vehicle.dvl.beam_azimuth_rad):
            beams = np.array([r[1][2] if r[1][2] is not None else np.full(nb, np.nan) for r in dvl]).reshape(-1, nb)
        ds = Dataset(vehicle,
                     DvlLog([r[0] for r in dvl], np.array([r[1][0] for r in dvl]).reshape(-1, 3), [r[1][1] for r in dvl],
                            beams),
                     AttitudeLog([r[0] for r in att], np.array([r[1] for r in att]).reshape(-1, 3)),
                     DepthLog([r[0] for r in dep], [r[1] for r in dep]),
                     scans=sorted(records, key=lambda r: r.start_stamp_s), directory=scratch,
                     metadata={"source": {"bag": str(bag_path), "topics": asdict(tmap), "time_origin_ns": origin[0],
                                          "T_vehicle_scanner_from": extrinsics or "vehicle file"}})
        if not len(ds.attitude):
            raise BagError(f"Bag {str(bag_path)!r}: the attitude topic {tmap.attitude!r} has no usable message.")
        return write_mission(ds, out, overwrite=overwrite)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


__all__ = ["TopicMap", "read_topic_map", "suggest_topic_map", "stream_bag", "export_bag", "BagDecoder",
           "SCAN_TYPES", "ATTITUDE_TYPES", "TWIST_TYPES", "DEPTH_TYPES"]
