"""Sources of a dive: one time-ordered stream of typed messages (:mod:`semslam.run.messages`) from a ROS 1/2 bag
(read lazily with rosbags: nothing is written to disk), a dataset directory, or a :class:`~semslam.dataset.Dataset`
in memory (the simulator's). ``open_dive`` picks the source; every consumer (``semslam run``, the benchmarks, the
ROS node's tests) reads a dive through it, so no figure comes from a privileged path.

Frames are never guessed. A bag is read with the topic map and the vehicle file the recorder left beside it
(``BAG.topics.toml``, ``BAG.vehicle.toml``) or the ones given; without a topic map, with the bag's own evidence
(the REP-103 conventions of standard message types, DVL message types whose driver documents its frame,
``/tf_static``); where that is not enough (a twist DVL without a stated frame) it stops with one line that shows
the suggested topic map.

Ground truth is not part of a dive: evaluation reads it after a run, from the source itself
(:func:`semslam.evaluation.slam_run.load_reference`).
"""

from __future__ import annotations

import heapq
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..cloud import POINT_TIME_FIELDS, PointCloud
from ..dataset import Dataset, VehicleDescription
from ..errors import BagError, InputError
from ..geodesy import GeodeticOrigin
from .messages import ORDER, Attitude, Depth, Dvl, Fix, Scan

#: a bag's messages may arrive out of stamp order by up to this much (s) and are reordered; older ones are
#: counted per topic and dropped
REORDER_WINDOW_S = 2.0


@dataclass
class Dive:
    """A dive opened by :func:`open_dive`: the vehicle description, the world frame's geodetic origin (None: a
    local frame, or no fixes), provenance, and the stream of messages (:meth:`messages`, one pass). ``counts``:
    messages per kind, and damaged/late/dropped ones per topic, filled as the stream is read."""

    vehicle: VehicleDescription
    name: str
    kind: str
    geodetic_origin: GeodeticOrigin | None = None
    metadata: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)
    _messages: Any = None

    def messages(self) -> Iterator:
        """The dive's messages in stamp order (see :mod:`semslam.run.messages`); one pass."""
        if self._messages is None:
            raise InputError(f"The dive {self.name!r} was already read: open it again for another pass.")
        it, self._messages = self._messages, None
        return it


def open_dive(source: Any, *, topics: Any = None, vehicle: Any = None, msg_dirs=(), scans: bool = True) -> Dive:
    """Open a dive: a :class:`~semslam.dataset.Dataset`, a dataset directory, or a ROS 1 (``.bag``) / ROS 2 bag.

    Parameters
    ----------
    source : Dataset, str or path
    topics : TopicMap or path, optional
        A bag's topic map (default: ``BAG.topics.toml`` beside the bag, else the bag's own evidence).
    vehicle : VehicleDescription, path or "girona500", optional
        Replaces the dive's vehicle description (default: a mission's ``vehicle.toml``, a bag's
        ``BAG.vehicle.toml``).
    msg_dirs : paths
        Extra ROS message definitions for vendor types.
    scans : bool
        False: the navigation only (detections made before, e.g. from a detections file).
    """
    veh = _vehicle(vehicle)
    if isinstance(source, Dataset):
        return _dataset_dive(source if veh is None else replace(source, vehicle=veh), name="dataset", kind="dataset",
                             scans=scans)
    path = Path(os.fspath(source))
    if (path / "mission.json").is_file():
        from ..dataset import read_dataset

        ds = read_dataset(path)
        return _dataset_dive(ds if veh is None else replace(ds, vehicle=veh), name=str(path), kind="mission",
                             scans=scans)
    if not path.exists():
        raise InputError(f"The dive {str(path)!r} does not exist: expected a ROS bag or a dataset directory.")
    return _bag_dive(path, topics, veh, msg_dirs, scans)


def _vehicle(vehicle: Any) -> VehicleDescription | None:
    if vehicle is None or isinstance(vehicle, VehicleDescription):
        return vehicle
    if vehicle == "girona500":
        return VehicleDescription.girona500()
    from ..dataset import read_vehicle_toml

    return read_vehicle_toml(vehicle)


# ---------------------------------------------------------------------------------------------- datasets
def dataset_messages(ds: Dataset, scans: bool = True) -> Iterator:
    """Every log sample and scan of ``ds`` as messages in stamp order (ties: attitude, DVL, depth, fix, scan;
    scans stamped at their end, when a scanner publishes them)."""
    a, d, z, f = ds.attitude, ds.dvl, ds.depth, ds.fixes
    keys = [(float(t), ORDER["attitude"], i) for i, t in enumerate(a.stamp_s)]
    keys += [(float(t), ORDER["dvl"], i) for i, t in enumerate(d.stamp_s)]
    keys += [(float(t), ORDER["depth"], i) for i, t in enumerate(z.stamp_s)]
    if f is not None:
        keys += [(float(t), ORDER["fix"], i) for i, t in enumerate(f.stamp_s)]
    if scans:
        keys += [(float(r.end_stamp_s), ORDER["scan"], i) for i, r in enumerate(ds.scans)]
    keys.sort()
    beams = d.beam_range_m
    for t, kind, i in keys:
        if kind == ORDER["attitude"]:
            yield Attitude(t, a.rpy_rad[i])
        elif kind == ORDER["dvl"]:
            yield Dvl(t, d.velocity_body_mps[i], bool(d.valid[i]), None if beams is None else beams[i])
        elif kind == ORDER["depth"]:
            yield Depth(t, float(z.depth_m[i]))
        elif kind == ORDER["fix"]:
            yield Fix(t, f.position_ne_m[i], f.covariance_ne_m2[i], f.source[i])
        else:
            rec = ds.scans[i]
            cloud = ds.load_scan(rec.scan_id)
            yield Scan(t, rec.scan_id, rec.start_stamp_s, rec.end_stamp_s, cloud, ds.point_stamps_s(rec, cloud))


def _dataset_dive(ds: Dataset, *, name: str, kind: str, scans: bool = True) -> Dive:
    meta = {"source": {"kind": kind, "path": name}}
    if "source" in ds.metadata:
        meta["recorded_from"] = ds.metadata["source"]
    return Dive(ds.vehicle, name, kind, ds.geodetic_origin, meta, {}, dataset_messages(ds, scans))


# ---------------------------------------------------------------------------------------------- bags
def companion(bag: Path, what: str) -> Path:
    """``BAG.topics.toml`` / ``BAG.vehicle.toml``: the files a recorder (``semslam simulate --format``) leaves beside
    a bag."""
    return bag.with_name(bag.name + f".{what}.toml")


def _bag_dive(path: Path, topics: Any, vehicle: VehicleDescription | None, msg_dirs, scans: bool = True) -> Dive:
    from ..dataset.rosbag import TopicMap, read_topic_map, suggest_topic_map
    from ..io.ros import open_bag

    used: dict = {}
    if isinstance(topics, TopicMap):
        tmap, used["topics"] = topics, "given"
    elif topics is not None:
        tmap, used["topics"] = read_topic_map(topics), str(topics)
    elif companion(path, "topics").is_file():
        tmap, used["topics"] = read_topic_map(companion(path, "topics")), str(companion(path, "topics"))
    else:
        tmap = None
    if vehicle is None:
        if companion(path, "vehicle").is_file():
            from ..dataset import read_vehicle_toml

            vehicle, used["vehicle"] = read_vehicle_toml(companion(path, "vehicle")), str(companion(path, "vehicle"))
        else:
            raise InputError(
                f"The bag {str(path)!r} has no vehicle description: give --vehicle FILE (the scanner's and "
                f"the DVL's mounting; 'girona500' for the documented defaults) or put "
                f"{companion(path, 'vehicle').name!r} beside it."
            )
    else:
        used["vehicle"] = "given"
    bag = open_bag(path, msg_dirs=msg_dirs)
    try:
        if tmap is None:
            tmap = suggest_topic_map(bag)
            used["topics"] = "the bag's own evidence (bag info's suggestion)"
            _check_evidence(bag, tmap, path)
        tmap = _resolve_dvl_frame(bag, tmap, path)
        vehicle, how = _mounting_at_open(bag, tmap, vehicle)
        used["T_vehicle_scanner_from"] = how
    except BaseException:
        bag.close()
        raise
    if not scans:
        tmap = replace(tmap, scans=None)
    origin = GeodeticOrigin.from_dict(tmap.origin) if tmap.origin is not None else None
    dive = Dive(vehicle, str(path), "bag", origin, {"source": {"kind": "bag", "path": str(path), **used},
                                                   "topics": tmap.to_toml()}, {}, None)
    dive._messages = _bag_messages(bag, tmap, dive)
    return dive


def _check_evidence(bag, tmap, path: Path) -> None:
    """Without a topic map, run only when the bag's evidence establishes every frame (see the module docstring)."""
    if tmap.attitude is None:
        raise BagError(f"The bag {str(path)!r} has no sensor_msgs/Imu topic for the attitude: give --topics FILE "
                       f"(`semslam bag info {path}` suggests one).")


def _resolve_dvl_frame(bag, tmap, path: Path):
    """The DVL's frame from the topic map when it states one, else from the message type when its driver documents
    it; otherwise an error showing the suggested map (never a guess)."""
    if tmap.dvl is None:
        return tmap
    if tmap.dvl_frame is not None:
        return tmap
    from ..io.ros.dvl import topic_dvl_convention

    rec = next((r for r in bag.topics() if r.topic == tmap.dvl), None)
    conv = topic_dvl_convention(bag, tmap.dvl) if rec is not None else None
    if conv is None:
        raise BagError(f"The frame of the DVL topic {tmap.dvl!r} ({rec.msgtype if rec else 'missing'}) cannot be "
                       f"established from the bag: state it in a topic map ([frames] dvl = \"frd\" or \"flu\") and "
                       f"give it with --topics. Suggested map:\n{tmap.to_toml()}")
    return replace(tmap, dvl_frame=conv)


def _bag_messages(bag, tmap, dive: Dive) -> Iterator:
    """The bag's mapped messages as typed messages in stamp order (a reorder window of :data:`REORDER_WINDOW_S`);
    closes the bag at the end."""
    from ..dataset.rosbag import stream_bag
    from .damage import damaged_per_topic

    counts = dive.counts
    late: dict = counts.setdefault("late_dropped", {})
    counts["damage"] = bag.damage  # damaged records per topic, filled as the bag is read (semslam.run.damage)
    heap: list = []
    seq = 0
    released = -math.inf
    newest = -math.inf
    origin_ns: list = [0]
    scan_id = 0
    geo = dive.geodetic_origin
    try:
        for t, kind, payload in stream_bag(bag, tmap, dive.vehicle, origin_ns, on_damage="count"):
            dive.metadata["time_origin_ns"] = origin_ns[0]
            if kind == "scan":
                if not payload.points_xyz_m.shape[0]:
                    counts["empty_scans"] = counts.get("empty_scans", 0) + 1
                    continue
                msg = _scan_message(payload, t, scan_id)
                scan_id += 1
            elif kind == "fix":
                if geo is None:
                    geo = _origin_from_fix(payload)
                    if geo is not None:
                        dive.geodetic_origin = geo
                        dive.metadata["geodetic_origin_from"] = "the first usable fix"
                msg = _fix_message(payload, t, geo)
            elif kind == "attitude":
                msg = Attitude(t, payload)
            elif kind == "dvl":
                msg = Dvl(t, payload[0], bool(payload[1]), payload[2])
            else:
                msg = Depth(t, float(payload))
            newest = max(newest, msg.stamp_s)
            if msg.stamp_s < released:
                late[kind] = late.get(kind, 0) + 1
                continue
            heapq.heappush(heap, (msg.stamp_s, ORDER[msg.kind], seq, msg))
            seq += 1
            while heap and heap[0][0] <= newest - REORDER_WINDOW_S:
                item = heapq.heappop(heap)
                released = item[0]
                counts[item[3].kind] = counts.get(item[3].kind, 0) + 1
                yield item[3]
        while heap:
            item = heapq.heappop(heap)
            counts[item[3].kind] = counts.get(item[3].kind, 0) + 1
            yield item[3]
    finally:
        counts["damaged"] = damaged_per_topic(bag.damage)
        bag.close()


def _mounting_at_open(bag, tmap, vehicle):
    """``vehicle`` with the scanner's mounting from the bag's ``/tf_static`` when it has it (the first scan's
    frame id names the scanner), before the run starts: every scan is then placed with the same mounting."""
    from ..dataset.rosbag import _vehicle_with_tf

    if tmap.scans is None:
        return vehicle, "vehicle file"
    frame = None
    for m in bag.messages([tmap.scans]):
        frame = getattr(getattr(m.msg, "header", None), "frame_id", None)
        break
    return _vehicle_with_tf(bag, tmap, vehicle, frame) if frame else (vehicle, "vehicle file")


def _scan_message(payload, t: float, scan_id: int) -> Scan:
    """A decoded PointCloud2 as a :class:`Scan`: per-point stamps from its time field (else every point at the
    header stamp), the scan stamped at its last point."""
    fields = {k: v for k, v in payload.fields.items() if k not in POINT_TIME_FIELDS}  # the stamps go to the Scan
    cloud = PointCloud(payload.points_xyz_m, intensity=payload.intensity, frame_id="scanner", fields=fields)
    n = len(payload.points_xyz_m)
    offs = payload.time_offset_s if payload.time_offset_s is not None else np.zeros(n)
    stamps = t + np.asarray(offs, dtype=float)
    start, end = float(stamps.min()), float(stamps.max())
    return Scan(end, scan_id, start, end, cloud, stamps if payload.time_offset_s is not None else None)


def _origin_from_fix(payload) -> GeodeticOrigin | None:
    lat, lon, _, cov, _ = payload
    if not (np.isfinite([lat, lon]).all() and np.isfinite(cov).all() and abs(lat) < 90 and abs(lon) <= 180):
        return None
    return GeodeticOrigin(lat, lon, 0.0)


def _fix_message(payload, t: float, geo: GeodeticOrigin | None) -> Fix:
    lat, lon, _, cov, source = payload
    ne = np.full(2, np.nan)
    if geo is not None and np.isfinite([lat, lon]).all() and abs(lat) <= 90 and abs(lon) <= 180:
        ne = geo.ned_from_geodetic_deg(lat, lon, 0.0)[0, 0:2]
    return Fix(t, ne, np.asarray(cov, dtype=float), source)
