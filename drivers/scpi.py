"""Protocol layer: SCPI commands and queries over a line transport, with error-queue checks."""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Iterator
from contextlib import contextmanager

from .errors import ConnectionLost, DeviceError, InstrumentTimeout, ProtocolError
from .serial_line import SerialLine

__all__ = ["ScpiProtocol"]

log = logging.getLogger(__name__)

_ERR_REPLY = re.compile(r'^([+-]?\d+)\s*,\s*"(.*)"$')
#: Re-synchronising query and its reply: two ``*OPC?`` in one line are answered by the one
#: line ``1;1``, which is no reply to anything else the drivers send (a late ``*OPC?`` or
#: ``OUTP?`` reply is a plain ``1``), so a late reply is not taken for it.
_SYNC_QUERY, _SYNC_REPLY = "*OPC?;*OPC?", "1;1"


class ScpiProtocol:
    """SCPI over a :class:`~drivers.serial_line.SerialLine`.

    ``write`` sends a setting and (by default) reads the error queue afterwards, so a
    rejected setting raises :class:`~drivers.errors.DeviceError` at once instead of leaving
    the instrument in an unknown state.
    """

    def __init__(self, line: SerialLine, name: str = "instrument") -> None:
        self.line = line
        self.name = name
        self._stale = False  # a query timed out: its reply may still come

    def query(self, command: str, timeout_s: float | None = None) -> str:
        """Send a query and return its reply line."""
        self._send(command)
        with self._link(repr(command)):
            return self.line.read_line(timeout_s)

    @contextmanager
    def _link(self, what: str) -> Iterator[None]:
        """The line's time-outs and link errors, naming this instrument and ``what`` was sent
        (the line names only its port, which does not say which instrument a run lost).

        After a time-out a reply may still come: the next command re-synchronises first.
        """
        try:
            yield
        except InstrumentTimeout as exc:
            self._stale = True
            raise InstrumentTimeout(f"{self.name}: {what}: {exc}") from exc
        except ConnectionLost as exc:
            raise ConnectionLost(f"{self.name}: {what}: {exc}") from exc

    def _send(self, command: str) -> None:
        """Send one line, after re-synchronising if a reply may be late."""
        if self._stale:
            with self._link(f"{_SYNC_QUERY!r} (re-synchronising before {command!r})"):
                self._sync()
        with self._link(repr(command)):
            self.line.write_line(command)

    def _sync(self) -> None:
        """Read up to the reply of :data:`_SYNC_QUERY`, dropping every line before it.

        A reply that comes after its query timed out would otherwise be read as the reply
        to the next command, and every later command would get its predecessor's reply (a
        refused setting taken as accepted). The instrument answers in order, so the late
        reply, if any, comes before the sync reply.
        """
        self.line.discard_input()
        self.line.write_line(_SYNC_QUERY)
        deadline = time.monotonic() + self.line.timeout_s
        while (reply := self._read_until(deadline)) != _SYNC_REPLY:
            log.debug("%s: late reply %r dropped", self.name, reply[:60])
        self._stale = False

    def _read_until(self, deadline: float) -> str:
        """The next reply line before ``deadline``; a garbled one is returned as its error text."""
        left = deadline - time.monotonic()
        if left <= 0:
            raise InstrumentTimeout(f"{self.line.url}: no {_SYNC_REPLY!r} within {self.line.timeout_s:g} s")
        try:
            return self.line.read_line(left)
        except ProtocolError as exc:
            return str(exc)

    def write(self, command: str, check: bool = True) -> None:
        """Send a command; with ``check``, raise if the instrument queued an error for it."""
        if not check:
            self._send(command)
            return
        # Command and error query in one line (";:" returns to the root): one round trip,
        # and no wait on TCP's Nagle/delayed-ACK between two small writes on socket links.
        first = self.query(f"{command};:SYST:ERR?")
        errors = [self._parse_error(first)]
        if errors[0][0] == 0:
            return
        errors += self.read_errors()
        listed = "; ".join(f"{c} {m}" for c, m in errors)
        raise DeviceError(f"{self.name}: instrument error after {command!r}: {listed}")

    def _parse_error(self, reply: str) -> tuple[int, str]:
        m = _ERR_REPLY.match(reply)
        if not m:
            raise ProtocolError(f"{self.name}: unexpected SYST:ERR? reply {reply[:60]!r}")
        return int(m.group(1)), m.group(2)

    def read_errors(self, max_errors: int = 32) -> list[tuple[int, str]]:
        """Drain the error queue (``SYSTem:ERRor?`` until ``+0``)."""
        errors = []
        for _ in range(max_errors):
            code, msg = self._parse_error(self.query("SYST:ERR?"))
            if code == 0:
                return errors
            errors.append((code, msg))
        raise ProtocolError(f"{self.name}: error queue did not empty after {max_errors} reads")

    def check_errors(self, context: str = "") -> None:
        errors = self.read_errors()
        if errors:
            listed = "; ".join(f"{c} {m}" for c, m in errors)
            where = f" after {context!r}" if context else ""
            raise DeviceError(f"{self.name}: instrument error{where}: {listed}")

    def opc(self, timeout_s: float | None = None) -> None:
        """Wait until pending operations are complete (``*OPC?`` -> ``1``)."""
        reply = self.query("*OPC?", timeout_s)
        if reply != "1":
            raise ProtocolError(f"{self.name}: unexpected *OPC? reply {reply[:60]!r}")

    def resync(self, attempts: int = 3) -> None:
        """Recover the dialogue after a timeout or garbage: flush, clear, confirm with ``*OPC?``.

        Raises the last error when the instrument still does not answer properly.
        """
        last: Exception | None = None
        for _ in range(attempts):
            time.sleep(0.02)  # let a late reply arrive so that it is flushed, not read later
            self.line.discard_input()
            try:
                with self._link(f"'*CLS', {_SYNC_QUERY!r}"):
                    self.line.write_line("*CLS")
                    self._sync()  # *OPC? with a reply that a late one cannot be taken for
                return
            except (InstrumentTimeout, ProtocolError) as exc:
                last = exc
        assert last is not None
        raise last
