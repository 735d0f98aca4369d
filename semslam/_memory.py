"""Give the C heap's free pages back to the system (glibc ``malloc_trim``), so a long run's resident memory
grows less.

Why: glibc raises its mmap threshold each time a large block is freed (up to 32 MB on 64-bit), so the scan-sized
arrays of recognition (a 100k-point scan: arrays of 0.1-10 MB) then come from the heap, which fragments and
grows: measured on a 100k-point dive (`semslam run`, pose mode), resident memory grew by 108 MB over 160 scans
while the Python objects alive grew by 39 MB. A fixed threshold (``mallopt``) stops that (42 MB) but maps and
unmaps every large array: 20-50 % slower here. ``malloc_trim(0)`` after each scan returns the free pages inside
the heap (``madvise``) and keeps the fast heap allocations. Elsewhere than glibc it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

__all__ = ["release_free_memory"]

_TRIM = None
if sys.platform.startswith("linux"):
    try:
        _libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        _TRIM = _libc.malloc_trim
        _TRIM.argtypes, _TRIM.restype = [ctypes.c_size_t], ctypes.c_int
    except (OSError, AttributeError):  # not glibc (musl has no malloc_trim)
        _TRIM = None


def release_free_memory() -> bool:
    """Return the heap's free pages to the system; True when it could (glibc), else False (nothing done)."""
    if _TRIM is None:
        return False
    _TRIM(0)
    return True
