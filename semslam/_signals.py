"""Critical sections that a Ctrl-C must not cut: loading native code.

A ``KeyboardInterrupt`` raised while Python imports a large C++ extension (trimesh imports the STEP reader
cascadio, which bundles OpenCASCADE) or while numba loads a cached kernel leaves that code half-initialised; the
process then dies of SIGSEGV (measured: 4 of 24 ``semslam run`` interrupted 1.95-2.1 s after the start, in
``cascadio``'s import and in the first call of a voxel-grid kernel during the recogniser's warm-up) instead of
reporting the interrupt. :func:`critical` marks such a section; the ``semslam`` command's SIGINT handler
(:mod:`semslam.cli.main`) asks :func:`defer_interrupt` and, inside one, only records the Ctrl-C, which is raised
as a ``KeyboardInterrupt`` when the outermost section ends. Outside the command (a library user's own handler)
nothing changes. Sections are short (imports, the warm-up: about a second).
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Iterator

__all__ = ["critical", "defer_interrupt"]

_state = {"depth": 0, "pending": False}
_lock = threading.Lock()


@contextmanager
def critical() -> Iterator[None]:
    """A section a Ctrl-C must not cut (main thread only; elsewhere, and nested, it only counts): an interrupt
    that arrives inside is raised as ``KeyboardInterrupt`` when the outermost section ends."""
    main = threading.current_thread() is threading.main_thread()
    if main:
        with _lock:
            _state["depth"] += 1
    try:
        yield
    finally:
        if main:
            with _lock:
                _state["depth"] -= 1
                fire = _state["depth"] == 0 and _state["pending"]
                if fire:
                    _state["pending"] = False
            if fire:
                raise KeyboardInterrupt


def defer_interrupt() -> bool:
    """For a SIGINT handler: True (and the interrupt recorded) inside a critical section, False outside."""
    if _state["depth"] > 0:
        _state["pending"] = True
        return True
    return False
