"""Live ROS 1 messages decoded exactly as the bag reader decodes them.

The node subscribes with ``rospy.AnyMsg``: it receives each message's serialized bytes and the connection header
(type, md5sum, message definition). :class:`LiveDecoder` deserializes the bytes with rosbags'
``Typestore.deserialize_ros1`` (the ROS 1 Noetic store, or the publisher's own definition for a vendor type
or a definition that differs) and converts them with :class:`semslam.dataset.rosbag.BagDecoder` and
:func:`semslam.io.ros.decode_pointcloud2`: the live path and ``semslam run BAG`` share one decoding. No rospy here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ...dataset.rosbag import (ATTITUDE_TYPES, DEPTH_TYPES, FIX_TYPES, SCAN_TYPES, TWIST_TYPES, BagDecoder, TopicMap,
                               _stamp_ns, navsatfix_ne)
from ...dataset.vehicle import VehicleDescription
from ...errors import BagError
from ...io.ros._types import normalize_msgtype

__all__ = ["KINDS", "LiveDecoder", "LiveMessage"]

#: topic-map field -> the kind of message it carries (as :func:`semslam.dataset.rosbag.stream_bag` names them)
KINDS = {"scans": "scan", "attitude": "attitude", "dvl": "dvl", "depth": "depth", "gps": "fix", "usbl": "fix"}
_ACCEPTED = {"scans": SCAN_TYPES, "attitude": ATTITUDE_TYPES, "dvl": TWIST_TYPES, "depth": DEPTH_TYPES,
             "gps": FIX_TYPES, "usbl": FIX_TYPES}


@dataclass(frozen=True)
class LiveMessage:
    """A decoded message: stamp (header stamp, else the receive time; integer ns), kind and payload as
    :func:`semslam.dataset.rosbag.stream_bag` yields them (attitude rpy (3,), dvl (velocity FRD, valid,
    ranges), depth m, fix (latitude, longitude, height, covariance NE, "gps"/"usbl"), scan
    :class:`~semslam.io.ros.PointCloud2Data`)."""

    stamp_ns: int
    kind: str
    payload: Any
    topic: str


class LiveDecoder:
    """Decode the topic map's topics from raw ROS 1 bytes (thread-safe after the first message of a type)."""

    def __init__(self, topic_map: TopicMap, vehicle: VehicleDescription) -> None:
        if not isinstance(topic_map, TopicMap):
            raise BagError(f"The 'topic_map' argument of LiveDecoder must be a TopicMap. Got "
                           f"{type(topic_map).__name__} instead.")
        if topic_map.attitude is None:
            raise BagError("The topic map names no attitude topic: the filter needs the attitude as input.")
        self.map = topic_map
        self.kinds = {getattr(topic_map, f): f for f in KINDS if getattr(topic_map, f) is not None}
        #: mapped topics the live path does not use (none: position fixes are gated updates of the runner)
        self.unused: dict[str, str] = {}
        self._bag = BagDecoder(topic_map, vehicle)
        self._stores: dict[tuple[str, str], Any] = {}

    @property
    def topics(self) -> list[str]:
        return list(self.kinds)

    def _store(self, topic: str, msgtype: str, md5sum: str, definition: str) -> Any:
        """The typestore for a connection (cached per type and md5); checks the type is one the topic accepts."""
        key = (msgtype, md5sum)
        store = self._stores.get(key)
        if store is not None:
            return store
        field = self.kinds[topic]
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        noetic = get_typestore(Stores.ROS1_NOETIC)
        known = msgtype in noetic.fielddefs
        if known and (not md5sum or md5sum == "*" or noetic.generate_msgdef(msgtype)[1] == md5sum):
            store = noetic
        elif definition:
            store = get_typestore(Stores.EMPTY)
            try:
                store.register(get_types_from_msg(definition, msgtype))
            except Exception as err:  # rosbags parse errors
                raise BagError(f"Topic '{topic}': the definition of {msgtype} sent by its publisher cannot be "
                               f"parsed ({type(err).__name__}: {err}).") from None
        else:
            raise BagError(f"Topic '{topic}': type {msgtype} (md5 {md5sum}) is not a ROS 1 Noetic type and its "
                           "publisher sent no message definition.")
        accepted = _ACCEPTED[field]
        vendor_dvl = field == "dvl" and any(name == "velocity" for name, _ in store.fielddefs[msgtype][1])
        if msgtype not in accepted and not vendor_dvl:
            raise BagError(
                f"Topic '{topic}' (topics.{field} of the topic map) must have type "
                f"{' or '.join(accepted)}{' or a vendor DVL message with a velocity field' if field == 'dvl' else ''}. "
                f"Got {msgtype} instead."
            )
        self._stores[key] = store
        return store

    def check_type(self, topic: str, ros_type: str, md5sum: str = "", definition: str = "") -> str:
        """The rosbags type name of a connection; :class:`BagError` naming the topic when it is unmapped or
        of a type the topic map's sensor does not accept."""
        if topic not in self.kinds:
            raise BagError(f"Topic '{topic}' is not in the topic map ({', '.join(self.kinds)}).")
        msgtype = normalize_msgtype(ros_type)
        self._store(topic, msgtype, md5sum, definition)
        return msgtype

    def decode(self, topic: str, ros_type: str, raw: bytes | memoryview, *, md5sum: str = "", definition: str = "",
               receive_ns: int = 0) -> LiveMessage | None:
        """One serialized message -> :class:`LiveMessage` (None for an attitude without orientation).

        Raises
        ------
        BagError
            Unmapped topic, a type the sensor does not accept, bytes that do not decode as the type.
        """
        msgtype = self.check_type(topic, ros_type, md5sum, definition)
        store = self._store(topic, msgtype, md5sum, definition)
        try:
            msg = store.deserialize_ros1(raw, msgtype)
        except Exception as err:  # SerdeError, struct.error, IndexError
            raise BagError(f"Topic '{topic}': a message cannot be decoded as {msgtype} "
                           f"({type(err).__name__}: {err}).") from None
        ns = _stamp_ns(msg, receive_ns)
        field = self.kinds[topic]
        if field == "attitude":
            rpy = self._bag.attitude(msg)
            return LiveMessage(ns, "attitude", rpy, topic) if np.isfinite(rpy).all() else None
        if field == "dvl":
            return LiveMessage(ns, "dvl", self._bag.dvl(msg, msgtype), topic)
        if field == "depth":
            return LiveMessage(ns, "depth", self._bag.depth(msg, msgtype), topic)
        if field in ("gps", "usbl"):  # (lat, lon, height, covariance NE, source), as stream_bag yields a fix
            return LiveMessage(ns, "fix", navsatfix_ne(msg) + (field,), topic)
        from ...io.ros import decode_pointcloud2

        return LiveMessage(ns, "scan", decode_pointcloud2(msg, source=f"topic {topic}"), topic)
