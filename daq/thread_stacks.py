"""Every thread's Python stack, written to stderr: where a run that does not stop waits.

Hand-written instead of :mod:`faulthandler` because faulthandler reads the other threads'
frames from C without the GIL, while those threads run: its ``register`` handler crashed a
run on Python 3.11 (a segfault in CI, cpython#116008) and its ``dump_traceback_later``
watchdog thread can crash the same way (cpython#131580). Here the frames are read by Python
code holding the GIL (``sys._current_frames``), so none changes while it is read. The price:
a thread stuck in C code that holds the GIL delays the report until it returns (a wait on a
lock, a socket or a sleep releases it).

Both functions take no lock another thread may hold (no ``threading.enumerate``, no buffered
stream), so that a signal handler may call them.
"""

from __future__ import annotations

import os
import sys
import threading
import traceback
from types import FrameType


def thread_stacks(current: tuple[int, FrameType] | None = None, skip: int | None = None) -> str:
    """Every thread's stack, most recent call first, in faulthandler's layout.

    Parameters
    ----------
    current : (thread ident, frame), optional
        The thread to head ``Current thread`` and the frame to show it from (a signal
        handler's interrupted frame instead of the handler's own).
    skip : thread ident, optional
        A thread left out (a watchdog's own).
    """
    main = threading.main_thread().ident  # a module global: no lock
    lines = []
    for ident, top in sys._current_frames().items():
        if ident == skip:
            continue
        is_current = current is not None and ident == current[0]
        # Most recent first, as walked; the source lines, never printed, are not read.
        stack = traceback.StackSummary.extract(traceback.walk_stack(current[1] if is_current else top),
                                               lookup_lines=False)
        head = "Current thread" if is_current else "Thread"
        lines.append(f"{head} 0x{ident:016x}{' (main)' if ident == main else ''} (most recent call first):")
        lines.extend(f'  File "{f.filename}", line {f.lineno} in {f.name}' for f in stack)
        lines.append("")
    return "\n".join(lines) + "\n"


def write_to_stderr(text: str) -> None:
    """``text`` to the process's stderr descriptor, unbuffered; nothing if there is none."""
    data = text.encode("utf-8", "replace")
    try:
        fd = sys.__stderr__.fileno()
        while data:
            data = data[os.write(fd, data):]
    except (OSError, ValueError, AttributeError):  # no stderr left to write to
        pass
