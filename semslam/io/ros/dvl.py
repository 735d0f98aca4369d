"""DVL messages as vehicles record them, decoded into one reading with a declared frame convention.

Each supported type says, from its driver's documentation, which axes its velocity is expressed in; the
caller never guesses. ``convention`` is the axis convention of the DVL (sensor) frame the velocity is in:

``"frd"``
    x forward, y starboard, z down (towards the seabed for a downward-looking DVL).
``"flu"``
    x forward, y port, z up (REP-103 body axes).
``None``
    the type does not tell (a generic twist, an unknown vendor message): the caller must take it from the
    user (topic map ``[frames] dvl``) or refuse to run.

The velocity is returned as the message holds it, in the DVL frame (the instrument, ``header.frame_id``);
:meth:`DvlReading.velocity_frd_mps` gives it with FRD axes. The DVL's mounting on the vehicle
(``T_vehicle_dvl`` of the vehicle file) is applied downstream, as for any DVL.

==========================================  ===========  =========================================================
type                                        convention   source of the convention
==========================================  ===========  =========================================================
``semslam_msgs/msg/Dvl``                    frd          semslam's writer: instrument frame, FRD
``waterlinked_a50_ros_driver/msg/DVL``      frd          Water Linked DVL axes: x forward (LED), y right, z down
``dvl_msgs/msg/DVL`` (Water Linked, ROS 2)  frd          same DVL, same protocol fields (vx, vy, vz)
``cola2_msgs/msg/DVL``                      frd          COLA2 (Girona 500, Sparus II): NED world / FRD frames
``uuv_sensor_ros_plugins_msgs/msg/DVL``     flu / frd    UUV Simulator DVL plugin: the Gazebo link's own axes
                                                         (FLU), or its local NED frame (FRD) when the plugin's
                                                         ``enable_local_ned_frame`` is set (frame_id ``*_ned``)
``marine_acoustic_msgs/msg/Dvl``            frd          the message's comment: z along the DVL's pointing
                                                         direction, x vehicle forward (right-handed: y starboard)
twists, odometry, other vendor messages     None         (not documented by the type)
==========================================  ===========  =========================================================

Validity and ranges per type: Water Linked ``velocity_valid`` and per-beam ``valid``/``distance``; UUV
Simulator/COLA2 a covariance of -1 marks an invalid velocity, a range < 0 an invalid beam; marine_acoustic_msgs
needs ``num_good_beams >= 3`` (a 3-D bottom-track solution) and ``beam_ranges_valid`` for the ranges; semslam's
own ``beam_valid``. A non-finite velocity is always invalid. Ranges are slant ranges (m), NaN where invalid.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ...errors import BagError

__all__ = ["DVL_MESSAGE_TYPES", "DvlReading", "decode_dvl", "dvl_convention", "topic_dvl_convention",
           "velocity_frd_from"]

_TWIST_TYPES = ("geometry_msgs/msg/TwistWithCovarianceStamped", "geometry_msgs/msg/TwistStamped",
                "nav_msgs/msg/Odometry")
_FLU_TO_FRD = np.array([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class DvlReading:
    """One DVL message: velocity (m/s) in the DVL frame with axes ``convention`` (None: not documented by the
    type), whether the velocity is valid, per-beam slant ranges (m, NaN where invalid; None when the message
    has none) and the frame named by the message's header."""

    velocity_mps: np.ndarray
    valid: bool
    beam_ranges_m: np.ndarray | None
    convention: str | None
    frame_id: str = ""

    def velocity_frd_mps(self, convention: str | None = None) -> np.ndarray:
        """The velocity with FRD axes. ``convention`` is used only when the type declares none; a BagError
        when neither says which axes the velocity is in (never a guess)."""
        conv = self.convention or convention
        if conv is None:
            raise BagError("The DVL message's type does not document its frame: state it in the topic map "
                           "([frames] dvl = \"frd\" or \"flu\").")
        return velocity_frd_from(self.velocity_mps, conv)


def velocity_frd_from(velocity_mps: Any, convention: str) -> np.ndarray:
    """A velocity with ``convention`` axes ("frd" or "flu") given with FRD axes."""
    v = np.asarray(velocity_mps, dtype=np.float64).reshape(3)
    if convention == "frd":
        return v.copy()
    if convention == "flu":
        return v * _FLU_TO_FRD
    raise BagError(f"A DVL frame convention must be 'frd' or 'flu'. Got {convention!r} instead.")


def _vec(v: Any) -> np.ndarray:
    return np.array([v.x, v.y, v.z], dtype=np.float64)


def _frame_id(msg: Any) -> str:
    h = getattr(msg, "header", None)
    return str(getattr(h, "frame_id", "") or "")


def _reading(v: np.ndarray, valid: bool, ranges: np.ndarray | None, convention: str | None, msg: Any) -> DvlReading:
    valid = bool(valid) and bool(np.isfinite(v).all())
    return DvlReading(v, valid, ranges, convention, _frame_id(msg))


# -- one decoder per type ---------------------------------------------------------------------------------------

def _semslam(msg: Any) -> DvlReading:
    beam_valid = np.asarray(msg.beam_valid, dtype=bool)
    ranges = np.asarray(msg.beam_ranges_m, dtype=np.float64).copy()
    ranges[~beam_valid] = np.nan
    return _reading(_vec(msg.velocity), beam_valid.any(), ranges, "frd", msg)


def _waterlinked(msg: Any) -> DvlReading:
    beams = list(msg.beams)
    ranges = np.array([float(b.distance) if b.valid and float(b.distance) > 0 else np.nan for b in beams])
    return _reading(_vec(msg.velocity), msg.velocity_valid, ranges if beams else None, "frd", msg)


def _uuv_like(convention: Callable[[Any], str]) -> Callable[[Any], DvlReading]:
    def decode(msg: Any) -> DvlReading:
        cov = np.asarray(msg.velocity_covariance, dtype=np.float64).reshape(9)
        beams = list(msg.beams)
        ranges = np.array([float(b.range) if float(b.range) >= 0 else np.nan for b in beams])
        return _reading(_vec(msg.velocity), not (cov[[0, 4, 8]] < 0).any(), ranges if beams else None,
                        convention(msg), msg)

    return decode


def _uuv_convention_of_frame(frame_id: str) -> str:
    """UUV Simulator's DVL plugin: the link's own (Gazebo, FLU) axes, or its ``<link>_ned`` frame (FRD)."""
    return "frd" if frame_id.rstrip("/").lower().endswith("_ned") else "flu"


def _marine_acoustic(msg: Any) -> DvlReading:
    ranges = np.asarray(msg.range, dtype=np.float64).copy()
    if not msg.beam_ranges_valid:
        ranges[:] = np.nan
    ranges[~(ranges > 0)] = np.nan
    return _reading(_vec(msg.velocity), int(msg.num_good_beams) >= 3, ranges, "frd", msg)


def _twist(path: tuple[str, ...]) -> Callable[[Any], DvlReading]:
    def decode(msg: Any) -> DvlReading:
        v = msg
        for name in path:
            v = getattr(v, name)
        return _reading(_vec(v), True, None, None, msg)

    return decode


_DECODERS: dict[str, Callable[[Any], DvlReading]] = {
    "semslam_msgs/msg/Dvl": _semslam,
    "waterlinked_a50_ros_driver/msg/DVL": _waterlinked,
    "dvl_msgs/msg/DVL": _waterlinked,
    "cola2_msgs/msg/DVL": _uuv_like(lambda msg: "frd"),
    "uuv_sensor_ros_plugins_msgs/msg/DVL": _uuv_like(lambda msg: _uuv_convention_of_frame(_frame_id(msg))),
    "marine_acoustic_msgs/msg/Dvl": _marine_acoustic,
    "geometry_msgs/msg/TwistWithCovarianceStamped": _twist(("twist", "twist", "linear")),
    "geometry_msgs/msg/TwistStamped": _twist(("twist", "linear")),
    "nav_msgs/msg/Odometry": _twist(("twist", "twist", "linear")),
}

#: the DVL message types with a documented frame convention (see the module docstring), in order of preference
DVL_MESSAGE_TYPES = ("semslam_msgs/msg/Dvl", "waterlinked_a50_ros_driver/msg/DVL", "dvl_msgs/msg/DVL",
                     "cola2_msgs/msg/DVL", "uuv_sensor_ros_plugins_msgs/msg/DVL", "marine_acoustic_msgs/msg/Dvl")
_FIXED_CONVENTION = {"semslam_msgs/msg/Dvl": "frd", "waterlinked_a50_ros_driver/msg/DVL": "frd",
                     "dvl_msgs/msg/DVL": "frd", "cola2_msgs/msg/DVL": "frd", "marine_acoustic_msgs/msg/Dvl": "frd"}


def dvl_convention(msgtype: str, frame_id: str | None = None) -> str | None:
    """The frame convention a DVL message type documents ("frd"/"flu"), None when it documents none. UUV
    Simulator's depends on the message's ``frame_id`` (None when not given)."""
    if msgtype == "uuv_sensor_ros_plugins_msgs/msg/DVL":
        return None if frame_id is None else _uuv_convention_of_frame(frame_id)
    return _FIXED_CONVENTION.get(msgtype)


def topic_dvl_convention(bag: Any, topic: str) -> str | None:
    """The frame convention of ``topic`` of an open :class:`~semslam.io.ros.Bag` as its type documents it (UUV
    Simulator's: from the frame_id of its first message); None when the type documents none or the topic is
    missing or empty."""
    msgtype = next((r.msgtype for r in bag.topics() if r.topic == topic), None)
    if msgtype is None:
        return None
    if msgtype != "uuv_sensor_ros_plugins_msgs/msg/DVL":
        return dvl_convention(msgtype)
    first = next(iter(bag.messages([topic])), None)
    return None if first is None else dvl_convention(msgtype, _frame_id(first.msg))


def _generic_vendor(msg: Any) -> DvlReading:
    """A vendor message with a ``velocity`` Vector3 and optionally ``beam_ranges_m`` / ``beam_valid``."""
    ranges = None
    valid = True
    if hasattr(msg, "beam_ranges_m"):
        ranges = np.asarray(msg.beam_ranges_m, dtype=np.float64).copy()
        if hasattr(msg, "beam_valid"):
            ranges[~np.asarray(msg.beam_valid, dtype=bool)] = np.nan
        valid = bool(np.isfinite(ranges).any())
    return _reading(_vec(msg.velocity), valid, ranges, None, msg)


def decode_dvl(msg: Any, msgtype: str, *, source: str = "DVL message") -> DvlReading:
    """Decode one deserialized DVL message of rosbags type ``msgtype`` (see the module docstring).

    Raises
    ------
    BagError
        ``msgtype`` is neither a known DVL type, a twist/odometry nor a vendor message with a ``velocity``
        field; or the message lacks a field its type must have (a different variant of the definition).
    """
    decoder = _DECODERS.get(msgtype)
    if decoder is None:
        if not hasattr(getattr(msg, "velocity", None), "x"):
            raise BagError(f"The {source} has type {msgtype}: expected one of "
                           f"{', '.join(DVL_MESSAGE_TYPES + _TWIST_TYPES)}, or a vendor message with a "
                           "'velocity' (geometry_msgs/Vector3) field.")
        decoder = _generic_vendor
    try:
        return decoder(msg)
    except AttributeError as err:
        raise BagError(f"The {source} of type {msgtype} lacks the field {err.name!r} semslam reads: the bag's "
                       "definition of the type differs from the driver's (see semslam/io/ros/msg/SOURCES.md).") \
            from None
