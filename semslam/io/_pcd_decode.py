"""Decoding the data section of a PCD file (:func:`.pcd.read_pcd`): ``binary`` (array of structures),
``binary_compressed`` (one LZF block of structure-of-arrays) and ``ascii``. Every problem raises
:class:`~semslam.errors.PcdError` naming the file."""

from __future__ import annotations

import itertools
import struct

import lzf
import numpy as np

from ..errors import PcdError
from ._pcd_header import PcdField, PcdHeader

def _fail(path: str, what: str) -> PcdError:
    return PcdError(f"Cannot read PCD file '{path}': {what}.")


def _data_fields(header: PcdHeader) -> list[PcdField]:
    return [f for f in header.fields if not f.is_padding]


def _shape(f: PcdField, n: int) -> tuple[int, ...]:
    return (n,) if f.count == 1 else (n, f.count)


def _empty(header: PcdHeader) -> dict[str, np.ndarray]:
    return {f.name: np.empty(_shape(f, 0), f.dtype) for f in _data_fields(header)}


def _decode_binary(buf: bytes, header: PcdHeader, where: str) -> dict[str, np.ndarray]:
    n, step = header.points, header.point_step
    available = len(buf) - header.data_offset
    if available < n * step:
        raise _fail(
            where,
            f"the binary data is truncated: {n} points of {step} bytes need {n * step} bytes, "
            f"the file has {available} after the header",
        )
    names, formats, offsets = [], [], []
    off = 0
    for i, f in enumerate(header.fields):
        if not f.is_padding:
            names.append(f"f{i}")
            formats.append(f.dtype if f.count == 1 else (f.dtype, (f.count,)))
            offsets.append(off)
        off += f.size * f.count
    dt = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    rec = np.frombuffer(buf, dtype=dt, count=n, offset=header.data_offset)
    out = {}
    for i, f in enumerate(header.fields):
        if not f.is_padding:
            out[f.name] = np.ascontiguousarray(rec[f"f{i}"])
    return out


def _decode_compressed(buf: bytes, header: PcdHeader, where: str) -> dict[str, np.ndarray]:
    n, start = header.points, header.data_offset
    if len(buf) < start + 8:
        raise _fail(
            where, "the binary_compressed data is truncated: the 8-byte size block is missing"
        )
    compressed, uncompressed = struct.unpack_from("<II", buf, start)
    fields = _data_fields(header)
    expected = n * sum(f.size * f.count for f in fields)
    if uncompressed != expected:
        raise _fail(
            where,
            f"the binary_compressed block says {uncompressed} bytes uncompressed, but {n} points of "
            f"these fields need {expected}",
        )
    if start + 8 + compressed > len(buf):
        raise _fail(
            where,
            f"the binary_compressed data is truncated: the LZF block of {compressed} bytes ends past "
            f"the end of the file ({len(buf) - start - 8} bytes available)",
        )
    try:
        raw = lzf.decompress(buf[start + 8 : start + 8 + compressed], uncompressed)
    except ValueError as exc:
        raise _fail(where, f"the LZF block is corrupted ({exc})") from None
    if raw is None or len(raw) != uncompressed:
        got = "more" if raw is None else len(raw)
        raise _fail(
            where,
            f"the LZF block is corrupted: it decompresses to {got} bytes instead of {uncompressed}",
        )
    out = {}
    off = 0
    for f in fields:
        k = n * f.count
        out[f.name] = np.frombuffer(raw, dtype=f.dtype, count=k, offset=off).reshape(_shape(f, n))
        off += k * f.size
    return out


def _decode_ascii(buf: bytes, header: PcdHeader, where: str) -> dict[str, np.ndarray]:
    n = header.points
    try:
        text = buf[header.data_offset :].decode("ascii")
    except UnicodeDecodeError:
        raise _fail(where, "the ascii data contains non-ASCII bytes") from None
    rows = [r for r in map(str.split, text.splitlines()) if r]
    if len(rows) != n:
        raise _fail(
            where,
            f"the header says {n} points but the ascii data has {len(rows)} non-empty line(s)",
        )
    per_line = sum(f.count for f in header.fields)
    counts = np.fromiter(map(len, rows), dtype=np.int64, count=n)
    bad = np.flatnonzero(counts != per_line)
    if bad.size:
        i = int(bad[0])
        raise _fail(
            where,
            f"point {i} (data line {i + 1}) has {counts[i]} values, expected {per_line} "
            "(the sum of COUNT)",
        )
    words = list(itertools.chain.from_iterable(rows))
    out = {}
    col = 0
    for f in header.fields:
        if not f.is_padding:
            columns = [_parse_column(words[col + k :: per_line], f, where) for k in range(f.count)]
            out[f.name] = columns[0] if f.count == 1 else np.stack(columns, axis=1)
        col += f.count
    return out


def _parse_column(words: list[str], f: PcdField, where: str) -> np.ndarray:
    """One column of ascii tokens at the field's dtype (Python's float/int parse, 3x numpy's string casts)."""
    parse = float if f.type == "F" else int
    try:
        values = list(map(parse, words))
    except ValueError:
        i = next(i for i, w in enumerate(words) if not _parses(parse, w))
        raise _fail(
            where,
            f"point {i}, field {f.name!r} ({f.type}{f.size}): {words[i][:20]!r} is not a valid "
            "number",
        ) from None
    if f.type == "F":
        with np.errstate(over="ignore"):  # beyond float32: inf, as PCL's reader
            return np.array(values, dtype=np.float64).astype(f.dtype)
    info = np.iinfo(f.dtype)
    lo, hi = (min(values), max(values)) if values else (0, 0)
    if lo < info.min or hi > info.max:
        raise _fail(
            where,
            f"field {f.name!r} ({f.type}{f.size}) has values outside [{info.min}, {info.max}]",
        )
    return np.array(values, dtype=f.dtype)


def _parses(parse, word: str) -> bool:
    try:
        parse(word)
    except ValueError:
        return False
    return True


# ----------------------------------------------------------------------------------------------- writing

