"""ROS 1 / ROS 2 bags as datasets: a topic map says which topic is which sensor, messages are converted to
semslam's frames at this border (REP-103/105: ROS world ENU and body FLU -> world NED and body FRD), and a bag
is streamed into a dataset directory (scans written one by one: bounded memory on a dive of any length).

Topic map (TOML; ``semslam bag info BAG`` prints a suggestion)::

    [topics]
    scans = "/laser/points"          # sensor_msgs/PointCloud2 (scanner frame; per-point time fields honoured)
    attitude = "/imu/data"           # sensor_msgs/Imu orientation
    dvl = "/dvl/data"                # a DVL message (semslam.io.ros.dvl: COLA2, Water Linked, UUV Simulator,
                                     # marine_acoustic_msgs, semslam_msgs), geometry_msgs/TwistWithCovarianceStamped,
                                     # nav_msgs/Odometry (twist), or a vendor message with `velocity` and optional
                                     # `beam_ranges_m`/`beam_valid`
    depth = "/pressure"              # sensor_msgs/FluidPressure (Pa), or nav_msgs/Odometry /
                                     # geometry_msgs/PoseWithCovarianceStamped (z)
    gps = "/gps/fix"                 # sensor_msgs/NavSatFix (optional): surface position fixes
    usbl = "/usbl/fix"               # sensor_msgs/NavSatFix (optional): acoustic fixes during the dive

    [origin]                         # optional: the world frame's geodetic origin (else the first usable fix)
    latitude_deg = 41.9785
    longitude_deg = 2.8053

    [frames]
    vehicle_frame_id = "base_link"   # the vehicle in /tf_static: T_vehicle_scanner is read from it when present
    attitude = "enu"                 # "enu": REP-103 (ENU world, FLU body); "ned": NED world, FRD body (COLA2)
    dvl = "flu"                      # "flu" (REP-103 body) or "frd"; only for types that do not document theirs
    depth = "enu"                    # for pose/odometry depth topics: "enu" (depth = -z) or "ned" (depth = z)

Stamps are the messages' header stamps, or the bag's receive time where a header stamp is zero, in seconds from
the whole second before the first message (``metadata["source"]["time_origin_ns"]`` gives it back). A twist with a
non-finite velocity, or a vendor message whose beams are all invalid, is a DVL
dropout.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from .._progress import Progress, progress_steps
from ..cloud import POINT_TIME_FIELDS
from ..errors import BagError, DatasetError, SemslamError
from ..limits import check as check_limit
from .topic_map import (ATTITUDE_TYPES, DEPTH_TYPES, DVL_TYPES, FIX_TYPES, SCAN_TYPES,  # noqa: F401 - re-exported
                        TWIST_TYPES, TopicMap, read_topic_map, suggest_topic_map)
from .vehicle import VehicleDescription

_G = 9.80665


def _stamp_ns(msg, stamp_ns: int) -> int:
    h = getattr(msg, "header", None)
    if h is not None and (h.stamp.sec or h.stamp.nanosec):
        return int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)
    return int(stamp_ns)


class BagDecoder:
    """Turns the mapped topics' messages into semslam's units and frames (one method per sensor)."""

    def __init__(self, topic_map: TopicMap, vehicle: VehicleDescription) -> None:
        self.map, self.vehicle = topic_map, vehicle

    def attitude(self, msg) -> np.ndarray:
        o = msg.orientation
        norm = math.hypot(float(o.w), float(o.x), float(o.y), float(o.z))  # no overflow at 1e300
        if not math.isnan(norm):  # NaN: no orientation, skipped by stream_bag
            check_limit("bag.quaternion_norm", norm, f"The attitude topic {self.map.attitude!r}: an orientation "
                        "quaternion's norm", error=BagError)
        from ..geometry import rpy_from_rotation
        from ..io.ros import imu_rpy_ned_frd

        if self.map.attitude_frame == "enu":
            return imu_rpy_ned_frd(msg)
        o = msg.orientation
        from ..geometry import rotation_from_quat_wxyz

        return rpy_from_rotation(rotation_from_quat_wxyz([o.w, o.x, o.y, o.z]))

    def dvl(self, msg, msgtype: str) -> tuple[np.ndarray, bool, np.ndarray | None]:
        """(velocity (3,) FRD axes of the DVL frame, valid, beam slant ranges or None). The topic map's
        ``frames.dvl`` when it states one (the user's word: it overrides the type's), else the frame the type
        documents (:mod:`semslam.io.ros.dvl`: COLA2, Water Linked, UUV Simulator, marine_acoustic_msgs, semslam's);
        neither is an error, never a guess."""
        from ..io.ros.dvl import decode_dvl, velocity_frd_from

        r = decode_dvl(msg, msgtype, source=f"DVL topic {self.map.dvl!r}")
        v = velocity_frd_from(r.velocity_mps, self.map.dvl_frame) if self.map.dvl_frame else r.velocity_frd_mps()
        return (v if r.valid else np.full(3, np.nan)), r.valid, r.beam_ranges_m

    def depth(self, msg, msgtype: str) -> float:
        where = f"The depth topic {self.map.depth!r}"
        if msgtype == "sensor_msgs/msg/FluidPressure":
            d = self.vehicle.depth
            p = check_limit("bag.fluid_pressure_pa", float(msg.fluid_pressure), f"{where}: a fluid_pressure",
                            error=BagError)
            return (p - d.atmospheric_pressure_pa) / (d.water_density_kg_m3 * _G)
        pose = msg.pose.pose if msgtype in ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseWithCovarianceStamped") \
            else msg.pose
        z = float(pose.position.z)
        return check_limit("nav.depth_m", -z if self.map.depth_frame == "enu" else z, f"{where}: a depth",
                           error=BagError)


#: a header stamp later than its bag receive time by more than this is outside the dive (a message cannot be recorded
#: before it was stamped; allows this much clock offset between the sensor and the recorder) (s)
STAMP_AHEAD_LIMIT_S = 2.0
#: a header stamp earlier than the bag's first receive time by more than this is outside the dive (s)
STAMP_BEFORE_START_LIMIT_S = 60.0


def stream_bag(bag, topic_map: TopicMap, vehicle: VehicleDescription,
               time_origin_ns: list | None = None, *, on_damage: str = "raise") -> Iterator[tuple[float, str, Any]]:
    """The mapped topics' messages in bag order as ``(stamp_s, kind, payload)``: ``attitude`` -> rpy (3,),
    ``dvl`` -> (velocity (3,) body FRD, valid, beam ranges or None), ``depth`` -> depth_m, ``scan`` ->
    :class:`~semslam.io.ros.PointCloud2Data`, ``fix`` -> (latitude_deg, longitude_deg, height_m, covariance
    north/east (2, 2) m^2 (NaN when the receiver has no fix or does not know it), source ``"gps"``/``"usbl"``).
    Checks that every mapped topic exists with an accepted type.

    Stamps are seconds from a time origin: the whole second at or before the bag's first message, whatever its
    topic (integer
    nanoseconds until then, so that float64 keeps sub-microsecond resolution on epoch times); it is stored into
    ``time_origin_ns`` (a one-element list) when given.

    ``on_damage="count"``: damaged records (see :meth:`semslam.io.ros.Bag.messages`) and messages stamped outside
    the dive (a header stamp more than :data:`STAMP_AHEAD_LIMIT_S` after its receive time, or more than
    :data:`STAMP_BEFORE_START_LIMIT_S` before the bag's start) are counted in ``bag.damage`` per topic and skipped;
    ``"raise"``: a BagError."""
    kinds = _mapped_topics(bag, topic_map)
    dec = BagDecoder(topic_map, vehicle)
    # the clock's origin: the whole second before the bag's first message over ALL its topics, so that two readings
    # of one bag with different topic maps (with and without the GPS, say) share one clock
    start = getattr(bag, "start_time_ns", None)
    origin = None if start is None else start - start % 1_000_000_000
    if origin is not None and time_origin_ns is not None:
        time_origin_ns[:] = [origin]
    damage = getattr(bag, "damage", None) if on_damage == "count" else None
    if damage is not None:
        damage.setdefault("invalid", {})
    decoded: dict[str, int] = {}
    for m in bag.messages(list(kinds), **({"on_damage": on_damage} if on_damage != "raise" else {})):
        kind, msgtype = kinds[m.topic]
        ns = _stamp_ns(m.msg, m.stamp_ns)
        where = _outside_dive(ns, m.stamp_ns, start)
        if where is not None:
            if damage is None:
                raise BagError(f"Bag '{getattr(bag, 'path', '?')}': topic '{m.topic}' has a message stamped "
                               f"{ns} ns, outside the dive (received at {m.stamp_ns} ns, the bag starts at {start} "
                               f"ns).")
            damage[where][m.topic] = damage[where].get(m.topic, 0) + 1
            continue
        if origin is None:
            origin = ns - ns % 1_000_000_000
            if time_origin_ns is not None:
                time_origin_ns[:] = [origin]
        t = (ns - origin) / 1e9  # a division: correctly rounded (whole seconds stay exact)
        try:
            item = _decoded(dec, kind, msgtype, m, t, ns)
        except SemslamError as err:  # a value out of its plausible range, a payload that does not parse
            # counted as damage; the first messages of a topic all failing is a systematic error: raised
            if damage is None or (not decoded.get(m.topic) and damage["invalid"].get(m.topic, 0) + 1 >= 20):
                raise
            damage["invalid"][m.topic] = damage["invalid"].get(m.topic, 0) + 1
            damage.setdefault("first_error", {}).setdefault(m.topic, str(err))
            continue
        decoded[m.topic] = decoded.get(m.topic, 0) + 1
        if item is not None:
            yield item


def _mapped_topics(bag, topic_map: TopicMap) -> dict[str, tuple[str, str]]:
    """``{topic: (sensor, message type)}`` of the mapped topics, each checked to exist with an accepted type; a
    :class:`BagError` without an attitude topic."""
    kinds = {}
    for kind, types in (("scans", SCAN_TYPES), ("attitude", ATTITUDE_TYPES), ("dvl", ()), ("depth", DEPTH_TYPES),
                        ("gps", FIX_TYPES), ("usbl", FIX_TYPES)):
        topic = getattr(topic_map, kind)
        if topic is not None:
            rec = bag.require_topic(topic, types)
            kinds[topic] = (kind, rec.msgtype)
    if topic_map.attitude is None:
        raise BagError("The topic map names no attitude topic: the filter needs the attitude as input.")
    return kinds


def _outside_dive(ns: int, receive_ns: int, start: int | None) -> str | None:
    """``"stamp_ahead"`` / ``"stamp_before_start"`` for a header stamp ``ns`` outside the dive (see
    :data:`STAMP_AHEAD_LIMIT_S`, :data:`STAMP_BEFORE_START_LIMIT_S`), else None."""
    return ("stamp_ahead" if ns - receive_ns > STAMP_AHEAD_LIMIT_S * 1e9 else "stamp_before_start"
            if start is not None and ns < start - STAMP_BEFORE_START_LIMIT_S * 1e9 else None)


def _decoded(dec: "BagDecoder", kind: str, msgtype: str, m, t: float, ns: int) -> tuple[float, str, Any] | None:
    """The bag message ``m`` of sensor ``kind`` as ``(t, kind, payload)`` (see :func:`stream_bag`; None: an
    attitude without orientation)."""
    from ..io.ros import decode_pointcloud2

    if kind == "attitude":
        rpy = dec.attitude(m.msg)
        item = (t, "attitude", rpy) if np.isfinite(rpy).all() else None
    elif kind == "dvl":
        item = (t, "dvl", dec.dvl(m.msg, msgtype))
    elif kind == "depth":
        item = (t, "depth", dec.depth(m.msg, msgtype))
    elif kind in ("gps", "usbl"):
        item = (t, "fix", navsatfix_ne(m.msg) + (kind,))
    else:
        pc = decode_pointcloud2(m.msg, source=f"topic {m.topic}")
        bad = 0 if pc.time_offset_s is None else int((~np.isfinite(pc.time_offset_s)).sum())
        if bad:  # its stamp (the last point's) would be NaN
            raise BagError(f"The scan topic {m.topic!r}: a message at {ns} ns has {bad} of "
                           f"{len(pc.time_offset_s)} per-point times that are not finite.")
        item = (t, "scan", pc)
    return item


def navsatfix_ne(msg) -> tuple[float, float, float, np.ndarray]:
    """A ``sensor_msgs/NavSatFix`` as (latitude_deg, longitude_deg, height_m, covariance (2, 2) m^2 north/east). The
    message's covariance is ENU (REP-103) row-major; a fix whose status is below STATUS_FIX (0), whose covariance
    type is COVARIANCE_TYPE_UNKNOWN (0), or whose numbers are not finite gets a NaN covariance: not usable."""
    c = np.asarray(msg.position_covariance, dtype=np.float64).reshape(3, 3)
    cov = np.array([[c[1, 1], c[1, 0]], [c[0, 1], c[0, 0]]])
    status = int(getattr(getattr(msg, "status", None), "status", 0))
    if status < 0 or int(msg.position_covariance_type) == 0 or not np.isfinite(cov).all():
        cov = np.full((2, 2), np.nan)
    return float(msg.latitude), float(msg.longitude), float(msg.altitude), cov


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
    fields = {k: v for k, v in cloud.fields.items() if k not in POINT_TIME_FIELDS}
    fields["t"] = (offs - offs.min()).astype(np.float64)
    cloud = dc_replace(cloud, fields=fields, frame_id="scanner")
    path = f"scans/scan_{index:05d}.pcd"
    write_point_cloud(scratch / path, cloud, encoding="binary_compressed")
    return ScanRecord(index, t + float(offs.min()), t + float(offs.max()), path, cloud.n_points)


def fixes_in_local_frame(rows, origin: dict | None):
    """``[(stamp_s, (lat, lon, h, cov_ne, source))]`` as a :class:`PositionFixLog` in local NED about ``origin`` (the
    topic map's), else about the first usable fix; ``(None, None)`` without fixes."""
    from ..geodesy import GeodeticOrigin
    from .logs import PositionFixLog

    if not rows:
        return None, None
    if origin is not None:
        geo = GeodeticOrigin.from_dict(origin)
    else:
        first = next((p for _, p in rows if np.isfinite(p[3]).all() and np.isfinite(p[:3]).all()), None)
        if first is None:
            return None, None
        geo = GeodeticOrigin(first[0], first[1], 0.0)
    lat = np.array([p[0] for _, p in rows])
    lon = np.array([p[1] for _, p in rows])
    ok = np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90) & (np.abs(lon) <= 180)
    ne = np.full((len(rows), 2), np.nan)
    if ok.any():
        ne[ok] = geo.ned_from_geodetic_deg(lat[ok], lon[ok], 0.0)[:, 0:2]
    cov = np.array([p[3] for _, p in rows]).reshape(-1, 2, 2)
    return PositionFixLog([t for t, _ in rows], ne, cov, tuple(p[4] for _, p in rows)), geo


def export_bag(bag_path: str | os.PathLike, out_dir: str | os.PathLike, *, topic_map: TopicMap | None = None,
               vehicle: VehicleDescription | None = None, msg_dirs=(), overwrite: bool = False,
               progress: Progress = False) -> Path:
    """Convert a bag into a dataset directory (format 2; scans as PCD with a per-point ``t`` field in seconds
    from the scan's start). Scans are written as they come; the directory appears only when complete."""
    import shutil

    from .._outdir import check_output_dir, staging_dir
    from ..io.ros import open_bag
    from .dataset import Dataset
    from .logs import AttitudeLog, DepthLog, DvlLog
    from .directory import write_dataset

    vehicle = VehicleDescription.girona500() if vehicle is None else vehicle
    out = Path(out_dir)
    # before any work: only an earlier mission semslam proves it wrote is replaced, never the bag (semslam._outdir)
    check_output_dir(out, overwrite=overwrite, kind="mission", inputs=(bag_path,))
    if out.exists() and not overwrite:
        raise DatasetError(f"The output directory {str(out)!r} exists: choose another, or overwrite it.")
    scratch = staging_dir(out, "scans")
    logs: dict[str, list] = {"attitude": [], "dvl": [], "depth": [], "fix": []}
    records = []
    try:
        with open_bag(bag_path, msg_dirs=msg_dirs) as bag:
            tmap = topic_map or suggest_topic_map(bag)
            total = sum(r.count for r in bag.topics()
                        if r.topic in (tmap.scans, tmap.attitude, tmap.dvl, tmap.depth, tmap.gps, tmap.usbl))
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
        fixes, geo = fixes_in_local_frame(sorted(logs["fix"], key=lambda r: r[0]), tmap.origin)
        nb = max((len(r[1][2]) for r in dvl if r[1][2] is not None), default=0)
        beams = None
        if nb and nb == len(vehicle.dvl.beam_azimuth_rad):
            beams = np.array([r[1][2] if r[1][2] is not None else np.full(nb, np.nan) for r in dvl]).reshape(-1, nb)
        ds = Dataset(
            vehicle,
            DvlLog([r[0] for r in dvl], np.array([r[1][0] for r in dvl]).reshape(-1, 3), [r[1][1] for r in dvl], beams),
            AttitudeLog([r[0] for r in att], np.array([r[1] for r in att]).reshape(-1, 3)),
            DepthLog([r[0] for r in dep], [r[1] for r in dep]),
            scans=sorted(records, key=lambda r: r.start_stamp_s),
            directory=scratch,
            metadata={
                "source": {
                    "bag": str(bag_path),
                    "topics": asdict(tmap),
                    "time_origin_ns": origin[0],
                    "T_vehicle_scanner_from": extrinsics or "vehicle file",
                }
            },
            fixes=fixes,
            geodetic_origin=geo,
        )
        if not len(ds.attitude):
            raise BagError(f"Bag {str(bag_path)!r}: the attitude topic {tmap.attitude!r} has no usable message.")
        return write_dataset(ds, out, overwrite=overwrite)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


__all__ = ["TopicMap", "read_topic_map", "suggest_topic_map", "stream_bag", "STAMP_AHEAD_LIMIT_S",
           "STAMP_BEFORE_START_LIMIT_S", "export_bag", "BagDecoder", "FIX_TYPES",
           "navsatfix_ne",
           "SCAN_TYPES", "ATTITUDE_TYPES", "TWIST_TYPES", "DVL_TYPES", "DEPTH_TYPES"]
