"""A Ctrl-C never leaves a driver's lock taken (drivers.interrupts).

The hazard, made deterministic: a helper thread holds the lock the main thread is about to
wait for, takes SIGINT itself (so the main thread's wait is not woken by it), then lets go.
The main thread's signal handler then runs the instant the lock is granted, inside
``threading.Condition.__enter__``. Without the held section, the KeyboardInterrupt raised
there leaves the lock taken for good: the aborted run that stalled in CI.
"""

from __future__ import annotations

import concurrent.futures
import logging
import signal
import threading
import time

import can
import pytest

from daq.control import clear_interrupts, latching_interrupt_handler
from drivers.daq import MAX_FRAMES_PER_POLL
from drivers.errors import FramesLost
from drivers.interrupts import future_result, interrupts_held


@pytest.fixture(params=["run's", "python's"])
def ctrl_c_handler(request):
    """A SIGINT handler in place for the test (the main thread only): the run's (daq.control),
    or Python's own, as a script that uses the drivers has it. With Python's, the held sections
    did not hold: a Ctrl-C in a script left the driver's lock taken."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers belong to the main thread")
    handler = (latching_interrupt_handler(KeyboardInterrupt) if request.param == "run's"
               else signal.default_int_handler)
    previous = signal.signal(signal.SIGINT, handler)
    yield
    assert signal.getsignal(signal.SIGINT) is handler  # the sections put back what they found
    signal.signal(signal.SIGINT, previous)
    clear_interrupts()


def _interrupt_while_held(lock) -> threading.Thread:
    """Start a thread that takes ``lock``, waits for the main thread to queue up behind it,
    takes SIGINT itself, and releases ``lock``. Returns once ``lock`` is taken."""
    taken = threading.Event()

    def hold() -> None:
        with lock:
            taken.set()
            time.sleep(0.2)  # the main thread is now waiting for the lock
            signal.pthread_kill(threading.get_ident(), signal.SIGINT)
            time.sleep(0.05)

    th = threading.Thread(target=hold, daemon=True)
    th.start()
    assert taken.wait(5.0)
    return th


def test_an_interrupt_inside_a_held_section_is_raised_when_the_outermost_one_ends(ctrl_c_handler):
    reached = []
    with pytest.raises(KeyboardInterrupt):
        with interrupts_held:
            with interrupts_held:
                signal.raise_signal(signal.SIGINT)
                reached.append("inner")
            reached.append("outer")  # not raised at the inner section's end
    assert reached == ["inner", "outer"]
    with pytest.raises(KeyboardInterrupt):  # outside a section: at once, as before
        signal.raise_signal(signal.SIGINT)
        reached.append("after")
    assert reached == ["inner", "outer"]


def test_ctrl_c_while_the_daq_driver_waits_for_its_bus_queue_leaves_the_queue_free(ctrl_c_handler, rig):
    _, sim, daq = rig
    mutex = daq.bus.queue.mutex  # the virtual bus's receive queue: the simulated DAQ sends into it
    holder = _interrupt_while_held(mutex)
    try:
        with pytest.raises(KeyboardInterrupt):
            daq.request("STATUS")
    finally:
        holder.join(5.0)
        leaked = mutex.locked()
        if leaked:
            mutex.release()  # so that the fixture can close the driver instead of hanging
    assert not leaked, "the KeyboardInterrupt left the driver's bus queue locked"
    # What the leak cost in CI: the stop request from the safe state's thread never answered.
    stopper = threading.Thread(target=daq.safe_state, daemon=True)
    stopper.start()
    stopper.join(5.0)
    assert not stopper.is_alive()
    assert daq.request("STATUS")["result"] == 0  # the simulated DAQ still answers


def test_ctrl_c_while_waiting_for_a_future_leaves_its_condition_free(ctrl_c_handler):
    """The amplifier driver's calls into its event loop wait in :func:`future_result`."""
    fut: concurrent.futures.Future = concurrent.futures.Future()
    # Private, but the lock Future.result waits on is what the event loop's thread takes
    # to set the result.
    holder = _interrupt_while_held(fut._condition)
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        future_result(fut, timeout_s=10.0)
    waited = time.monotonic() - t0
    holder.join(5.0)
    setter = threading.Thread(target=fut.set_result, args=(1,), daemon=True)
    setter.start()
    setter.join(5.0)
    assert not setter.is_alive(), "the KeyboardInterrupt left the future's condition locked"
    assert waited < 2.0  # within a slice of the holder letting go, not at the 10 s timeout


def test_future_result_returns_the_result_or_raises_as_future_result_does():
    pool = concurrent.futures.ThreadPoolExecutor(1)
    try:
        assert future_result(pool.submit(lambda: time.sleep(0.12) or 7), timeout_s=5.0) == 7
        with pytest.raises(ValueError, match="own"):
            future_result(pool.submit(lambda: (_ for _ in ()).throw(ValueError("own"))), timeout_s=5.0)
        t0 = time.monotonic()
        with pytest.raises(TimeoutError):
            future_result(concurrent.futures.Future(), timeout_s=0.2)
        assert 0.2 <= time.monotonic() - t0 < 1.0
    finally:
        pool.shutdown()


def test_one_poll_of_the_bus_drains_a_bounded_number_of_frames(rig):
    """A sender faster than the driver must not keep one poll, and with it a held Ctrl-C,
    going for as long as it sends: each poll stops after MAX_FRAMES_PER_POLL frames."""
    _, sim, daq = rig
    n = MAX_FRAMES_PER_POLL + 500
    with can.Bus(interface="virtual", channel=sim.channel) as other:
        for k in range(n):  # frames of an ID the driver does not use
            other.send(can.Message(arbitration_id=0x7F0, data=bytes([k & 0xFF]), is_extended_id=False))
    assert daq.bus.queue.qsize() == n
    assert daq._pump(0.05)
    assert daq.bus.queue.qsize() == n - MAX_FRAMES_PER_POLL
    assert daq.request("STATUS")["result"] == 0  # later polls drain the rest, and answers come through
    assert daq.bus.queue.qsize() == 0


def test_ctrl_c_while_the_daq_driver_logs_a_gap_leaves_the_log_handler_free(ctrl_c_handler, rig):
    """The one warning the main thread logs mid-run (frames lost, ``on_gap="mark"``) takes
    each handler's lock, which the safe state's threads take too when they log."""
    _, sim, daq = rig
    handler = logging.Handler()  # its emit is never reached: the lock is what matters
    handler.emit = lambda record: None
    logger = logging.getLogger("drivers.daq")
    logger.addHandler(handler)
    daq.on_gap = "mark"
    daq._errors.append(FramesLost("daq: 3 frames lost"))  # as the poll records a gap
    try:
        holder = _interrupt_while_held(handler.lock)
        try:
            with pytest.raises(KeyboardInterrupt):
                daq._raise_errors()
        finally:
            holder.join(5.0)
        other = threading.Thread(target=logger.warning, args=("from another thread",), daemon=True)
        other.start()
        other.join(5.0)
        leaked = other.is_alive()
        if leaked:
            handler.release()  # the main thread owns it: let the other thread finish
            other.join(5.0)
    finally:
        logger.removeHandler(handler)
    assert not leaked, "the KeyboardInterrupt left the log handler's lock taken"
    assert not daq._errors  # the gap was logged, not raised later as an error
