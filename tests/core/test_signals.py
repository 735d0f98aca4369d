"""Critical sections a Ctrl-C must not cut (semslam._signals): the interrupt is raised when they end."""

from __future__ import annotations

import os
import signal
import threading

import pytest

from semslam._signals import critical, defer_interrupt, forget_interrupts


def test_outside_a_section_nothing_is_deferred():
    assert defer_interrupt() is False


def test_an_interrupt_inside_nested_sections_is_raised_when_the_outermost_ends():
    reached = []
    with pytest.raises(KeyboardInterrupt):
        with critical():
            with critical():
                assert defer_interrupt() is True
                reached.append("inner")
            reached.append("outer")  # the inner section's end does not raise
    assert reached == ["inner", "outer"]
    assert defer_interrupt() is False  # nothing left pending after it was raised
    with critical():
        pass  # a later section without an interrupt ends quietly


def test_the_commands_sigint_handler_lets_a_section_finish_then_raises():
    """A real SIGINT through semslam's command handler (semslam.cli.main): the section runs to its end."""
    from semslam.cli import main as cli_main

    old = signal.signal(signal.SIGINT, cli_main._on_sigint)
    try:
        done = []
        with pytest.raises(KeyboardInterrupt):
            with critical():
                os.kill(os.getpid(), signal.SIGINT)
                for _ in range(1000):  # the handler runs between bytecodes: here, inside the section
                    pass
                done.append(True)
        assert done == [True]
        with pytest.raises(KeyboardInterrupt):  # outside a section: at once
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):
                pass
    finally:
        signal.signal(signal.SIGINT, old)
        forget_interrupts()


def test_a_section_in_another_thread_defers_nothing():
    seen = []
    t = threading.Thread(target=lambda: seen.append(_inside_section()))
    t.start()
    t.join()
    assert seen == [False]


def _inside_section() -> bool:
    with critical():
        return defer_interrupt()


# A command that never ends after its Ctrl-C (semslam._signals.start_watchdog), run as `semslam` runs: console()
# with a main() that swallows every KeyboardInterrupt (the worst library) or takes SIGINT over (as the ROS node).
_NEVER_ENDING = r"""
import signal, sys, time
from pathlib import Path
import semslam._signals as sig
import semslam.cli.main as cli

sig.INTERRUPT_GRACE_S = 1.0
staging, kept, mode = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
for path in (staging, kept):
    path.mkdir()
    (path / "part.bin").write_bytes(b"x")
sig.remove_on_interrupt(staging)
sig.remove_on_interrupt(staging / "part.bin")


def swallow(argv=None):
    if mode == "takes_over":
        signal.signal(signal.SIGINT, lambda *a: None)
    end = time.monotonic() + (3.0 if mode == "takes_over" else 20.0)
    ready = False
    while True:
        try:  # "ready" printed inside: the one Ctrl-C, sent once it is read, cannot escape
            if not ready:
                ready = True
                print("ready", flush=True)
            while time.monotonic() < end:
                time.sleep(0.02)
            return 0
        except KeyboardInterrupt:
            continue


cli.main = swallow
cli.console()
"""


def _interrupt_never_ending(tmp_path, mode: str):
    import subprocess
    import sys

    staging, kept = tmp_path / ".out.semslam-1-x.tmp", tmp_path / "earlier"
    proc = subprocess.Popen([sys.executable, "-c", _NEVER_ENDING, str(staging), str(kept), mode],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        os.kill(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    return proc.returncode, err, staging, kept


@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
def test_a_command_that_swallows_its_ctrl_c_is_ended_by_the_watchdog_with_its_staging_removed(tmp_path):
    code, err, staging, kept = _interrupt_never_ending(tmp_path, "swallows")
    assert code == 130, err
    assert err.strip().splitlines() == ["semslam: interrupted"]
    assert not staging.exists()  # recorded: removed
    assert (kept / "part.bin").read_bytes() == b"x"  # not recorded: untouched


@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
def test_a_command_that_took_sigint_over_is_not_ended_by_the_watchdog(tmp_path):
    code, err, staging, _ = _interrupt_never_ending(tmp_path, "takes_over")
    assert code == 0, err  # ran its 3 s to the end, past the 1-s grace
    assert err == "" and staging.is_dir()


def test_the_watchdog_is_not_started_off_the_main_thread():
    from semslam._signals import start_watchdog

    started = []
    t = threading.Thread(target=lambda: started.append(start_watchdog(lambda *a: None)))
    t.start()
    t.join()
    assert started == [False]
