"""Transport layer: CAN FD frames tunnelled over a TCP stream (a python-can bus).

The standalone simulated lab (``ssidlab sim-lab``) cannot share python-can's in-process
virtual bus with another process, so it bridges its bus to TCP on 127.0.0.1, the way an
Ethernet-CAN gateway bridges a real bus. This class is the client end: a
:class:`can.BusABC`, so the DAQ driver uses it exactly like any other interface.

Wire format, both directions, little-endian, one record per frame::

    u32  can_id    bits 0..28 the identifier, bit 31 set for a 29-bit identifier
    u8   flags     bit0 CAN FD, bit1 bit-rate switch, bit2 error-state indicator,
                   bit3 error frame
    u8   length    data bytes that follow (0..64)
    f64  timestamp seconds (sender's clock)
    ...  data
"""

from __future__ import annotations

import select
import socket
import struct

import can

from .errors import ConnectionLost

__all__ = ["RECORD", "TcpCanBus", "pack_frame"]

RECORD = struct.Struct("<IBBd")
EXT_FLAG = 1 << 31


def pack_frame(msg: can.Message) -> bytes:
    """One wire record for ``msg``."""
    flags = (msg.is_fd << 0) | (msg.bitrate_switch << 1) | (msg.error_state_indicator << 2) | (msg.is_error_frame << 3)
    cid = msg.arbitration_id | (EXT_FLAG if msg.is_extended_id else 0)
    data = bytes(msg.data)
    return RECORD.pack(cid, flags, len(data), msg.timestamp or 0.0) + data


class TcpCanBus(can.BusABC):
    """A CAN FD bus reached through a TCP gateway.

    Parameters
    ----------
    host, port : str, int
        Gateway address.
    connect_timeout_s : float
        Connection timeout.
    """

    def __init__(self, host: str, port: int, connect_timeout_s: float = 2.0, **kwargs) -> None:
        try:
            self._sock = socket.create_connection((host, port), timeout=connect_timeout_s)
        except OSError as exc:
            raise ConnectionLost(f"CAN gateway {host}:{port}: cannot connect: {exc}") from exc
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock.settimeout(None)
        self._buf = bytearray()
        self.channel_info = f"CAN FD over TCP {host}:{port}"
        super().__init__(channel=f"{host}:{port}", **kwargs)
        self._can_protocol = can.CanProtocol.CAN_FD

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        try:
            self._sock.settimeout(timeout if timeout is not None else 5.0)
            self._sock.sendall(pack_frame(msg))
        except OSError as exc:
            raise can.CanOperationError(f"{self.channel_info}: send failed: {exc}") from exc

    def _parse(self) -> can.Message | None:
        if len(self._buf) < RECORD.size:
            return None
        cid, flags, length, ts = RECORD.unpack_from(self._buf)
        end = RECORD.size + length
        if length > 64:
            raise can.CanOperationError(f"{self.channel_info}: corrupt stream (length {length})")
        if len(self._buf) < end:
            return None
        data = bytes(self._buf[RECORD.size : end])
        del self._buf[:end]
        return can.Message(
            timestamp=ts, arbitration_id=cid & 0x1FFFFFFF, is_extended_id=bool(cid & EXT_FLAG),
            is_fd=bool(flags & 1), bitrate_switch=bool(flags & 2), error_state_indicator=bool(flags & 4),
            is_error_frame=bool(flags & 8), data=data, dlc=length, is_rx=True, channel=self.channel_info,
        )

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        msg = self._parse()
        if msg is not None:
            return msg, False
        ready, _, _ = select.select([self._sock], [], [], timeout)
        if not ready:
            return None, False
        try:
            chunk = self._sock.recv(1 << 16)
        except OSError as exc:
            raise can.CanOperationError(f"{self.channel_info}: receive failed: {exc}") from exc
        if not chunk:
            raise can.CanOperationError(f"{self.channel_info}: gateway closed the connection")
        self._buf += chunk
        return self._parse(), False

    def shutdown(self) -> None:
        super().shutdown()
        try:
            self._sock.close()
        except OSError:
            pass
