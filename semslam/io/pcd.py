"""PCD files (PCL's Point Cloud Data format, v0.7): ``ascii``, ``binary`` and ``binary_compressed``.

Layout, as PCL 1.13 reads and writes it (``pcl/io/src/pcd_io.cpp``):

* ``binary``: the points one after the other (array of structures), ``point_step`` bytes each,
  fields in FIELDS order including ``_`` padding; PCL pads the file after the data (ignored here).
* ``binary_compressed``: ``uint32`` compressed size, ``uint32`` uncompressed size, then one LZF block
  whose content is the fields one after the other (structure of arrays), padding fields left out.
* ``ascii``: one line per point, ``sum(COUNT)`` tokens, ``nan`` for NaN. Like PCL, a float field named
  ``rgb`` is written as the unsigned integer of its bits (``TYPE U``), so that its bits survive.

:func:`read_pcd` returns a :class:`PcdData` with every field at its exact dtype; :meth:`PcdData.to_point_cloud`
turns it into a :class:`~semslam.cloud.PointCloud`. Every problem raises :class:`~semslam.errors.PcdError`
naming the file.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import lzf
import numpy as np

from .._atomic import atomic_open
from ..cloud import PointCloud
from ..errors import InputError, PcdError
from ._pcd_decode import _decode_ascii, _decode_binary, _decode_compressed, _empty
from ._pcd_header import ENCODINGS, PCD_DTYPES, PcdField, format_header, parse_header

__all__ = ["PcdData", "PcdField", "read_pcd", "write_pcd"]

_DEFAULT_VIEWPOINT = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
_STANDARD = ("x", "y", "z", "normal_x", "normal_y", "normal_z", "intensity")


@dataclass(frozen=True, eq=False)
class PcdData:
    """The content of a PCD file, field by field, at the file's exact dtypes.

    Parameters
    ----------
    fields : mapping of str to array of shape (N,) or (N, COUNT)
        One array per field in file order, padding (``_``) fields left out. Little-endian, C-contiguous.
    width, height : int
        Organisation; ``width * height == N``. Unorganised clouds have ``height == 1``.
    viewpoint : array of shape (7,)
        Sensor pose ``tx ty tz qw qx qy qz`` (metres, unit quaternion), PCD ``VIEWPOINT``.
    encoding : str
        ``ascii``, ``binary`` or ``binary_compressed``: how the file was stored (used by ``info``).
    file_fields : tuple of PcdField, optional
        The FIELDS/SIZE/TYPE/COUNT of the file as read, padding included; ``None`` when built in memory.
    path : str, optional
        Where it was read from.

    Attributes
    ----------
    valid_mask : ndarray of bool, shape (N,)
        True where x, y and z are all finite (all True when the file has no xyz).
    """

    fields: Mapping[str, np.ndarray]
    width: int
    height: int = 1
    viewpoint: np.ndarray = field(default_factory=lambda: np.array(_DEFAULT_VIEWPOINT))
    encoding: str = "binary"
    file_fields: tuple[PcdField, ...] | None = None
    path: str | None = None
    valid_mask: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        where = self.path or "<memory>"
        n = int(self.width) * int(self.height)
        checked: dict[str, np.ndarray] = {}
        for name, values in dict(self.fields).items():
            _check_name(name, where)
            arr = np.asarray(values)
            if arr.ndim not in (1, 2) or len(arr) != n:
                raise PcdError(
                    f"PCD data for '{where}': field {name!r} must have {n} rows "
                    f"(WIDTH x HEIGHT), got shape {arr.shape}."
                )
            _dtype_key(arr.dtype, name, where)
            checked[name] = np.ascontiguousarray(arr, dtype=arr.dtype.newbyteorder("<"))
        vp = np.asarray(self.viewpoint, dtype=np.float64)
        if vp.shape != (7,) or not np.isfinite(vp).all():
            raise PcdError(
                f"PCD data for '{where}': viewpoint must be 7 finite numbers "
                f"(tx ty tz qw qx qy qz), got {vp.tolist()}."
            )
        object.__setattr__(self, "fields", checked)
        object.__setattr__(self, "viewpoint", vp)
        mask = np.ones(n, dtype=bool)
        for c in ("x", "y", "z"):
            if c in checked and checked[c].ndim == 1 and checked[c].dtype.kind == "f":
                mask &= np.isfinite(checked[c])
        object.__setattr__(self, "valid_mask", mask)

    @property
    def n_points(self) -> int:
        return int(self.width) * int(self.height)

    @property
    def n_nan(self) -> int:
        """Points whose x, y or z is not finite (PCL's NaN count)."""
        return int(self.n_points - np.count_nonzero(self.valid_mask))

    @property
    def pcd_fields(self) -> tuple[PcdField, ...]:
        """The FIELDS this data is written with (the file's, padding included, when it was read)."""
        if self.file_fields is not None:
            return self.file_fields
        out = []
        for name, arr in self.fields.items():
            typ, size = _dtype_key(arr.dtype, name, self.path or "<memory>")
            out.append(PcdField(name, size, typ, 1 if arr.ndim == 1 else arr.shape[1]))
        return tuple(out)

    def to_point_cloud(self, *, drop_nan: bool = True, frame_id: str = "sensor") -> PointCloud:
        """A :class:`PointCloud`: x y z -> ``points_xyz_m`` (float64), normal_x/y/z -> ``normals_xyz``,
        intensity -> ``intensity``, every other field kept in ``fields``; VIEWPOINT tx ty tz ->
        ``viewpoint_xyz_m``.

        With ``drop_nan`` the points whose x, y or z is not finite are removed (with their other fields);
        without it such points raise :class:`PcdError` (a PointCloud holds finite points only; use
        :attr:`valid_mask` on the :class:`PcdData` to keep the organisation).
        """
        where = self.path or "<memory>"
        missing = [c for c in ("x", "y", "z") if c not in self.fields or self.fields[c].ndim != 1]
        if missing:
            raise PcdError(
                f"PCD file '{where}' has no scalar field(s) {', '.join(missing)}: it is not a point cloud "
                f"(fields: {', '.join(self.fields) or 'none'})."
            )
        keep = None
        if self.n_nan:
            if not drop_nan:
                raise PcdError(
                    f"PCD file '{where}' has {self.n_nan} point(s) with NaN or infinite x, y or z; a "
                    "PointCloud holds finite points only: pass drop_nan=True, or use read_pcd() and its "
                    "valid_mask to keep the organised layout."
                )
            keep = self.valid_mask

        rows = None if keep is None else np.flatnonzero(keep)

        def take(a: np.ndarray) -> np.ndarray:
            return a if rows is None else a.take(rows, axis=0)

        def columns(names: tuple[str, str, str]) -> np.ndarray:
            out = np.empty((self.n_points if rows is None else len(rows), 3), dtype=np.float64)
            for j, c in enumerate(names):
                out[:, j] = take(f[c])
            return out

        f = self.fields
        pts = columns(("x", "y", "z"))
        normals = None
        if all(c in f and f[c].ndim == 1 for c in ("normal_x", "normal_y", "normal_z")):
            normals = columns(("normal_x", "normal_y", "normal_z"))
        intensity = (
            take(f["intensity"]).astype(np.float64)
            if "intensity" in f and f["intensity"].ndim == 1
            else None
        )
        used = set(_STANDARD) if normals is not None else {"x", "y", "z", "intensity"}
        if intensity is None:
            used.discard("intensity")
        extra = {k: take(v) for k, v in f.items() if k not in used}
        try:
            return PointCloud(pts, normals, intensity, self.viewpoint[:3].copy(), frame_id, extra)
        except InputError as exc:
            raise PcdError(
                f"PCD file '{where}' cannot be turned into a PointCloud: {exc}"
            ) from None

    @classmethod
    def from_point_cloud(cls, cloud: PointCloud, *, coords_dtype: str = "float32") -> PcdData:
        """The PCD fields of ``cloud``: x y z [normal_x normal_y normal_z] [intensity] then ``cloud.fields``.

        ``coords_dtype`` (``"float32"``, PCL's type, or ``"float64"``) is used for coordinates, normals and
        intensity; a finite value that does not fit in float32 raises :class:`PcdError`.
        """
        if not isinstance(cloud, PointCloud):
            raise PcdError(
                f"Cannot write a PCD file from {type(cloud).__name__}: expected a PointCloud or PcdData."
            )
        if coords_dtype not in ("float32", "float64"):
            raise PcdError(
                f"The 'coords_dtype' argument must be 'float32' or 'float64'. Got {coords_dtype!r} instead."
            )
        dt = np.dtype(coords_dtype)

        def conv(name: str, a: np.ndarray) -> np.ndarray:
            with np.errstate(over="ignore"):
                out = a.astype(dt)
            if dt == np.float32 and np.count_nonzero(np.isinf(out)) != np.count_nonzero(
                np.isinf(a)
            ):
                raise PcdError(
                    f"Cannot write field {name!r} as float32: a value exceeds the float32 range "
                    "(use coords_dtype='float64')."
                )
            return out

        out: dict[str, np.ndarray] = {}
        for i, c in enumerate("xyz"):
            out[c] = conv(c, cloud.points_xyz_m[:, i])
        if cloud.normals_xyz is not None:
            for i, c in enumerate(("normal_x", "normal_y", "normal_z")):
                out[c] = conv(c, cloud.normals_xyz[:, i])
        if cloud.intensity is not None:
            out["intensity"] = conv("intensity", cloud.intensity)
        for name, arr in cloud.fields.items():
            if name in out:
                raise PcdError(
                    f"Cannot write the PointCloud field {name!r}: it clashes with a standard PCD field."
                )
            out[name] = arr
        vp = np.concatenate([cloud.viewpoint_xyz_m, [1.0, 0.0, 0.0, 0.0]])
        return cls(out, width=cloud.n_points, height=1, viewpoint=vp)


def _check_name(name: object, where: str) -> None:
    if (
        not isinstance(name, str)
        or not name
        or any(ch.isspace() for ch in name)
        or not name.isascii()
    ):
        raise PcdError(
            f"PCD data for '{where}': field names must be non-empty ASCII without spaces, got {name!r}."
        )


def _dtype_key(dtype: np.dtype, name: str, where: str) -> tuple[str, int]:
    kind = {"f": "F", "i": "I", "u": "U"}.get(dtype.kind)
    if kind is None or (kind, dtype.itemsize) not in PCD_DTYPES:
        raise PcdError(
            f"PCD data for '{where}': field {name!r} has dtype {dtype}, which PCD cannot store "
            "(float32/64, int8-64, uint8-64)."
        )
    return kind, dtype.itemsize


# ----------------------------------------------------------------------------------------------- reading


def _read_bytes(path: Path) -> bytes:
    from . import check_regular_file

    check_regular_file(path)
    try:
        with open(path, "rb") as fh:
            return fh.read()
    except OSError as exc:
        raise PcdError(f"Cannot read point-cloud file '{path}': {exc.strerror or exc}.") from None


def read_pcd(path: str | os.PathLike) -> PcdData:
    """Read a PCD file (any encoding, any FIELDS/SIZE/TYPE/COUNT) into a :class:`PcdData`.

    Raises
    ------
    PcdError
        Missing file, directory, empty or truncated file, inconsistent header, unknown TYPE/SIZE,
        corrupted LZF block, malformed ASCII line. The message names the file.
    """
    path = Path(path)
    buf = _read_bytes(path)
    where = str(path)
    header = parse_header(buf, where)
    decode = {
        "ascii": _decode_ascii,
        "binary": _decode_binary,
        "binary_compressed": _decode_compressed,
    }
    arrays = decode[header.encoding](buf, header, where) if header.points else _empty(header)
    return PcdData(
        arrays,
        header.width,
        header.height,
        np.array(header.viewpoint),
        header.encoding,
        header.fields,
        where,
    )


def write_pcd(
    path: str | os.PathLike,
    data: PcdData | PointCloud,
    *,
    encoding: str = "binary_compressed",
    coords_dtype: str = "float32",
) -> None:
    """Write ``data`` to ``path`` atomically (temporary file then rename), in a form PCL 1.13 reads.

    Parameters
    ----------
    data : PcdData or PointCloud
        A PointCloud is converted with :meth:`PcdData.from_point_cloud` (``coords_dtype``).
    encoding : {"binary_compressed", "binary", "ascii"}
    """
    where = str(path)
    if encoding not in ENCODINGS:
        raise PcdError(
            f"Cannot write PCD file '{where}': encoding must be one of {', '.join(ENCODINGS)}, "
            f"got {encoding!r}."
        )
    if not isinstance(data, PcdData):
        data = PcdData.from_point_cloud(data, coords_dtype=coords_dtype)
    fields = tuple(PcdField(f.name, f.size, f.type, f.count) for f in _fields_to_write(data))
    body, fields = _encode(data, fields, encoding)
    vp = tuple(float(v) for v in data.viewpoint)
    head = format_header(fields, data.width, data.height, vp, encoding)
    if Path(path).is_dir():
        raise PcdError(f"Cannot write PCD file '{where}': it is a directory.")
    try:
        with atomic_open(path, "wb") as fh:
            fh.write(head)
            fh.write(body)
    except OSError as exc:
        raise PcdError(f"Cannot write PCD file '{where}': {exc.strerror or exc}.") from None


def _fields_to_write(data: PcdData) -> list[PcdField]:
    # padding is not written: the arrays are the data, the layout is ours
    out = []
    for name, arr in data.fields.items():
        typ, size = _dtype_key(arr.dtype, name, data.path or "<memory>")
        out.append(PcdField(name, size, typ, 1 if arr.ndim == 1 else arr.shape[1]))
    return out


def _encode(
    data: PcdData, fields: tuple[PcdField, ...], encoding: str
) -> tuple[bytes, tuple[PcdField, ...]]:
    n = data.n_points
    arrays = [data.fields[f.name] for f in fields]
    if encoding == "binary":
        dt = np.dtype(
            [
                (f"f{i}", f.dtype if f.count == 1 else (f.dtype, (f.count,)))
                for i, f in enumerate(fields)
            ]
        )
        rec = np.empty(n, dtype=dt)
        for i, a in enumerate(arrays):
            rec[f"f{i}"] = a
        return rec.tobytes(), fields
    if encoding == "binary_compressed":
        raw = b"".join(
            np.ascontiguousarray(a, dtype=f.dtype).tobytes() for f, a in zip(fields, arrays)
        )
        if not raw:
            return struct.pack("<II", 0, 0), fields
        packed = lzf.compress(raw, len(raw) + len(raw) // 16 + 64)
        if packed is None:  # pragma: no cover - the bound above is LZF's worst case
            raise PcdError("LZF compression failed while writing a PCD file.")
        return struct.pack("<II", len(packed), len(raw)) + packed, fields
    return _encode_ascii(fields, arrays, n)


def _encode_ascii(
    fields: tuple[PcdField, ...], arrays: list[np.ndarray], n: int
) -> tuple[bytes, tuple[PcdField, ...]]:
    columns = []
    out_fields = []
    for f, a in zip(fields, arrays):
        if f.name == "rgb" and f.type == "F" and f.size == 4:
            # PCL writes packed rgb floats as the integer of their bits (NaN patterns would be lost)
            a = a.view(np.uint32)
            f = PcdField(f.name, 4, "U", f.count)
        out_fields.append(f)
        a2 = a.reshape(n, f.count)
        columns.extend(a2[:, j].astype(str) for j in range(f.count))
    if n == 0:
        return b"", tuple(out_fields)
    line = columns[0]
    for c in columns[1:]:
        line = np.char.add(np.char.add(line, " "), c)
    return ("\n".join(line.tolist()) + "\n").encode("ascii"), tuple(out_fields)
