"""Ctrl-C held back while a driver waits on a lock that another thread also takes.

CPython runs a signal handler between two bytecodes of the main thread, wherever that is,
and the exception it raises (KeyboardInterrupt for Ctrl-C) propagates from there. Raised in
Python code that has just taken a lock and returns it to a ``with`` not yet in place, it
leaves the lock taken for good. ``threading.Condition.__enter__`` is such code, and every
``queue.Queue.get`` and ``concurrent.futures.Future.result`` passes through it. The likeliest
moment is the worst one: the main thread waits for a contended lock, the signal lands on
another thread, and the handler runs the instant the lock is granted.

That is how an aborted run once stalled in CI. The virtual CAN bus's receive queue was left
locked; the simulated DAQ blocked for good sending into it; the driver's stop request, sent
from another thread, waited on the same queue and was never answered.
``tests/test_driver_interrupts.py`` reproduces that deterministically.

Drivers therefore wrap such waits in :data:`interrupts_held`. A signal handler that asks
:func:`hold_interrupt` first raises at once outside those sections and, inside one, when the
outermost section ends (its waits are short: a bus poll, a slice of a future's wait). Only the
main thread runs Python signal handlers, so only its sections count. Where SIGINT still has
Python's own handler (a script that uses the drivers without ``ssidlab``'s), a section puts
one that asks :func:`hold_interrupt` in its place while it lasts: with Python's, a Ctrl-C in a
script left a lock taken and a driver's ``close()`` hung, or the amplifier enabled.

The drivers' ``close()`` also hold Ctrl-C back while they bring their instrument to its safe
state: interrupted there, the excitation stayed on.
"""

from __future__ import annotations

import concurrent.futures
import signal
import threading
import time
from typing import Any

__all__ = ["future_result", "hold_interrupt", "interrupts_held"]


class _HeldSection:
    """Context manager (reentrant) marking code the main thread must not be interrupted in."""

    __slots__ = ("depth", "pending", "_main", "_put_handler")

    def __init__(self) -> None:
        self.depth = 0
        self.pending: type[BaseException] | None = None
        self._main = threading.main_thread().ident
        self._put_handler = False

    def __enter__(self) -> _HeldSection:
        if threading.get_ident() == self._main:
            if self.depth == 0:
                self._put_handler = _hold_in_pythons_place()
            self.depth += 1
        return self

    def __exit__(self, *exc) -> bool:
        if threading.get_ident() == self._main:
            if self.depth == 1 and self._put_handler:
                signal.signal(signal.SIGINT, signal.default_int_handler)
                self._put_handler = False
            self.depth -= 1
            if self.depth == 0 and self.pending is not None:
                exc_type, self.pending = self.pending, None
                raise exc_type()
        return False


def _holding_int_handler(signum, frame) -> None:
    """Python's SIGINT handler, but held back inside :data:`interrupts_held`."""
    if not hold_interrupt(KeyboardInterrupt):
        raise KeyboardInterrupt


def _hold_in_pythons_place() -> bool:
    """Put :func:`_holding_int_handler` in place of Python's SIGINT handler (main thread);
    True if it did. A handler someone else installed stays: it is theirs to hold with."""
    try:
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            signal.signal(signal.SIGINT, _holding_int_handler)
            return True
    except ValueError:  # not the main interpreter's main thread
        pass
    return False


#: ``with interrupts_held:`` around a call that takes a lock another thread also takes.
interrupts_held = _HeldSection()


def hold_interrupt(exc_type: type[BaseException]) -> bool:
    """For a signal handler: True if the main thread is inside :data:`interrupts_held`;
    ``exc_type()`` is then raised when it leaves the outermost section."""
    if interrupts_held.depth:
        interrupts_held.pending = exc_type
        return True
    return False


def future_result(fut: concurrent.futures.Future, timeout_s: float, slice_s: float = 0.05) -> Any:
    """``fut.result(timeout_s)``, waited for in slices of ``slice_s`` with interrupts held.

    A Ctrl-C comes through between two slices, within ``slice_s``, and never inside the
    future's condition. Raises ``TimeoutError`` as ``Future.result`` does: the call's own
    (``fut.done()``) or the wait's, at ``timeout_s``.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        left = deadline - time.monotonic()
        with interrupts_held:
            try:
                return fut.result(max(0.0, min(slice_s, left)))
            except TimeoutError:
                if fut.done() or left <= slice_s:
                    raise
