"""The on-disk cache of derived arrays (``$SEMSLAM_CACHE_DIR`` or ``~/.cache/semslam``).

Content-addressed: an entry's name is the SHA-256 of everything it is derived from (the input arrays' bytes,
the parameters and a format version), so a stale entry is never read, and entries are written atomically
(temporary file, then rename). A missing, unreadable or corrupted entry is rebuilt; a cache folder that cannot
be written (read-only home) only costs the rebuild. ``SEMSLAM_NO_CACHE=1`` turns the cache off.

The cache is bounded: after every write, the entries least recently used (written or read) are deleted until the
entries of every kind together take at most ``$SEMSLAM_CACHE_MAX_MB`` (2048 MB by default; a 13-class database of
laser views takes ~0.3 GB, most of it distance fields). Only the cache's own entries are ever deleted: files named
by a SHA-256 (64 hex digits, ``.npz``) in a kind's folder (``NAME_vN``: a kind's name ends with its format version).
When the limit is smaller than what one run uses (an entry written or read since the process started is evicted),
a :class:`CacheLimitWarning` says so, once per process.
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
import time
import warnings
import zipfile
from pathlib import Path
from typing import Callable

import numpy as np

from ._signals import remove_on_interrupt

__all__ = ["CacheLimitWarning", "cache_dir", "cache_limit_bytes", "cached_arrays", "key_digest"]

DEFAULT_LIMIT_MB = 2048.0
_KIND = re.compile(r"[a-z0-9_]+_v[0-9]+")
_ENTRY = re.compile(r"[0-9a-f]{64}\.npz")  # an entry's name: the SHA-256 of its key
_PROCESS_START = time.time()
_warned: list = []


class CacheLimitWarning(UserWarning):
    """The cache evicted an entry this process wrote or read: its limit is smaller than what one run uses, so every
    run builds those entries again."""


def cache_dir() -> Path:
    """``$SEMSLAM_CACHE_DIR`` if set, else ``~/.cache/semslam``."""
    env = os.environ.get("SEMSLAM_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "semslam"


def key_digest(key: list) -> str:
    """SHA-256 (hex) of ``key``: ndarrays by dtype, shape and bytes, anything else by its ``repr``. A digest is a
    valid part of another key (a large input hashed once for several entries)."""
    h = hashlib.sha256()
    for part in key:
        if isinstance(part, np.ndarray):
            a = np.ascontiguousarray(part)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        else:
            h.update(repr(part).encode())
    return h.hexdigest()


def cached_arrays(kind: str, key: list, build: Callable[[], dict]) -> dict:
    """``build()`` (a dict of str to ndarray), read from the cache when an entry of ``kind`` (``NAME_vN``, N the
    format version of its entries) with the same ``key`` (a list of ndarrays, strings and numbers) was written
    before."""
    if not _KIND.fullmatch(kind):
        raise ValueError(f"cache kind {kind!r} is not NAME_vN")  # a programming error, not a user's
    if os.environ.get("SEMSLAM_NO_CACHE", "") not in ("", "0"):
        return build()
    digest = key_digest([kind, *key])
    limit = cache_limit_bytes()
    path = cache_dir() / kind / f"{digest}.npz"
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {name: z[name] for name in z.files}
        _touch(path)
        return arrays
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        pass
    arrays = build()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".tmp", dir=path.parent)
        remove_on_interrupt(tmp)
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **arrays)
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        _evict(cache_dir(), limit, keep=path)
    except OSError:
        pass
    return arrays


def cache_limit_bytes() -> int:
    """``$SEMSLAM_CACHE_MAX_MB`` (default 2048) in bytes."""
    from .errors import InputError

    raw = os.environ.get("SEMSLAM_CACHE_MAX_MB", "")
    try:
        mb = float(raw) if raw.strip() else DEFAULT_LIMIT_MB
    except ValueError:
        mb = float("nan")
    if not mb >= 0 or mb == float("inf"):
        raise InputError(f"The environment variable SEMSLAM_CACHE_MAX_MB must be a size in MB (a number >= 0). "
                         f"Got {raw!r} instead.")
    return int(mb * 2**20)


def _touch(path: Path) -> None:
    """Mark an entry used now (its modification time orders the eviction)."""
    try:
        os.utime(path)
    except OSError:
        pass


def _evict(root: Path, limit: int, keep: Path) -> None:
    """Delete the least recently used ``root/KIND_vN/SHA256.npz`` entries (never ``keep``) until they take
    <= ``limit``."""
    entries = []
    for p in root.glob("*/*.npz"):
        if not (_KIND.fullmatch(p.parent.name) and _ENTRY.fullmatch(p.name)):
            continue
        try:
            st = p.stat()
        except OSError:
            continue
        entries.append((st.st_mtime, st.st_size, p))
    total = sum(e[1] for e in entries)
    for mtime, size, p in sorted(entries, key=lambda e: e[0]):
        if total <= limit:
            break
        if p == keep:
            continue
        try:
            p.unlink()
            total -= size
        except OSError:
            continue
        if mtime >= _PROCESS_START - 1.0 and not _warned:  # used by this run: the limit is too small for one run
            _warned.append(p)
            warnings.warn(f"The semslam cache ({root}) evicted an entry this run uses: its limit, "
                          f"SEMSLAM_CACHE_MAX_MB = {limit / 2**20:g}, is smaller than one run's derived arrays, which "
                          f"are then built again every run. Raise SEMSLAM_CACHE_MAX_MB.", CacheLimitWarning,
                          stacklevel=3)
