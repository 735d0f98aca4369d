"""Critical sections that a Ctrl-C must not cut: loading native code.

A ``KeyboardInterrupt`` raised while Python imports a large C++ extension (trimesh imports the STEP reader
cascadio, which bundles OpenCASCADE) or while numba loads a cached kernel leaves that code half-initialised; the
process then dies of SIGSEGV (measured: 4 of 24 ``semslam run`` interrupted 1.95-2.1 s after the start, in
``cascadio``'s import and in the first call of a voxel-grid kernel during the recogniser's warm-up) instead of
reporting the interrupt. :func:`critical` marks such a section; the ``semslam`` command's SIGINT handler
(:mod:`semslam.cli.main`) asks :func:`defer_interrupt` and, inside one, only records the Ctrl-C, which is raised
as a ``KeyboardInterrupt`` when the outermost section ends. Outside the command (a library user's own handler)
nothing changes. Sections are short (imports, the warm-up: about a second).

**A Ctrl-C some library swallowed.** The handler's ``KeyboardInterrupt`` can be lost: raised inside a finaliser or
a weakref callback (Python reports it as unraisable and goes on), or caught by a library's ``except
BaseException``. The command then runs to its end. So the handler also records every Ctrl-C
(:func:`note_interrupt`), and an output is committed only when none was seen (:func:`raise_if_interrupted`, called
by :mod:`semslam._outdir` just before it swaps a staged output in): an interrupted command never leaves a result
behind, however the interrupt was lost (measured: a CI run's ``semslam simulate`` interrupted 2 s after its start
wrote its whole mission and exited 130).
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Iterator

__all__ = ["critical", "defer_interrupt", "note_interrupt", "interrupt_seen", "raise_if_interrupted",
           "forget_interrupts"]

_state = {"depth": 0, "pending": False, "seen": False}
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


def note_interrupt() -> None:
    """For a SIGINT handler: record that the process received a Ctrl-C (whether or not it is raised now)."""
    _state["seen"] = True


def interrupt_seen() -> bool:
    """Whether a Ctrl-C was recorded (:func:`note_interrupt`) since the start or :func:`forget_interrupts`."""
    return bool(_state["seen"])


def raise_if_interrupted() -> None:
    """Raise ``KeyboardInterrupt`` when a Ctrl-C was recorded: called before an output is committed, so the work
    of a command whose interrupt a library swallowed is never published."""
    if _state["seen"]:
        raise KeyboardInterrupt


def forget_interrupts() -> None:
    """Clear the record (a caller running commands in its own process, e.g. tests)."""
    _state["seen"] = False
