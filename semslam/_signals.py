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

**A Ctrl-C that never ends the command.** Whatever the cause (a first run on a fresh checkout compiles its kernels
inside the warm-up's critical section: measured, a Ctrl-C 1.4-1.7 s into ``semslam run`` waited more than 17 s for
the compilation; a library that swallows every interrupt and loops; or a cause not found: once, a CI run's ``semslam
run`` interrupted 0.3 s after its start still ran 300 s later), the user's Ctrl-C must end the command.
:func:`start_watchdog` (the ``semslam`` command calls it) starts a thread that Python's C-level signal handler wakes
(:func:`signal.set_wakeup_fd`: it is written even while the main thread is stuck in native code); if the process
still runs :data:`INTERRUPT_GRACE_S` after a Ctrl-C taken by the command's own handler, the thread removes the
staging folders and temporary files this process made (:func:`remove_on_interrupt`: never an earlier output moved
aside during a swap), writes ``semslam: interrupted`` and ends the process with status 130. A command that took
SIGINT over (the ROS node: a Ctrl-C is its normal end, then it writes its run) is not ended.
"""

from __future__ import annotations

import os
import select
import shutil
import signal
import threading
import time
from contextlib import contextmanager
from typing import Iterator

__all__ = ["critical", "defer_interrupt", "note_interrupt", "interrupt_seen", "raise_if_interrupted",
           "forget_interrupts", "start_watchdog", "remove_on_interrupt", "note_reported", "interrupt_reported",
           "INTERRUPT_GRACE_S"]

#: seconds a command has, after a Ctrl-C, to end by itself before the watchdog ends it (the unwinding waits for the
#: scans in recognition: a few seconds)
INTERRUPT_GRACE_S = 20.0

_state = {"depth": 0, "pending": False, "seen": False, "reported": False}
#: staging folders and temporary files of this process, removed by the watchdog (see remove_on_interrupt)
_to_remove: set[str] = set()
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


def note_reported(reported: bool = True) -> None:
    """For the command: the interrupt was reported on stderr (the watchdog then does not report it again); False
    clears the record (a new command in the same process)."""
    _state["reported"] = bool(reported)


def interrupt_reported() -> bool:
    """Whether the interrupt was reported on stderr (:func:`note_reported`)."""
    return bool(_state["reported"])


def remove_on_interrupt(path) -> None:
    """Record ``path`` (a staging folder or temporary file this process just made, holding nothing else) for removal
    should the watchdog end the process. Paths renamed or removed since are harmless: nothing new takes their
    random names."""
    _to_remove.add(os.fspath(path))


def start_watchdog(handler) -> bool:
    """Main thread only: end the process :data:`INTERRUPT_GRACE_S` after a Ctrl-C that ``handler`` (the installed
    SIGINT handler) took, if it still runs (see the module's docstring). False (nothing started) where a wake-up
    descriptor is already in use (an event loop's) or off the main thread."""
    if threading.current_thread() is not threading.main_thread():
        return False
    r, w = os.pipe()
    os.set_blocking(w, False)
    try:
        previous = signal.set_wakeup_fd(w, warn_on_full_buffer=False)
    except ValueError:
        previous = None
    if previous != -1:  # someone else's descriptor (or none could be set): leave it
        if previous is not None:
            signal.set_wakeup_fd(previous)
        os.close(r)
        os.close(w)
        return False
    threading.Thread(target=_watch, args=(r, handler), name="semslam-interrupt-watchdog", daemon=True).start()
    return True


def _watch(r: int, handler) -> None:
    """The watchdog's thread: wait for a SIGINT taken by ``handler``, then give the command its grace period."""
    while True:
        data = os.read(r, 64)
        if not data:
            return
        if signal.SIGINT in data and signal.getsignal(signal.SIGINT) is handler:
            break
    deadline = time.monotonic() + INTERRUPT_GRACE_S
    while (left := deadline - time.monotonic()) > 0:
        select.select([], [], [], left)
    for path in sorted(_to_remove, key=len, reverse=True):
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path, ignore_errors=True)
        else:
            try:
                os.unlink(path)
            except OSError:
                pass
    if not interrupt_reported():
        try:
            os.write(2, b"semslam: interrupted\n")
        except OSError:  # stderr closed: the status says it
            pass
    os._exit(130)
