"""``sensor_msgs/PointCloud2`` decoding and encoding over numpy (no ROS, no PCL).

:func:`decode_pointcloud2` reads any field layout: fields in any order, padding between fields, at the end
of a point (``point_step`` larger than the fields) and at the end of a row (``row_step``), datatypes INT8 to
FLOAT64 (``PointField`` constants 1 to 8), ``count`` > 1, either byte order (``is_bigendian``), organised
(``height`` > 1) or not. Every declared size is checked against the data before it is used, so a lying
message raises :class:`~semslam.errors.BagError` and never makes the decoder read or allocate more than its
data implies.

Per-point time (the first field found among ``t``, ``time``, ``timestamp``, ``time_offset``,
``offset_time``) is returned as float64 seconds relative to the header stamp:

* integer fields (INT8..UINT32) are nanoseconds relative to the header stamp (Ouster ``t`` uint32,
  Livox ``offset_time`` uint32): ``value * 1e-9``;
* float fields are seconds relative to the header stamp (Velodyne ``time`` float32) when their median
  magnitude is below 1e6; absolute seconds since the epoch when it is in [1e6, 1e12) (Hesai, Robosense
  ``timestamp`` float64): ``value - stamp_s``; absolute nanoseconds from 1e12 on (Livox ``timestamp``
  float64): ``(value - stamp_ns) * 1e-9``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ...cloud import POINT_TIME_FIELDS, PointCloud
from ...errors import BagError
from ._pointcloud2_kernels import finite_xyz, gather_kept

__all__ = ["DATATYPES", "PointCloud2Data", "decode_pointcloud2", "encode_pointcloud2"]

#: ``sensor_msgs/PointField`` datatype constant -> numpy type code (byte order added per message).
DATATYPES: dict[int, str] = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
_XYZ = ("x", "y", "z")


@dataclass(frozen=True, eq=False)
class PointCloud2Data:
    """A decoded PointCloud2: finite points only, with what was dropped.

    Attributes
    ----------
    points_xyz_m : ndarray of shape (N, 3), float64
        Points with finite x, y and z, in frame ``frame_id`` (row-major order of the organised cloud).
    intensity : ndarray of shape (N,), float64, or None
        The ``intensity`` field when present (sensor units).
    time_offset_s : ndarray of shape (N,), float64, or None
        Per-point time in seconds relative to ``stamp_s`` (see the module notes on unit conversion).
    frame_id : str
        ``header.frame_id`` (may be empty).
    stamp_s, stamp_ns : float, int
        Header stamp in seconds and in integer nanoseconds.
    n_dropped : int
        Points removed because x, y or z was NaN or infinite.
    valid_mask : ndarray of shape (height, width), bool
        Which points of the organised layout were kept.
    fields : dict of str to ndarray of shape (N,) or (N, count)
        Every other named field (``ring``, ``reflectivity`` ...) at its own dtype, dropped points removed.
    time_field : str or None
        Name of the field ``time_offset_s`` came from.
    """

    points_xyz_m: np.ndarray
    intensity: np.ndarray | None
    time_offset_s: np.ndarray | None
    frame_id: str
    stamp_s: float
    stamp_ns: int
    n_dropped: int
    valid_mask: np.ndarray
    fields: Mapping[str, np.ndarray] = field(default_factory=dict)
    time_field: str | None = None

    @property
    def n_points(self) -> int:
        return len(self.points_xyz_m)

    @property
    def height(self) -> int:
        return self.valid_mask.shape[0]

    @property
    def width(self) -> int:
        return self.valid_mask.shape[1]

    def to_point_cloud(self, *, frame_id: str | None = None) -> PointCloud:
        """A :class:`~semslam.cloud.PointCloud` in ``frame_id`` (default: the header's, else ``"sensor"``).

        ``time_offset_s`` and the other fields go to ``PointCloud.fields``.
        """
        extra = dict(self.fields)
        if self.time_offset_s is not None:
            extra["time_offset_s"] = self.time_offset_s
        return PointCloud(self.points_xyz_m, intensity=self.intensity,
                          frame_id=frame_id or self.frame_id or "sensor", fields=extra)


def _int_attr(msg: Any, name: str, source: str) -> int:
    value = getattr(msg, name, None)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 0:
        raise BagError(f"{source}: PointCloud2 '{name}' must be a non-negative integer. Got {value!r} instead.")
    return int(value)


def _data_bytes(msg: Any, source: str) -> np.ndarray:
    data = getattr(msg, "data", None)
    try:
        if isinstance(data, np.ndarray):
            return np.ascontiguousarray(data).reshape(-1).view(np.uint8)
        return np.frombuffer(data, dtype=np.uint8)
    except (TypeError, ValueError):
        raise BagError(f"{source}: PointCloud2 'data' must be a byte buffer. "
                       f"Got {type(data).__name__} instead.") from None


def _stamp_ns(msg: Any, source: str) -> tuple[str, int]:
    header = getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    sec, nsec = getattr(stamp, "sec", None), getattr(stamp, "nanosec", None)
    if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (sec, nsec)):
        raise BagError(f"{source}: PointCloud2 'header.stamp' must have integer sec and nanosec. "
                       f"Got {stamp!r:.80} instead.")
    frame_id = getattr(header, "frame_id", "")
    return (frame_id if isinstance(frame_id, str) else str(frame_id)), int(sec) * 1_000_000_000 + int(nsec)


def _layout(msg: Any, source: str, n_bytes: int) -> tuple[dict[str, tuple[int, str, int]], int, int, int, int]:
    """Check every declared size against the data; return the named fields and height, width, steps."""
    height, width = _int_attr(msg, "height", source), _int_attr(msg, "width", source)
    point_step, row_step = _int_attr(msg, "point_step", source), _int_attr(msg, "row_step", source)
    n_points = height * width
    if n_points > n_bytes:
        raise BagError(f"{source}: PointCloud2 declares width*height = {width}*{height} = {n_points} points "
                       f"but its data holds only {n_bytes} bytes.")
    if n_points and point_step == 0:
        raise BagError(f"{source}: PointCloud2 'point_step' must be positive for {n_points} points. Got 0 instead.")
    if row_step < point_step * width:
        raise BagError(f"{source}: PointCloud2 'row_step' must be >= point_step*width = {point_step}*{width} = "
                       f"{point_step * width}. Got {row_step} instead.")
    if n_bytes < row_step * height:
        raise BagError(f"{source}: PointCloud2 data must hold row_step*height = {row_step}*{height} = "
                       f"{row_step * height} bytes. Got {n_bytes} bytes instead.")
    order = ">" if bool(getattr(msg, "is_bigendian", False)) else "<"
    named: dict[str, tuple[int, str, int]] = {}
    for fld in getattr(msg, "fields", None) or ():
        name = getattr(fld, "name", None)
        offset, datatype = _int_attr(fld, "offset", source), _int_attr(fld, "datatype", source)
        count = max(_int_attr(fld, "count", source), 1)  # count 0 is read as 1
        if datatype not in DATATYPES:
            raise BagError(f"{source}: PointCloud2 field {name!r} must have a datatype in 1..8 (INT8..FLOAT64). "
                           f"Got {datatype} instead.")
        code = order + DATATYPES[datatype]
        end = offset + np.dtype(code).itemsize * count
        if end > point_step:
            raise BagError(f"{source}: PointCloud2 field {name!r} (offset {offset}, {count} x {DATATYPES[datatype]}) "
                           f"must end within point_step = {point_step}. Got end {end} instead.")
        if isinstance(name, str) and name and name not in named:
            named[name] = (offset, code, count)
    if n_points and not all(axis in named for axis in _XYZ):
        raise BagError(f"{source}: PointCloud2 must have fields x, y and z. Got fields {sorted(named)} instead.")
    return named, height, width, point_step, row_step


def _time_offsets_s(values: np.ndarray, stamp_ns: int, integer: bool | None = None) -> np.ndarray:
    """Seconds from the header stamp of a time field's ``values`` (``integer``: the field's type was an integer one,
    when ``values`` are already float64)."""
    if values.dtype.kind in "iu" if integer is None else integer:
        return np.asarray(values, dtype=np.float64) * 1e-9
    v = np.asarray(values, dtype=np.float64)
    sample = v[::max(1, len(v) // 4096)]  # the unit is read from the magnitude: ~4k evenly spaced points suffice
    finite = np.abs(sample[np.isfinite(sample)])
    if not finite.size:  # the sample missed the few finite stamps: all of them
        finite = np.abs(v[np.isfinite(v)])
    ref = float(np.median(finite)) if finite.size else 0.0
    if ref >= 1e12:  # absolute nanoseconds
        return (v - float(stamp_ns)) * 1e-9
    if ref >= 1e6:  # absolute seconds
        return v - stamp_ns * 1e-9
    return v


def decode_pointcloud2(msg: Any, *, source: str = "PointCloud2 message") -> PointCloud2Data:
    """Decode a ``sensor_msgs/PointCloud2`` (any object with its attributes, e.g. a rosbags message).

    Parameters
    ----------
    msg : sensor_msgs/msg/PointCloud2
        ``header`` (``stamp.sec``, ``stamp.nanosec``, ``frame_id``), ``height``, ``width``, ``fields``
        (``name``, ``offset``, ``datatype``, ``count``), ``is_bigendian``, ``point_step``, ``row_step``,
        ``data`` (bytes or uint8 array), ``is_dense`` (not trusted: non-finite points are always dropped).
    source : str
        What the message is, for error messages (``"bag 'x.bag' topic '/points' message 3"``).

    Returns
    -------
    PointCloud2Data
        Fields with ``count`` > 1 give x, y, z, intensity and time from their first element; other fields
        keep shape (N, count).

    Raises
    ------
    BagError
        A size that does not fit the data, a field outside the point, an unknown datatype, no x/y/z field.
    """
    buf = _data_bytes(msg, source)
    frame_id, stamp_ns = _stamp_ns(msg, source)
    named, height, width, point_step, row_step = _layout(msg, source, len(buf))
    names = list(named)
    if height * width == 0:
        grid = None
    else:
        dtype = np.dtype({"names": names, "offsets": [named[n][0] for n in names], "itemsize": point_step,
                          "formats": [np.dtype((named[n][1], (named[n][2],))) if named[n][2] > 1
                                      else np.dtype(named[n][1]) for n in names]})
        grid = np.ndarray((height, width), dtype=dtype, buffer=buf, strides=(row_step, point_step))
    with np.errstate(invalid="ignore", over="ignore"):  # casting signalling NaNs warns; they are dropped
        return _extract(grid, named, height, width, frame_id, stamp_ns)


def _gathered(values: np.ndarray, keep: np.ndarray, n_keep: int) -> np.ndarray:
    out = np.empty(n_keep)
    gather_kept(values, keep, out)
    return out


def _native(code: str, kinds: str) -> bool:
    """A field type code (``"<f4"``, ``">u4"``...) the kernels read: native byte order, one of ``kinds``."""
    dt = np.dtype(code)
    return dt.kind in kinds and dt.isnative and dt.itemsize >= (4 if dt.kind == "f" else 1)


def _first(values: np.ndarray) -> np.ndarray:
    """(H, W, count) -> (H, W): the first element of a ``count`` > 1 field."""
    return values[..., 0] if values.ndim == 3 else values


def _extract(grid: np.ndarray | None, named: dict[str, tuple[int, str, int]], height: int, width: int,
             frame_id: str, stamp_ns: int) -> PointCloud2Data:
    if grid is None:  # an empty cloud: empty arrays for the fields it declares
        grid = np.zeros((height, width), dtype=[(n, c, (k,)) if k > 1 else (n, c) for n, (_, c, k) in named.items()])
    time_field = next((n for n in POINT_TIME_FIELDS if n in named), None)
    fast = all(a in named for a in _XYZ) and len({named[a][1] for a in _XYZ}) == 1 and _native(named["x"][1], "f")
    if fast:  # one pass of a kernel over the message's own strided fields (_pointcloud2_kernels)
        keep, xyz = np.empty(height * width, dtype=bool), np.empty((height * width, 3))
        n_keep = finite_xyz(*(_first(grid[a]) for a in _XYZ), keep, xyz)
        xyz = xyz if n_keep == len(xyz) else xyz[:n_keep].copy()
    else:  # per axis on flat arrays, then one (M, 3) array filled column by column
        cols = ([_first(grid[a]).reshape(-1).astype(np.float64) for a in _XYZ] if all(a in named for a in _XYZ)
                else [np.zeros(height * width)] * 3)
        keep = np.isfinite(cols[0]) & np.isfinite(cols[1]) & np.isfinite(cols[2])
        n_keep = int(np.count_nonzero(keep))
        xyz = np.empty((n_keep, 3))
        for k, c in enumerate(cols):
            xyz[:, k] = c if n_keep == keep.size else c[keep]
    valid = keep.reshape(height, width)
    time_s = intensity = None
    if time_field is not None:
        code = named[time_field][1]
        values = _first(grid[time_field])
        time_s = (_time_offsets_s(_gathered(values, keep, n_keep), stamp_ns, code[1] in "iu")
                  if fast and _native(code, "iuf") else _time_offsets_s(values.reshape(-1)[keep], stamp_ns))
    if "intensity" in named:
        values = _first(grid["intensity"])
        intensity = (_gathered(values, keep, n_keep) if fast and _native(named["intensity"][1], "iuf")
                     else values.astype(np.float64).reshape(-1)[keep])
    extra: dict[str, np.ndarray] = {}
    for n in named:
        if n not in (*_XYZ, "intensity", time_field):
            values = grid[n].reshape(height * width, *grid[n].shape[2:])[keep]
            extra[n] = values.astype(values.dtype.newbyteorder("="))
    return PointCloud2Data(points_xyz_m=xyz, intensity=intensity,
                           time_offset_s=time_s, frame_id=frame_id, stamp_s=stamp_ns * 1e-9, stamp_ns=stamp_ns,
                           n_dropped=int(keep.size - keep.sum()), valid_mask=valid, fields=extra,
                           time_field=time_field)


from ._encode import encode_pointcloud2  # noqa: E402 - re-exported; rosbags is imported lazily there
