"""Output that never stalls a run: ``ssidlab acquire`` prints through a writer thread.

A write to a pipe or terminal blocks while its reader does not read: a UI whose event loop
is busy drawing (``ssidlab tui`` reads the run's output and hands each line to its loop), a
terminal stopped with Ctrl-S, a ``| less`` at its prompt. If the run's own thread made that
write, the run would stop mid-line with the excitation on, and with it the checks of the
limits, for as long as the reader waits (seen: a run blocked for 20 s in an event print).

:class:`OutputPump` takes ``sys.stdout`` and ``sys.stderr`` over for the length of a run:
their writes go on one queue (so the two keep their order), and one daemon thread writes
them out. The run never waits for its reader. If the reader falls more than
``limit_chars`` behind, further text is dropped and counted, and a line in the printout,
where the gap is, says how many lines are missing: the run file, not the printout, is the
record. When the run ends, :meth:`OutputPump.close` waits a bounded time for the rest to be
read, so a reader that never reads again cannot keep the process (its instruments already
safe) from exiting.

Written by hand because the standard library's ``logging.handlers.QueueHandler`` covers
log records only, not prints, and its listener writes through the stream's buffered layer,
whose lock a daemon thread blocked in a write would hold at interpreter shutdown (CPython
then aborts the process); this writer calls ``os.write`` on the descriptor instead.
"""

from __future__ import annotations

import io
import os
import queue
import sys
import threading
from typing import TextIO

__all__ = ["OutputPump"]

_CLOSE = object()


class _QueuedStream(io.TextIOBase):
    """Stands in for ``sys.stdout`` or ``sys.stderr``: writes go to the pump's queue."""

    def __init__(self, pump: OutputPump, target: TextIO) -> None:
        super().__init__()
        self._pump, self._target = pump, target

    def write(self, s: str) -> int:
        self._pump._put(self._target, s)
        return len(s)

    def flush(self) -> None:
        # Nothing to wait for: the pump writes as soon as the reader reads. A reader that
        # went away is reported here as on a plain stream.
        self._pump._raise_if_broken(self._target)

    def writable(self) -> bool:
        return True

    def isatty(self) -> bool:
        return self._target.isatty()

    def fileno(self) -> int:
        return self._target.fileno()

    @property
    def encoding(self) -> str:  # type: ignore[override]
        return getattr(self._target, "encoding", None) or "utf-8"


class OutputPump:
    """Route ``sys.stdout`` and ``sys.stderr`` through a writer thread until :meth:`close`.

    Parameters
    ----------
    limit_chars : int
        Text queued but not yet read beyond which further writes are dropped (counted).
    """

    def __init__(self, limit_chars: int = 4_000_000) -> None:
        self.limit_chars = int(limit_chars)
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        # Two counters, each written by one side, instead of a lock: a Ctrl-C raised in the
        # run's thread must never find a lock held (the handler runs between any two bytecodes).
        self._chars_in = 0
        self._chars_out = 0
        self.n_dropped_lines = 0
        self._n_said_dropped = 0  # dropped lines a queued note already counts
        self._at_line_start, self._dropping = True, False
        # Per stream: a reader of stdout gone (``| head``) leaves stderr to say so.
        self._broken: dict[int, BrokenPipeError] = {}
        self._saved: tuple[TextIO, TextIO] | None = None
        self._notes: TextIO = sys.stderr  # where the pump's own line goes
        self._thread: threading.Thread | None = None

    # --------------------------------------------------------------------- setup
    def start(self) -> OutputPump:
        """Take over ``sys.stdout`` and ``sys.stderr`` (flushed first) and start the writer."""
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        self._saved = (sys.stdout, sys.stderr)
        self._notes = sys.stderr
        self._thread = threading.Thread(target=self._write_out, name="output-pump", daemon=True)
        self._thread.start()
        sys.stdout = _QueuedStream(self, self._saved[0])  # type: ignore[assignment]
        sys.stderr = _QueuedStream(self, self._saved[1])  # type: ignore[assignment]
        return self

    def close(self, timeout_s: float = 5.0) -> bool:
        """Give the streams back and wait up to ``timeout_s`` for the queued text to be read.

        Returns True if everything queued was written; False if the reader did not read it
        in time: the rest is dropped, and stdout and stderr are pointed at the null device so
        that the command's last prints cannot block either (the writer thread is a daemon
        and dies with the process).
        """
        if self._saved is None:
            return True
        sys.stdout, sys.stderr = self._saved
        self._saved = None
        self._note_dropped()  # the gap at the end of the run's output
        self._queue.put(_CLOSE)
        assert self._thread is not None
        self._thread.join(timeout_s)
        if not self._thread.is_alive():
            return True
        # The reader has stopped reading: what the command still prints (its last lines)
        # would block on the full pipe. Those descriptors now lead nowhere; a write the
        # writer thread is blocked in stays on the old pipe and dies with the process.
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            for stream in (sys.stdout, sys.stderr):
                try:
                    os.dup2(devnull, stream.fileno())
                except (OSError, ValueError):
                    pass
        finally:
            os.close(devnull)
        return False

    def __enter__(self) -> OutputPump:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # --------------------------------------------------------------------- the run's side
    def _put(self, target: TextIO, s: str) -> None:
        self._raise_if_broken(target)
        if not s:
            return
        # Whole lines are kept or dropped (print writes a line's text and its newline apart).
        if self._at_line_start:
            self._dropping = self._chars_in - self._chars_out > self.limit_chars
            if not self._dropping:
                self._note_dropped()  # back under the limit: the note goes where lines are missing
        self._at_line_start = s.endswith("\n")
        if self._dropping:
            self.n_dropped_lines += s.count("\n")
            return
        self._chars_in += len(s)
        self._queue.put((target, s))

    def _note_dropped(self) -> None:
        """Queue a line counting the lines dropped since the last such line, if any."""
        n = self.n_dropped_lines - self._n_said_dropped
        if n <= 0:
            return
        self._n_said_dropped = self.n_dropped_lines
        note = (f"ssidlab: {n} output line(s) dropped here while the output was not read "
                f"(the run file holds every measured line)\n")
        self._chars_in += len(note)
        self._queue.put((self._notes, note))

    def _raise_if_broken(self, target: TextIO) -> None:
        broken = self._broken.get(id(target))
        if broken is not None:
            raise BrokenPipeError(broken.errno, broken.strerror)

    # --------------------------------------------------------------------- the writer
    def _write_out(self) -> None:
        while True:
            item = self._queue.get()
            if item is _CLOSE:
                return
            target, s = item
            if id(target) not in self._broken:
                self._write(target, s)
            self._chars_out += len(s)

    def _write(self, target: TextIO, s: str) -> None:
        encoding = getattr(target, "encoding", None) or "utf-8"
        data = s.encode(encoding, errors="backslashreplace")
        try:
            fd = target.fileno()
        except (OSError, ValueError, AttributeError):
            fd = None
        try:
            if fd is None:  # not a real descriptor (a test's StringIO): its own write
                target.write(s)
                return
            while data:
                data = data[os.write(fd, data):]
        except BrokenPipeError as exc:
            self._broken[id(target)] = exc
        except OSError:
            pass  # a terminal gone; nothing to tell it
