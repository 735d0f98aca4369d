"""Build rosbags ROS messages from numpy arrays: ``sensor_msgs/msg/PointCloud2`` in any layout (tests,
simulator) and the ``std_msgs/msg/Header`` every stamped message needs. rosbags is imported lazily."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ...errors import InputError

__all__ = ["encode_pointcloud2", "ros_header", "default_typestore"]

_DATATYPE_OF = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}
_TIME_ENCODINGS = {"uint32_ns": "u4", "float32_s": "f4", "float64_s": "f8"}


def default_typestore(ros1: bool = False) -> Any:
    """The rosbags typestore semslam writes with: ROS 1 Noetic or ROS 2 Humble."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)


def ros_header(typestore: Any, stamp_ns: int, frame_id: str) -> Any:
    """A ``std_msgs/msg/Header`` of ``typestore`` (with ``seq = 0`` for a ROS 1 store)."""
    Header = typestore.types["std_msgs/msg/Header"]
    Time = typestore.types["builtin_interfaces/msg/Time"]
    stamp = Time(sec=int(stamp_ns) // 1_000_000_000, nanosec=int(stamp_ns) % 1_000_000_000)
    extra = {"seq": 0} if "seq" in Header.__dataclass_fields__ else {}
    return Header(**extra, stamp=stamp, frame_id=frame_id)


def encode_pointcloud2(
    points_xyz_m: Any,
    *,
    intensity: Any = None,
    time_offset_s: Any = None,
    time_field: str = "t",
    time_encoding: str = "uint32_ns",
    frame_id: str = "sensor",
    stamp_ns: int = 0,
    coords_dtype: str = "float32",
    big_endian: bool = False,
    height: int = 1,
    field_order: Sequence[str] | None = None,
    field_gap_bytes: int = 0,
    point_padding_bytes: int = 0,
    row_padding_bytes: int = 0,
    typestore: Any = None,
) -> Any:
    """Encode points as a ``sensor_msgs/msg/PointCloud2`` of a rosbags typestore.

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Points in metres; NaN rows are written as they are (``is_dense`` is then False).
    intensity : array-like of shape (N,), optional
        Written as float32 field ``intensity``.
    time_offset_s : array-like of shape (N,), optional
        Seconds relative to the stamp, written as field ``time_field`` with ``time_encoding``:
        ``"uint32_ns"`` (Ouster ``t``, rounded to ns), ``"float32_s"`` (Velodyne ``time``) or ``"float64_s"``.
    frame_id, stamp_ns : str, int
        Header frame and stamp (integer nanoseconds).
    coords_dtype : {"float32", "float64"}
        Type of x, y, z.
    big_endian : bool
        Byte order of the data (``is_bigendian``).
    height : int
        Rows of the organised layout; must divide N (``width = N // height``).
    field_order : sequence of str, optional
        Order of the fields in a point and in ``fields`` (default x, y, z, intensity, time).
    field_gap_bytes, point_padding_bytes, row_padding_bytes : int
        Unused bytes after every field, at the end of each point and at the end of each row.
    typestore : rosbags Typestore, optional
        Default ROS 2 Humble; pass ``default_typestore(ros1=True)`` to write a ROS 1 bag.
    """
    pts = np.asarray(points_xyz_m, dtype=np.float64).reshape(-1, 3)
    n = len(pts)
    if coords_dtype not in ("float32", "float64"):
        raise InputError(f"The 'coords_dtype' argument of encode_pointcloud2 must be 'float32' or 'float64'. "
                         f"Got {coords_dtype!r} instead.")
    if time_encoding not in _TIME_ENCODINGS:
        raise InputError(f"The 'time_encoding' argument of encode_pointcloud2 must be one of "
                         f"{sorted(_TIME_ENCODINGS)}. Got {time_encoding!r} instead.")
    if height < 1 or n % height:
        raise InputError(f"The 'height' argument of encode_pointcloud2 must be >= 1 and divide the {n} points. "
                         f"Got {height} instead.")
    width = n // height
    columns = _point_columns(pts, intensity, time_offset_s, time_field, time_encoding, coords_dtype)
    order = list(field_order) if field_order is not None else list(columns)
    if sorted(order) != sorted(columns):
        raise InputError(f"The 'field_order' argument of encode_pointcloud2 must list the fields "
                         f"{sorted(columns)}. Got {order} instead.")
    offsets, point_step, row_step, data = _packed_rows(columns, order, big_endian, height, width, field_gap_bytes,
                                                       point_padding_bytes, row_padding_bytes)
    ts = typestore if typestore is not None else default_typestore()
    PointField = ts.types["sensor_msgs/msg/PointField"]
    fields = [PointField(name=k, offset=offsets[k], datatype=_DATATYPE_OF[columns[k][0]], count=1) for k in order]
    return ts.types["sensor_msgs/msg/PointCloud2"](
        header=ros_header(ts, stamp_ns, frame_id), height=height, width=width, fields=fields,
        is_bigendian=bool(big_endian), point_step=point_step, row_step=row_step, data=data.reshape(-1),
        is_dense=bool(np.isfinite(pts).all()))


def _point_columns(pts: np.ndarray, intensity: Any, time_offset_s: Any, time_field: str, time_encoding: str,
                   coords_dtype: str) -> dict[str, tuple[str, np.ndarray]]:
    """Per field of a point, its numpy type code and its values: x, y, z, then intensity and time when given."""
    n = len(pts)
    coord_code = {"float32": "f4", "float64": "f8"}[coords_dtype]
    columns: dict[str, tuple[str, np.ndarray]] = {a: (coord_code, pts[:, i]) for i, a in enumerate("xyz")}
    if intensity is not None:
        columns["intensity"] = ("f4", np.asarray(intensity, dtype=np.float64).reshape(n))
    if time_offset_s is not None:
        t = np.asarray(time_offset_s, dtype=np.float64).reshape(n)
        code = _TIME_ENCODINGS[time_encoding]
        columns[time_field] = (code, np.round(t * 1e9) if code == "u4" else t)
    return columns


def _packed_rows(columns: dict[str, tuple[str, np.ndarray]], order: list[str], big_endian: bool, height: int,
                 width: int, field_gap_bytes: int, point_padding_bytes: int,
                 row_padding_bytes: int) -> tuple[dict[str, int], int, int, np.ndarray]:
    """The fields packed in ``order`` with the gaps and paddings asked for: ``(offset per field, point_step,
    row_step, data (height, row_step) uint8)``."""
    n = height * width
    bo = ">" if big_endian else "<"
    offsets, offset = {}, 0
    for name in order:
        offsets[name] = offset
        offset += np.dtype(columns[name][0]).itemsize + field_gap_bytes
    point_step = offset + point_padding_bytes
    dtype = np.dtype({"names": order, "formats": [bo + columns[k][0] for k in order],
                      "offsets": [offsets[k] for k in order], "itemsize": point_step})
    points = np.zeros(n, dtype=dtype)
    for name in order:
        points[name] = columns[name][1]
    row_step = point_step * width + row_padding_bytes
    data = np.zeros((height, row_step), dtype=np.uint8)
    data[:, : point_step * width] = points.view(np.uint8).reshape(height, point_step * width)
    return offsets, point_step, row_step, data
