"""Protocol layer: SCPI commands and queries over a line transport, with error-queue checks."""

from __future__ import annotations

import re
import time

from .errors import DeviceError, InstrumentTimeout, ProtocolError
from .serial_line import SerialLine

__all__ = ["ScpiProtocol"]

_ERR_REPLY = re.compile(r'^([+-]?\d+)\s*,\s*"(.*)"$')


class ScpiProtocol:
    """SCPI over a :class:`~drivers.serial_line.SerialLine`.

    ``write`` sends a setting and (by default) reads the error queue afterwards, so a
    rejected setting raises :class:`~drivers.errors.DeviceError` at once instead of leaving
    the instrument in an unknown state.
    """

    def __init__(self, line: SerialLine, name: str = "instrument") -> None:
        self.line = line
        self.name = name

    def query(self, command: str, timeout_s: float | None = None) -> str:
        """Send a query and return its reply line."""
        self.line.write_line(command)
        try:
            return self.line.read_line(timeout_s)
        except InstrumentTimeout as exc:
            raise InstrumentTimeout(f"{self.name}: {command!r}: {exc}") from exc

    def write(self, command: str, check: bool = True) -> None:
        """Send a command; with ``check``, raise if the instrument queued an error for it."""
        if not check:
            self.line.write_line(command)
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
                self.line.write_line("*CLS")
                self.opc()
                return
            except (InstrumentTimeout, ProtocolError) as exc:
                last = exc
        assert last is not None
        raise last
