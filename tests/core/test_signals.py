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
