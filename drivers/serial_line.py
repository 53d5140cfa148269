"""Transport layer: a line-oriented serial link (pyserial), with timeouts on every read.

Works with any pyserial URL: a device (``/dev/ttyUSB0``, a pseudo-terminal ``/dev/pts/N``)
or ``socket://host:port`` (a serial-over-TCP converter, or the simulator's socket).
"""

from __future__ import annotations

import serial

from .errors import ConnectionLost, InstrumentTimeout, ProtocolError

__all__ = ["SerialLine"]


class SerialLine:
    """A serial link that sends and receives text lines.

    Parameters
    ----------
    url : str
        Port name or pyserial URL.
    baudrate : int
        Bits per second (ignored by sockets and pseudo-terminals).
    timeout_s : float
        Longest wait for a complete reply line. A line that has started but not ended by
        then is a timeout too (a partial line is never returned as a reply).
    terminator : bytes
        Line terminator, sent after each command and expected after each reply.
    max_line_bytes : int
        Longest acceptable reply; more without a terminator is a protocol error.
    """

    def __init__(
        self,
        url: str,
        baudrate: int = 115200,
        timeout_s: float = 1.0,
        terminator: bytes = b"\n",
        max_line_bytes: int = 1 << 16,
    ) -> None:
        if not timeout_s > 0:
            raise ValueError("timeout_s must be > 0 (a read without timeout could hang)")
        self.url = url
        self.timeout_s = float(timeout_s)
        self.terminator = terminator
        self.max_line_bytes = max_line_bytes
        try:
            self._port = serial.serial_for_url(
                url, baudrate=baudrate, timeout=self.timeout_s, write_timeout=self.timeout_s
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise ConnectionLost(f"cannot open serial port {url!r}: {exc}") from exc

    def write_line(self, text: str) -> None:
        """Send ``text`` plus the terminator."""
        try:
            self._port.write(text.encode("ascii") + self.terminator)
            self._port.flush()
        except serial.SerialTimeoutException as exc:
            raise InstrumentTimeout(f"{self.url}: write timed out ({self.timeout_s:g} s)") from exc
        except (serial.SerialException, OSError) as exc:
            raise ConnectionLost(f"{self.url}: write failed: {_detail(exc, 'write failed: ')}") from exc

    def read_line(self, timeout_s: float | None = None) -> str:
        """One reply line without its terminator.

        Raises
        ------
        InstrumentTimeout
            Nothing, or only part of a line, arrived within the timeout.
        ProtocolError
            The reply is not ASCII text.
        """
        timeout = self.timeout_s if timeout_s is None else timeout_s
        self._port.timeout = timeout
        try:
            raw = self._port.read_until(self.terminator, self.max_line_bytes)
        except (serial.SerialException, OSError) as exc:
            raise ConnectionLost(f"{self.url}: read failed: {_detail(exc, 'read failed: ')}") from exc
        if not raw.endswith(self.terminator):
            if len(raw) >= self.max_line_bytes:
                raise ProtocolError(f"{self.url}: reply longer than {self.max_line_bytes} bytes")
            what = f"partial line {raw[:40]!r}" if raw else "no reply"
            raise InstrumentTimeout(f"{self.url}: {what} within {timeout:g} s")
        try:
            return raw[: -len(self.terminator)].decode("ascii").strip()
        except UnicodeDecodeError:
            raise ProtocolError(f"{self.url}: garbled reply {raw[:40]!r}") from None

    def discard_input(self) -> None:
        """Throw away whatever is waiting to be read (resynchronise after a fault)."""
        try:
            self._port.reset_input_buffer()
        except (serial.SerialException, OSError):
            pass

    def close(self) -> None:
        try:
            self._port.close()
        except (serial.SerialException, OSError):
            pass

    @property
    def is_open(self) -> bool:
        return bool(self._port.is_open)


def _detail(exc: BaseException, said: str) -> str:
    """The exception's text without what our message says already (pyserial's socket://
    transport words its own errors "read failed: ...")."""
    return str(exc).removeprefix(said)
