"""Give the C heap's free pages back to the system (glibc ``malloc_trim``), so a long run's resident memory
grows less.

Why: glibc raises its mmap threshold each time a large block is freed (up to 32 MB on 64-bit), so the scan-sized
arrays of recognition (a 100k-point scan: arrays of 0.1-10 MB) then come from the heap, which fragments and
grows: measured on a 100k-point dive (`semslam run`, pose mode), resident memory grew by 108 MB over 160 scans
while the Python objects alive grew by 39 MB. A fixed threshold (``mallopt``) stops that (42 MB) but maps and
unmaps every large array: 20-50 % slower here. ``malloc_trim(0)`` returns the free pages inside the heap
(``madvise``) and keeps the fast heap allocations. Elsewhere than glibc it does nothing.

Not after every scan: each trim gives back pages the next scan faults in again (a 3-minute 100k-point bag: 780k
page faults and ~12 % more CPU than without trimming). :data:`TRIM_ABOVE_BYTES` trims only when that much is free
in the heap (glibc's ``mallinfo2``): 140k faults, the speed of not trimming, and the 30-minute bag's peak resident
memory 538 MB (benchmarks/history/io-and-bags.md).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

__all__ = ["TRIM_ABOVE_BYTES", "heap_free_bytes", "release_free_memory"]

#: a run trims the heap after a scan when more than this is free in it
TRIM_ABOVE_BYTES = 128 << 20


class _Mallinfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                      "fsmblks", "uordblks", "fordblks", "keepcost")]


_TRIM = _INFO = None
if sys.platform.startswith("linux"):
    try:
        _libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        _TRIM = _libc.malloc_trim
        _TRIM.argtypes, _TRIM.restype = [ctypes.c_size_t], ctypes.c_int
    except (OSError, AttributeError):  # not glibc (musl has no malloc_trim)
        _TRIM = None
    try:
        _INFO = _libc.mallinfo2  # glibc >= 2.33
        _INFO.argtypes, _INFO.restype = [], _Mallinfo2
    except (NameError, AttributeError):
        _INFO = None


def heap_free_bytes() -> int | None:
    """The bytes free inside the C heap's arenas (glibc ``mallinfo2().fordblks``), None where unknown."""
    return None if _INFO is None else int(_INFO().fordblks)


def release_free_memory(above_bytes: int = 0) -> bool:
    """Return the heap's free pages to the system when more than ``above_bytes`` are free in it (always when
    that is unknown); True when it did (glibc), else False."""
    if _TRIM is None:
        return False
    if above_bytes > 0:
        free = heap_free_bytes()
        if free is not None and free <= above_bytes:
            return False
    _TRIM(0)
    return True
