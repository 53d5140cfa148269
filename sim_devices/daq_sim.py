"""Simulated CAN FD DAQ front end: a node on a python-can bus, the clock master of the world.

Protocol (``docs/drivers.md``; the DBC ``drivers/ssidlab_daq.dbc`` describes the same
frames - this module packs them with ``struct``/numpy as a device firmware would, and the
tests decode its frames with cantools to check that both agree):

* ``0x100`` DAQ_REQUEST (host -> DAQ, 16 bytes): ``cmd``, ``token``, ``channel`` and
  per-command fields (SET_CHANNEL, SET_RATE, START, STOP, STATUS, RESET, IDENTIFY).
* ``0x101`` DAQ_RESPONSE (DAQ -> host, 16 bytes): echoes ``cmd`` and ``token``, ``result``.
* ``0x200 + k`` DAQ_DATA of input ``k`` (64 bytes): ``seq`` (u16, per input), ``timestamp``
  (u32 sample-clock tick of the first sample), flags (overload, last frame, sample count),
  then 19 signed 24-bit samples.

While acquiring, the node advances the world block by block in sample time and sends the
frames; ``speed=None`` runs as fast as the host thread can (no sleeping), ``speed=1.0``
paces it to real time. Faults for tests (:meth:`SimDaq.inject`): ``drop``, ``duplicate``,
``swap`` (reorder) of a given data frame, ``bus_off`` (error frame, then silence for a
while; the frames of that time are lost), ``silent`` (no answers, no data), ``overload``
(a spike beyond range on one input), ``rail`` (an input stuck beyond its range).
"""

from __future__ import annotations

import copy
import logging
import struct
import threading
import time

import can
import numpy as np
from can.interfaces.virtual import VirtualBus
from scipy.signal import lfilter

from .world import World

__all__ = ["AC_CORNER_HZ", "DATA_ID0", "REQ_ID", "RSP_ID", "SAMPLES_PER_FRAME", "SimDaq", "ac_highpass"]

REQ_ID, RSP_ID, DATA_ID0 = 0x100, 0x101, 0x200
SAMPLES_PER_FRAME = 19
MAX_INPUTS = 32
CMD_SET_CHANNEL, CMD_SET_RATE, CMD_START, CMD_STOP, CMD_STATUS, CMD_RESET, CMD_IDENTIFY = range(1, 8)
R_OK, R_BAD_CHANNEL, R_BAD_VALUE, R_BUSY, R_UNKNOWN, R_NOTHING = 0, 1, 2, 3, 4, 5
STATE_IDLE, STATE_RUNNING, STATE_DONE = 0, 1, 2
FW_VERSION = 0x0100
#: The simulated front end's AC/IEPE coupling corner (-3 dB), Hz, unless a lab sets another.
AC_CORNER_HZ = 0.5
CAN_ERR_BUSOFF = 0x40  # SocketCAN error class of a bus-off error frame
_DATA_DTYPE = np.dtype([("seq", "<u2"), ("ts", "<u4"), ("flags", "u1"), ("s", "u1", (57,))])


def ac_highpass(v: np.ndarray, fs_hz: float, corner_hz: float, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An AC/IEPE input's coupling: the first-order high-pass ``iw / (iw + w_c)`` by the
    bilinear transform, prewarped to its -3 dB corner ``corner_hz``; ``state`` (1,) is the
    filter's (zeros: at rest). Returns the filtered samples and the state after them.

    It departs from the analog filter by about ``(f_c / f) (1 - x / tan x)``, ``x = pi f / f_s``
    (2e-4 at 0.45 f_s for 0.5 Hz at 4096 S/s), which :mod:`daq.coupling`'s correction leaves.
    """
    wc = np.tan(np.pi * corner_hz / fs_hz)
    b = np.array([1.0, -1.0]) / (1 + wc)
    a = np.array([1.0, (wc - 1) / (1 + wc)])
    return lfilter(b, a, v, zi=state)


class _SenderBus(VirtualBus):
    """python-can's virtual bus, sending without the per-recipient deep copy.

    The stock ``VirtualBus.send`` deep-copies every frame for every listener, which was
    the largest single cost of the simulated chain. The simulator builds a fresh Message
    for every frame and never touches it after sending, so the first listener can get
    the object itself (later listeners still get copies). Receiving is unchanged: the
    driver uses a stock virtual bus on the same channel.
    """

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        msg.timestamp = time.time()
        msg.channel = self.channel_id
        msg.is_rx = True
        first = True
        for q in self.channel:
            if q is self.queue:
                continue
            q.put(msg if first else copy.deepcopy(msg), block=True, timeout=timeout)
            first = False


class _Input:
    def __init__(self) -> None:
        self.enabled = False
        self.coupling = 2  # IEPE
        self.range_volt = 10.0
        self.sensitivity_mv = 10.0
        self.quantity = 1
        self.hp_state = np.zeros(1)


class SimDaq:
    """A simulated DAQ node wired to the sensors of ``world`` (input ``k`` = sensor ``k``).

    Parameters
    ----------
    world : World
    channel : str
        python-can virtual channel name (the bus the driver joins).
    speed : float or None
        None: as fast as possible; otherwise the ratio of simulated to wall time.
    block_scans : int
        Scans per world step (a multiple of 19 keeps frames full).
    serial : int
        Serial number reported by IDENTIFY.
    ac_corner_hz : float
        -3 dB corner of the AC/IEPE coupling's first-order high-pass (the front end's spec;
        a setup's ``[daq] ac_corner_hz`` says what its analysis divides out).
    """

    def __init__(
        self,
        world: World,
        channel: str = "ssidlab-daq",
        *,
        speed: float | None = None,
        block_scans: int = 19 * 14,
        serial: int = 1,
        seed: int = 0,
        ac_corner_hz: float = AC_CORNER_HZ,
    ) -> None:
        if len(world.sensors) > MAX_INPUTS:
            raise ValueError(f"the DAQ has {MAX_INPUTS} inputs; the world has {len(world.sensors)} sensors")
        self.world = world
        self.channel = channel
        self.speed = speed
        self.block_scans = int(block_scans)
        self.serial = serial
        self.ac_corner_hz = float(ac_corner_hz)
        self.inputs = [_Input() for _ in world.sensors]
        self.sample_rate_hz = 5120
        self.state = STATE_IDLE
        self.overload_mask = 0
        self._rng = np.random.default_rng(seed)
        self._bus: can.BusABC | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._frame_faults: dict[tuple[int, int], str] = {}
        self._bus_off_until = 0.0
        self._silent = False
        self._spike: set[int] = set()
        self._rail: set[int] = set()
        self.frames_sent = 0
        self._swap_held: dict[int, can.Message] = {}

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> SimDaq:
        self._bus = _SenderBus(channel=self.channel, protocol=can.CanProtocol.CAN_FD)
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="sim-daq", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._thread = None
        self._bus.shutdown()
        self._bus = None

    def __enter__(self) -> SimDaq:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def inject(self, kind: str, *, channel: int = 0, seq: int = 0, duration_s: float = 0.3, on: bool = True) -> None:
        """Switch on a fault: ``drop``/``duplicate``/``swap`` data frame ``seq`` of input
        ``channel``; ``bus_off`` for ``duration_s``; ``silent`` (``on``); ``overload`` (one
        sample of ``channel`` beyond its range); ``rail`` (``channel`` stuck beyond its range
        while ``on``: a broken sensor or cable)."""
        with self._lock:
            if kind in ("drop", "duplicate", "swap"):
                self._frame_faults[(channel, seq)] = kind
            elif kind == "bus_off":
                # The controller's error frame goes out first, then the node is off the bus.
                self._send(can.Message(arbitration_id=CAN_ERR_BUSOFF, is_error_frame=True, dlc=8, data=bytes(8)))
                self._bus_off_until = time.monotonic() + duration_s
            elif kind == "silent":
                self._silent = on
            elif kind == "overload":
                self._spike.add(channel)
            elif kind == "rail":
                (self._rail.add if on else self._rail.discard)(channel)
            else:
                raise ValueError(f"unknown DAQ fault {kind!r}")

    # ------------------------------------------------------------------ main loop
    def _send(self, msg: can.Message) -> None:
        if self._bus is not None and not self._silent and time.monotonic() >= self._bus_off_until:
            self._bus.send(msg)

    def _run(self) -> None:
        try:
            self._loop()
        except Exception:  # a simulator bug must be visible, not a silently dead node
            logging.getLogger(__name__).exception("simulated DAQ stopped")
            self.state = STATE_IDLE

    def _loop(self) -> None:
        while not self._stop.is_set():
            if self.state == STATE_RUNNING:
                while (msg := self._bus.recv(0.0)) is not None:
                    self._on_frame(msg)
                if self.state == STATE_RUNNING:
                    self._stream_block()
            else:
                msg = self._bus.recv(0.05)
                if msg is not None:
                    self._on_frame(msg)

    def _on_frame(self, msg: can.Message) -> None:
        if msg.arbitration_id != REQ_ID or msg.is_error_frame or len(msg.data) < 3:
            return
        if self._silent or time.monotonic() < self._bus_off_until:
            return  # a bus-off node hears nothing either
        data = bytes(msg.data).ljust(16, b"\0")
        cmd, token, ch = data[0], data[1], data[2]
        result, extra = self._execute(cmd, ch, data)
        payload = bytes([cmd, token, result]) + extra
        self._send(can.Message(arbitration_id=RSP_ID, data=payload.ljust(16, b"\0"), is_fd=True,
                               bitrate_switch=True, is_extended_id=False))

    def _execute(self, cmd: int, ch: int, d: bytes) -> tuple[int, bytes]:
        with self._lock:
            busy = self.state == STATE_RUNNING
            if cmd == CMD_SET_CHANNEL:
                if busy:
                    return R_BUSY, b""
                if ch >= len(self.inputs):
                    return R_BAD_CHANNEL, b""
                enable, coupling = d[3], d[4]
                range_mv, = struct.unpack_from("<H", d, 5)
                sens, = struct.unpack_from("<f", d, 7)
                quantity = d[11]
                if (enable > 1 or coupling > 2 or not 100 <= range_mv <= 10000
                        or not (np.isfinite(sens) and sens > 0) or quantity > 3):
                    return R_BAD_VALUE, b""
                inp = self.inputs[ch]
                if (bool(enable), coupling) != (inp.enabled, inp.coupling):
                    # Another analog path (coupling capacitor switched in or out, IEPE current
                    # on or off): its high-pass starts from rest. A range or sensitivity
                    # change leaves the capacitor's charge alone.
                    inp.hp_state = np.zeros(1)
                inp.enabled, inp.coupling, inp.range_volt = bool(enable), coupling, range_mv / 1000.0
                inp.sensitivity_mv, inp.quantity = float(sens), quantity
                return R_OK, b""
            if cmd == CMD_SET_RATE:
                if busy:
                    return R_BUSY, b""
                rate, = struct.unpack_from("<I", d, 3)
                if not 1 <= rate <= 102400:
                    return R_BAD_VALUE, b""
                self.sample_rate_hz = rate
                return R_OK, b""
            if cmd == CMD_START:
                if busy:
                    return R_BUSY, b""
                if not any(i.enabled for i in self.inputs):
                    return R_NOTHING, b""
                n_scans, = struct.unpack_from("<I", d, 3)
                self._begin(n_scans)
                return R_OK, b""
            if cmd == CMD_STOP:
                self.state = STATE_IDLE if self.state == STATE_RUNNING else self.state
                return R_OK, b""
            if cmd == CMD_STATUS:
                n_en = sum(i.enabled for i in self.inputs)
                return R_OK, struct.pack("<BBII", self.state, n_en, self.overload_mask, self.sample_rate_hz)
            if cmd == CMD_RESET:
                self.state, self.overload_mask = STATE_IDLE, 0
                return R_OK, b""
            if cmd == CMD_IDENTIFY:
                return R_OK, struct.pack("<BHI", len(self.inputs), FW_VERSION, self.serial)
            return R_UNKNOWN, b""

    def _begin(self, n_scans: int) -> None:
        self.world.set_sample_rate(float(self.sample_rate_hz))
        self._active = [k for k, i in enumerate(self.inputs) if i.enabled]
        self._seq = {k: 0 for k in self._active}
        self._tick = 0  # sample-clock ticks since START
        self._left = n_scans if n_scans else None
        self._pending: dict[int, np.ndarray] = {k: np.zeros(0, np.int32) for k in self._active}
        self._pending_over: dict[int, bool] = {k: False for k in self._active}
        self._next_ts: dict[int, int] = {k: 0 for k in self._active}  # tick of _pending[k][0]
        self._t0_wall = time.monotonic()
        self.overload_mask = 0
        # The AC/IEPE high-pass state is not reset: a coupling capacitor keeps its charge
        # from one acquisition to the next, and the world only advances while acquiring, so
        # successive acquisitions are one continuous record. Reset at every START, the filter
        # stepped at the start of each of a run's chunks (periodic random on all-IEPE
        # channels: errors up to 2.9e-3 against 4.6e-4 with DC).
        self.state = STATE_RUNNING

    def _stream_block(self) -> None:
        n = self.block_scans if self._left is None else min(self.block_scans, self._left)
        if self.speed:
            # Real-time pacing (only when asked): wait until the wall clock catches up.
            due = self._t0_wall + self._tick / self.sample_rate_hz / self.speed
            delay = due - time.monotonic()
            if delay > 0 and self._stop.wait(delay):
                return
        blk = self.world.advance(n)
        codes = {}
        for k in self._active:  # input k is wired to sensor k
            codes[k], over = self._digitise(k, blk.volts[k], blk.overload[k])
            if over:
                self.overload_mask |= 1 << k
                self._pending_over[k] = True
        if self._left is not None:
            self._left -= n
        last = self._left == 0
        self._emit(codes, last)
        self._tick += n
        if last:
            self.state = STATE_DONE

    def _digitise(self, k: int, volts: np.ndarray, sensor_over: bool) -> tuple[np.ndarray, bool]:
        """Coupling, range and 24-bit quantisation of one input."""
        inp = self.inputs[k]
        v = volts
        if inp.coupling in (1, 2):
            # AC/IEPE coupling, state carried across blocks and acquisitions (reset only when
            # SET_CHANNEL changes the input's analog path).
            v, inp.hp_state = ac_highpass(v, self.sample_rate_hz, self.ac_corner_hz, inp.hp_state)
        if k in self._spike:
            self._spike.discard(k)
            v = v.copy()
            v[len(v) // 2] = 2 * inp.range_volt
        if k in self._rail:
            v = np.full_like(v, 1.5 * inp.range_volt)
        over = sensor_over or bool(np.any(np.abs(v) > inp.range_volt))
        fs = 2**23 - 1
        codes = np.clip(np.rint(v / inp.range_volt * 2**23), -fs - 1, fs).astype(np.int32)
        return codes, over

    def _emit(self, codes: dict[int, np.ndarray], last: bool) -> None:
        """Pack full frames of every input (all of them at the end) and send them."""
        spf = SAMPLES_PER_FRAME
        per_input = []
        for k in self._active:
            buf = np.concatenate([self._pending[k], codes[k]])
            n_full = buf.size // spf if not last else -(-buf.size // spf)
            take = min(buf.size, n_full * spf)
            self._pending[k] = buf[take:]
            if n_full == 0:
                per_input.append((k, None, 0))
                continue
            used = buf[:take]
            counts = np.full(n_full, spf)
            if last and take % spf:
                counts[-1] = take % spf
            frames = np.zeros(n_full, _DATA_DTYPE)
            padded = np.zeros(n_full * spf, np.int32)
            padded[:take] = used
            u = padded.astype(np.uint32) & 0xFFFFFF
            b = np.stack([u & 0xFF, (u >> 8) & 0xFF, (u >> 16) & 0xFF], axis=-1).astype(np.uint8)
            frames["s"] = b.reshape(n_full, spf * 3)
            seq0 = self._seq[k]
            frames["seq"] = (seq0 + np.arange(n_full)) & 0xFFFF
            frames["ts"] = (self._next_ts[k] + spf * np.arange(n_full)) & 0xFFFFFFFF
            self._next_ts[k] += take
            flags = (counts << 3).astype(np.uint8)
            if self._pending_over[k]:
                flags |= 1
                self._pending_over[k] = False
            if last:
                flags[-1] |= 2
            frames["flags"] = flags
            self._seq[k] = (seq0 + n_full) & 0xFFFF
            per_input.append((k, frames.tobytes(), n_full))
        # Interleave inputs frame by frame, as a DAQ that samples all inputs together would.
        n_max = max((nf for _, _, nf in per_input), default=0)
        if not self._frame_faults and not self._swap_held:
            # Fast path (no frame fault armed): the hot loop of the whole simulated chain.
            if self._silent or time.monotonic() < self._bus_off_until:
                return  # off the bus: these frames are lost
            send, msg_cls, sent = self._bus.send, can.Message, 0
            for f in range(n_max):
                lo, hi = 64 * f, 64 * (f + 1)
                for k, raw, nf in per_input:
                    if f < nf:
                        send(msg_cls(arbitration_id=DATA_ID0 + k, data=raw[lo:hi], is_fd=True,
                                     bitrate_switch=True, is_extended_id=False))
                        sent += 1
            self.frames_sent += sent
            return
        for f in range(n_max):
            for k, raw, nf in per_input:
                if f >= nf:
                    continue
                data = raw[64 * f : 64 * (f + 1)]
                seq = (self._seq[k] - nf + f) & 0xFFFF
                self._send_data(k, seq, data)
        if self._swap_held:
            for k, msg in self._swap_held.items():
                self._send(msg)
            self._swap_held.clear()

    def _send_data(self, k: int, seq: int, data: bytes) -> None:
        msg = can.Message(arbitration_id=DATA_ID0 + k, data=data, is_fd=True, bitrate_switch=True, is_extended_id=False)
        fault = self._frame_faults.pop((k, seq), None) if self._frame_faults else None
        held = self._swap_held.pop(k, None) if self._swap_held else None
        if fault == "drop":
            msg = None
        elif fault == "swap":
            self._swap_held[k] = msg  # sent after the next frame of input k
            msg = None
        if msg is not None:
            self._send(msg)
            self.frames_sent += 1
            if fault == "duplicate":
                self._send(msg)
        if held is not None:
            self._send(held)
