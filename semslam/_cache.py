"""The on-disk cache of derived arrays (``$SEMSLAM_CACHE_DIR`` or ``~/.cache/semslam``).

Content-addressed: an entry's name is the SHA-256 of everything it is derived from (the input arrays' bytes,
the parameters and a format version), so a stale entry is never read, and entries are written atomically
(temporary file, then rename). A missing, unreadable or corrupted entry is rebuilt; a cache folder that cannot
be written (read-only home) only costs the rebuild. ``SEMSLAM_NO_CACHE=1`` turns the cache off.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import zipfile
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["cache_dir", "cached_arrays"]


def cache_dir() -> Path:
    """``$SEMSLAM_CACHE_DIR`` if set, else ``~/.cache/semslam``."""
    env = os.environ.get("SEMSLAM_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "semslam"


def cached_arrays(kind: str, key: list, build: Callable[[], dict]) -> dict:
    """``build()`` (a dict of str to ndarray), read from the cache when an entry of ``kind`` with the same
    ``key`` (a list of ndarrays, strings and numbers) was written before."""
    if os.environ.get("SEMSLAM_NO_CACHE", "") not in ("", "0"):
        return build()
    h = hashlib.sha256(kind.encode())
    for part in key:
        if isinstance(part, np.ndarray):
            a = np.ascontiguousarray(part)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        else:
            h.update(repr(part).encode())
    path = cache_dir() / kind / f"{h.hexdigest()}.npz"
    try:
        with np.load(path, allow_pickle=False) as z:
            return {name: z[name] for name in z.files}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        pass
    arrays = build()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **arrays)
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    except OSError:
        pass
    return arrays
