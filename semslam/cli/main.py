"""Entry point of the ``semslam`` command.

Sub-commands are discovered: every module ``semslam/cli/cmd_*.py`` defines
``register(subparsers, common)`` and adds its parsers with ``parser.set_defaults(func=run)``, where
``run(args) -> int``. ``common`` is a parent parser carrying ``--json``, so that ``--json`` works both
before the sub-command (global) and after it. Heavy imports belong inside ``run``. A command line naming a
sub-command ``X`` defined by ``cmd_X.py`` builds only that module's parsers; help, errors and the commands of
modules with another name (``montecarlo`` in ``cmd_slam.py``) build them all.

Errors: a :class:`~semslam.errors.SemslamError` prints one line ``semslam: error: ...`` on stderr and
exits 1; a usage error exits 2 (argparse); a Ctrl-C at any moment prints ``semslam: interrupted`` and exits 130
(:func:`console`); anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import atexit
import gc
import os
import importlib
import pkgutil
import signal
import sys
from typing import Sequence

from .. import __version__
from ..errors import SemslamError
from .._signals import (defer_interrupt, interrupt_reported, interrupt_seen, note_interrupt, note_reported,
                        start_watchdog)


def _command_modules() -> list[str]:
    from . import __path__ as cli_path

    return sorted(info.name for info in pkgutil.iter_modules(cli_path) if info.name.startswith("cmd_"))


def _command_module(argv: Sequence[str]) -> str | None:
    """``cmd_X`` when the sub-command in ``argv`` (its first argument that is not an option: the global options
    take no value) is ``X`` and ``semslam/cli/cmd_X.py`` exists, else None."""
    command = next((a for a in argv if not a.startswith("-")), None)
    return f"cmd_{command}" if command is not None and f"cmd_{command}" in _command_modules() else None


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The ``semslam`` parser with the sub-commands of every ``cmd_*`` module, or of the module ``only``."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                        help="print machine-readable JSON instead of text")
    parser = argparse.ArgumentParser(
        prog="semslam",
        description="Object-level SLAM for underwater vehicles: recognise known objects in laser scans, "
                    "estimate their pose, and use them as landmarks.",
    )
    parser.add_argument("--version", action="version", version=f"semslam {__version__}")
    parser.add_argument("--json", action="store_true", default=False,
                        help="print machine-readable JSON instead of text")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _command_modules():
        if only in (None, name):
            importlib.import_module(f"{__package__}.{name}").register(sub, common)
    return parser


#: one-scan commands whose run is mostly start-up: the cyclic garbage collector is paused while they run
_GC_PAUSED_COMMANDS = ("recognize",)


def main(argv: Sequence[str] | None = None) -> int:
    # The interpreter's final garbage collections traverse every object still alive at exit (numba's typing
    # registries and loaded kernels, scipy): ~0.25 s of a cold `semslam recognize`. gc.freeze at exit skips
    # that work (the objects are not collected, the process ends); the atexit handlers registered before this
    # one (logging, numba, weakref.finalize) still run after it. Registered once however often main() runs.
    atexit.unregister(gc.freeze)
    atexit.register(gc.freeze)
    note_reported(False)
    if argv is None:
        argv = sys.argv[1:]
    try:  # building the parsers imports the command's module: a Ctrl-C then is an interrupt like any other
        parser = build_parser(_command_module(argv))
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        from threadpoolctl import threadpool_limits
    except KeyboardInterrupt:
        return _interrupted()

    # A single-scan `recognize` spends its start importing numba and scipy and loading kernels: ~10^5 long-lived
    # objects that the cyclic collector traverses again and again and never frees (~0.1 s of ~1.1 s, measured
    # interleaved). The collector is paused for that command and resumed after it: main() may run inside a
    # caller's process (tests, notebooks), whose collector must come back as it was.
    pause_gc = args.command in _GC_PAUSED_COMMANDS and gc.isenabled()
    if pause_gc:
        gc.disable()
    try:
        # semslam's linear algebra is on small matrices (filter blocks, 3x3 fits, per-cluster PCA): BLAS threads
        # only spin on them (the SLAM ran 6x slower with OpenBLAS's 2 threads on a busy 2-core machine)
        with threadpool_limits(limits=1, user_api="blas"):
            return int(args.func(args) or 0)
    except SemslamError as exc:
        message = " ".join(str(exc).split())
        print(f"semslam: error: {message}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # e.g. `semslam info X --json | head`
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    except KeyboardInterrupt:
        return _interrupted()
    except Exception as exc:
        # after a Ctrl-C, whatever the interrupt left behind: wrapped by a compiled kernel (numba: a SystemError
        # from it) or a library module half-imported (a NameError in its __init__ later)
        if _from_interrupt(exc) or interrupt_seen():
            return _interrupted()
        raise
    finally:
        if pause_gc:
            gc.enable()


def _interrupted() -> int:
    """A Ctrl-C: one line (once), exit status 130 (128 + SIGINT)."""
    if not interrupt_reported():  # (shared with the watchdog: semslam._signals)
        print("semslam: interrupted", file=sys.stderr)
        note_reported()
    return 130


def _on_sigint(signum, frame) -> None:
    note_interrupt()  # recorded even if a library swallows the exception: no output is committed after it
    if defer_interrupt():  # loading native code (semslam._signals): raised when that section ends
        return
    raise KeyboardInterrupt


def _unraisable(hook):
    """``sys.unraisablehook`` that stays silent about a KeyboardInterrupt (raised in a finaliser or a callback
    after a Ctrl-C: the command reports the interrupt itself) and passes anything else to ``hook``."""
    def silent(unraisable) -> None:
        if not isinstance(unraisable.exc_value, KeyboardInterrupt):
            hook(unraisable)

    return silent


def _from_interrupt(exc: BaseException) -> bool:
    """Whether ``exc`` was caused by a KeyboardInterrupt (its chain of causes and contexts)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def console() -> None:
    """The ``semslam`` command (``[project.scripts]``): :func:`main`, whose interrupts at any moment — start-up
    included — end with one line and status 130, never a traceback. Once main returns, further Ctrl-Cs are
    ignored: the interpreter's exit (atexit handlers of numba, Dask, logging) is not interrupted half-way."""
    signal.signal(signal.SIGINT, _on_sigint)
    start_watchdog(_on_sigint)  # a Ctrl-C ends the command even where the interrupt cannot (semslam._signals)
    sys.unraisablehook = _unraisable(sys.unraisablehook)
    try:
        code = main()
    except KeyboardInterrupt:  # between main's own handlers (e.g. in its finally clause)
        code = _interrupted()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if interrupt_seen():  # a Ctrl-C some library swallowed: its work was not committed, the run says so
        code = _interrupted()
    if code == 130:
        # Interrupted: leave now. CPython remembers a KeyboardInterrupt raised inside code it ran for a library
        # (and then re-raises SIGINT at exit, status -2), and the atexit handlers have nothing left to finish:
        # the staging folders were removed as the interrupt unwound.
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(130)
    sys.exit(code)


if __name__ == "__main__":  # pragma: no cover
    console()
