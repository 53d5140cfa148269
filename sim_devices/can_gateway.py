"""A CAN-over-TCP gateway on 127.0.0.1: the simulated lab's CAN bus, reachable from other processes.

Each TCP client gets its own node on the in-process python-can virtual bus; frames are
copied both ways in the wire format of :mod:`drivers.can_tcp` (documented in
``docs/drivers.md``; repeated here because simulators do not import drivers)::

    <u32 can_id | bit31 extended> <u8 flags: FD, BRS, ESI, error> <u8 length> <f64 timestamp> data
"""

from __future__ import annotations

import select
import socket
import struct
import threading

import can

__all__ = ["CanTcpGateway"]

RECORD = struct.Struct("<IBBd")
EXT_FLAG = 1 << 31


def _pack(msg: can.Message) -> bytes:
    flags = msg.is_fd | (msg.bitrate_switch << 1) | (msg.error_state_indicator << 2) | (msg.is_error_frame << 3)
    cid = msg.arbitration_id | (EXT_FLAG if msg.is_extended_id else 0)
    data = bytes(msg.data)
    return RECORD.pack(cid, flags, len(data), msg.timestamp or 0.0) + data


class CanTcpGateway:
    """Bridge virtual CAN channel ``channel`` to TCP clients on 127.0.0.1:``port`` (0: ephemeral)."""

    def __init__(self, channel: str, port: int = 0) -> None:
        self.channel = channel
        self._srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._srv.bind(("127.0.0.1", port))  # loopback only
        self._srv.listen(4)
        self.host, self.port = self._srv.getsockname()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._clients: list[tuple[socket.socket, can.BusABC]] = []
        self._lock = threading.Lock()

    def start(self) -> CanTcpGateway:
        t = threading.Thread(target=self._accept_loop, name="can-gateway", daemon=True)
        t.start()
        self._threads.append(t)
        return self

    def stop(self) -> None:
        self._stop.set()
        for t in list(self._threads):
            t.join(timeout=5.0)
        with self._lock:
            for sock, bus in self._clients:
                sock.close()
                bus.shutdown()
            self._clients.clear()
        self._srv.close()

    def __enter__(self) -> CanTcpGateway:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._srv], [], [], 0.1)
            if not ready:
                continue
            sock, _ = self._srv.accept()
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            bus = can.Bus(interface="virtual", channel=self.channel, protocol=can.CanProtocol.CAN_FD)
            with self._lock:
                self._clients.append((sock, bus))
            for target, name in ((self._tcp_to_bus, "rx"), (self._bus_to_tcp, "tx")):
                t = threading.Thread(target=target, args=(sock, bus), name=f"can-gateway-{name}", daemon=True)
                t.start()
                self._threads.append(t)

    def _tcp_to_bus(self, sock: socket.socket, bus: can.BusABC) -> None:
        buf = bytearray()
        while not self._stop.is_set():
            ready, _, _ = select.select([sock], [], [], 0.1)
            if not ready:
                continue
            try:
                chunk = sock.recv(1 << 16)
            except OSError:
                return
            if not chunk:
                return
            buf += chunk
            while len(buf) >= RECORD.size:
                cid, flags, length, _ts = RECORD.unpack_from(buf)
                end = RECORD.size + length
                if length > 64:
                    return  # corrupt stream: drop the client
                if len(buf) < end:
                    break
                bus.send(can.Message(
                    arbitration_id=cid & 0x1FFFFFFF, is_extended_id=bool(cid & EXT_FLAG), is_fd=bool(flags & 1),
                    bitrate_switch=bool(flags & 2), error_state_indicator=bool(flags & 4),
                    is_error_frame=bool(flags & 8), data=bytes(buf[RECORD.size : end]), dlc=length,
                ))
                del buf[:end]

    def _bus_to_tcp(self, sock: socket.socket, bus: can.BusABC) -> None:
        while not self._stop.is_set():
            msg = bus.recv(0.1)
            if msg is None:
                continue
            out = [_pack(msg)]
            while len(out) < 256 and (msg := bus.recv(0.0)) is not None:
                out.append(_pack(msg))
            try:
                sock.sendall(b"".join(out))
            except OSError:
                return
