"""Parsing and writing of the PCD text header (PCL's ``pcd_io.cpp`` ``readHeader`` / ``generateHeader``).

The header is a sequence of ``KEY values`` lines ending with the ``DATA`` line; ``#`` lines are comments.
Everything here is pure text handling; the body codecs live in :mod:`semslam.io.pcd`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import PcdError

#: (TYPE letter, SIZE in bytes) -> little-endian numpy dtype, as PCL 1.13 supports them.
PCD_DTYPES: dict[tuple[str, int], np.dtype] = {
    ("F", 4): np.dtype("<f4"),
    ("F", 8): np.dtype("<f8"),
    ("I", 1): np.dtype("i1"),
    ("I", 2): np.dtype("<i2"),
    ("I", 4): np.dtype("<i4"),
    ("I", 8): np.dtype("<i8"),
    ("U", 1): np.dtype("u1"),
    ("U", 2): np.dtype("<u2"),
    ("U", 4): np.dtype("<u4"),
    ("U", 8): np.dtype("<u8"),
}
ENCODINGS = ("ascii", "binary", "binary_compressed")
PADDING = "_"
_MAX_HEADER_BYTES = 1 << 20


@dataclass(frozen=True)
class PcdField:
    """One column of a PCD file: ``name``, ``size`` (bytes per element), ``type`` (F, I or U) and ``count``
    (elements per point, e.g. 308 for a VFH signature). A field named ``_`` is padding."""

    name: str
    size: int
    type: str
    count: int = 1

    @property
    def dtype(self) -> np.dtype:
        return PCD_DTYPES[(self.type, self.size)]

    @property
    def is_padding(self) -> bool:
        return self.name == PADDING


@dataclass(frozen=True)
class PcdHeader:
    """The parsed header: fields, organisation, viewpoint (tx ty tz qw qx qy qz), point count, encoding,
    and ``data_offset``, the byte where the body starts."""

    version: str
    fields: tuple[PcdField, ...]
    width: int
    height: int
    viewpoint: tuple[float, ...]
    points: int
    encoding: str
    data_offset: int

    @property
    def point_step(self) -> int:
        """Bytes per point in the ``binary`` layout (padding included)."""
        return sum(f.size * f.count for f in self.fields)


def _fail(path: str, what: str) -> PcdError:
    return PcdError(f"Cannot read PCD file '{path}': {what}.")


def _ints(path: str, key: str, values: list[str], n: int | None, minimum: int) -> list[int]:
    if n is not None and len(values) != n:
        raise _fail(
            path, f"the {key} line must have {n} value(s) (one per field), got {len(values)}"
        )
    out = []
    for v in values:
        try:
            i = int(v)
        except ValueError:
            raise _fail(path, f"the {key} line must hold integers, got {v!r}") from None
        if i < minimum:
            raise _fail(path, f"the {key} values must be >= {minimum}, got {i}")
        out.append(i)
    return out


def parse_header(buf: bytes | memoryview, path: str) -> PcdHeader:
    """Parse the header at the start of ``buf``; raise :class:`PcdError` naming ``path`` on any problem."""
    end = bytes(buf[:_MAX_HEADER_BYTES])
    entries: dict[str, list[str]] = {}
    pos = 0
    encoding = None
    while pos < len(end):
        nl = end.find(b"\n", pos)
        stop = len(end) if nl < 0 else nl
        raw = end[pos:stop]
        pos = stop + 1
        try:
            line = raw.decode("utf-8").strip()
        except UnicodeDecodeError:
            raise _fail(path, f"the header is not UTF-8 text (line {raw[:40]!r})") from None
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        key = key.upper()
        if key == "COLUMNS":  # very old files
            key = "FIELDS"
        if key not in (
            "VERSION",
            "FIELDS",
            "SIZE",
            "TYPE",
            "COUNT",
            "WIDTH",
            "HEIGHT",
            "VIEWPOINT",
            "POINTS",
            "DATA",
        ):
            raise _fail(path, f"unknown header line {line[:60]!r}")
        if key in entries:
            raise _fail(path, f"the header has two {key} lines")
        entries[key] = values
        if key == "DATA":
            if nl < 0:
                pos = len(end)
            if len(values) != 1 or values[0].lower() not in ENCODINGS:
                raise _fail(
                    path, f"DATA must be one of {', '.join(ENCODINGS)}, got {' '.join(values)!r}"
                )
            encoding = values[0].lower()
            break
    if encoding is None:
        if not end.strip():
            raise _fail(path, "the file is empty")
        raise _fail(path, "no DATA line found: this is not a PCD file or its header is truncated")
    return _build(entries, encoding, pos, path)


def _build(entries: dict[str, list[str]], encoding: str, offset: int, path: str) -> PcdHeader:
    for key in ("FIELDS", "SIZE", "TYPE"):
        if key not in entries:
            raise _fail(path, f"the header has no {key} line")
    names = entries["FIELDS"]
    if not names:
        raise _fail(path, "the FIELDS line is empty")
    nf = len(names)
    sizes = _ints(path, "SIZE", entries["SIZE"], nf, 1)
    types = [t.upper() for t in entries["TYPE"]]
    if len(types) != nf:
        raise _fail(
            path, f"the TYPE line must have {nf} value(s) (one per field), got {len(types)}"
        )
    counts = _ints(path, "COUNT", entries["COUNT"], nf, 1) if "COUNT" in entries else [1] * nf
    fields = []
    seen = set()
    for name, size, typ, count in zip(names, sizes, types, counts):
        if (typ, size) not in PCD_DTYPES:
            raise _fail(
                path,
                f"field {name!r} has TYPE {typ} with SIZE {size}, which is not a PCD type "
                "(F 4/8, I or U 1/2/4/8)",
            )
        if name != PADDING:
            if name in seen:
                raise _fail(path, f"field {name!r} appears twice in FIELDS")
            seen.add(name)
        fields.append(PcdField(name, size, typ, count))
    width_given = "WIDTH" in entries
    width = _ints(path, "WIDTH", entries["WIDTH"], 1, 0)[0] if width_given else None
    height = _ints(path, "HEIGHT", entries["HEIGHT"], 1, 0)[0] if "HEIGHT" in entries else 1
    points = _ints(path, "POINTS", entries["POINTS"], 1, 0)[0] if "POINTS" in entries else None
    if width is None:
        if points is None:
            raise _fail(path, "the header has neither WIDTH nor POINTS")
        width, height = points, 1
    if points is None:
        points = width * height
    if width * height != points:
        raise _fail(
            path,
            f"WIDTH x HEIGHT ({width} x {height} = {width * height}) differs from POINTS ({points})",
        )
    viewpoint = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    if "VIEWPOINT" in entries:
        vp = entries["VIEWPOINT"]
        try:
            viewpoint = tuple(float(v) for v in vp)
        except ValueError:
            raise _fail(path, f"VIEWPOINT must hold 7 numbers, got {' '.join(vp)[:60]!r}") from None
        if len(viewpoint) != 7 or not np.isfinite(viewpoint).all():
            raise _fail(
                path,
                f"VIEWPOINT must hold 7 finite numbers (tx ty tz qw qx qy qz), got {' '.join(vp)[:60]!r}",
            )
    version = " ".join(entries.get("VERSION", ["0.7"]))
    return PcdHeader(version, tuple(fields), width, height, viewpoint, points, encoding, offset)


def _num(v: float) -> str:
    return np.format_float_positional(np.float64(v), unique=True, trim="-")


def format_header(
    fields: tuple[PcdField, ...],
    width: int,
    height: int,
    viewpoint: tuple[float, ...],
    encoding: str,
) -> bytes:
    """The header text PCL's ``generateHeader`` writes (version 0.7), ending with the DATA line."""
    lines = [
        "# .PCD v0.7 - Point Cloud Data file format",
        "VERSION 0.7",
        "FIELDS " + " ".join(f.name for f in fields),
        "SIZE " + " ".join(str(f.size) for f in fields),
        "TYPE " + " ".join(f.type for f in fields),
        "COUNT " + " ".join(str(f.count) for f in fields),
        f"WIDTH {width}",
        f"HEIGHT {height}",
        "VIEWPOINT " + " ".join(_num(v) for v in viewpoint),
        f"POINTS {width * height}",
        f"DATA {encoding}",
    ]
    return ("\n".join(lines) + "\n").encode("ascii")
