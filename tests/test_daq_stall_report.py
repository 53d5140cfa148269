"""Where a run that does not reach its safe state waits (``daq.run._stall_report``,
``daq.thread_stacks``): every thread's stack on stderr, read with the GIL held. The report's
timing in a clean process: ``tests/test_daq_interrupt.py``."""

from __future__ import annotations

import sys
import threading
import time

from daq.run import _stall_report
from daq.thread_stacks import thread_stacks


def waiting_for_the_amplifier(seconds: float) -> None:
    time.sleep(seconds)


def test_a_block_past_the_limit_prints_every_threads_stack_once(capfd):
    """0.8 s in a block allowed 0.2 s: one report, naming the call that waits and the other
    threads' stacks; not the watchdog's own."""
    stop = threading.Event()
    other = threading.Thread(target=stop.wait, name="other", daemon=True)
    other.start()
    try:
        with _stall_report(after_s=0.2):
            waiting_for_the_amplifier(0.8)
    finally:
        stop.set()
        other.join()
    err = capfd.readouterr().err
    assert err.count("the safe state is not reached after 0.2 s") == 1, err
    assert "in waiting_for_the_amplifier" in err, err
    assert f"Thread 0x{other.ident:016x}" in err, err
    assert " in watch\n" not in err, err


def test_a_block_within_the_limit_leaves_no_thread():
    """(That it prints nothing: tests/test_daq_interrupt.py, in a process of its own.)"""
    before = threading.active_count()
    with _stall_report(after_s=5.0):
        pass
    assert threading.active_count() == before


def test_the_current_thread_is_shown_from_the_frame_given():
    """A signal handler passes the frame it interrupted: the stack shown for its thread ends
    there, not in the handler."""
    def handler_like() -> str:
        caller = sys._getframe(1)
        return thread_stacks(current=(threading.get_ident(), caller))

    text = handler_like()
    me = text[text.index("Current thread"):]
    me = me[: me.index("\n\n")]
    assert "in test_the_current_thread_is_shown_from_the_frame_given" in me
    assert "in handler_like" not in me


def test_no_thread_to_be_had_still_runs_the_block(monkeypatch):
    """The report guards the way to the safe state: when no thread can be started (a
    process at its thread limit), the block runs without it instead of raising."""
    def refuse(self):
        raise RuntimeError("can't start new thread")

    monkeypatch.setattr(threading.Thread, "start", refuse)
    ran = []
    with _stall_report(after_s=0.1):
        ran.append(True)
    assert ran == [True]
