"""Protocol layer of the CAN FD DAQ: frame layouts (from the DBC), bus load, stream checks.

Request and response frames are encoded and decoded with cantools from
``drivers/ssidlab_daq.dbc``. Sample frames use the DBC's ``DAQ_DATA`` layout too, but are
decoded here with numpy in bulk: cantools decodes one frame at a time through a dict of
23 signals, far too slow for tens of thousands of frames per second (the tests check that
both decoders agree bit for bit).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import cantools
import numpy as np

from .errors import FramesLost, ProtocolError

__all__ = [
    "DATA_ID0",
    "DBC_PATH",
    "MAX_INPUTS",
    "REQ_ID",
    "RSP_ID",
    "SAMPLES_PER_FRAME",
    "ChannelStream",
    "bus_load",
    "decode_codes",
    "fd_frame_bits",
    "load_dbc",
]

DBC_PATH = Path(__file__).with_name("ssidlab_daq.dbc")
REQ_ID, RSP_ID, DATA_ID0 = 0x100, 0x101, 0x200
SAMPLES_PER_FRAME = 19
MAX_INPUTS = 32
CMD = {"SET_CHANNEL": 1, "SET_RATE": 2, "START": 3, "STOP": 4, "STATUS": 5, "RESET": 6, "IDENTIFY": 7}
RESULTS = {0: "ok", 1: "bad channel", 2: "bad value", 3: "busy (acquiring)", 4: "unknown command", 5: "no channel enabled"}
COUPLING = {"DC": 0, "AC": 1, "IEPE": 2}
QUANTITY = {"voltage": 0, "acceleration": 1, "force": 2}
_HDR = struct.Struct("<HIB")


def load_dbc(path: Path | str = DBC_PATH) -> cantools.database.can.Database:
    """The DAQ's frame database."""
    return cantools.database.load_file(str(path))


def fd_frame_bits(n_data_bytes: int = 64) -> tuple[int, int]:
    """Worst-case bits of one CAN FD frame with 11-bit ID and bit-rate switch.

    Returns
    -------
    (nominal_bits, data_bits)
        Bits sent at the nominal (arbitration) rate and at the data rate, with worst-case
        dynamic bit stuffing (one stuff bit per four bits) and the fixed stuff bits of the
        FD CRC field.

    Notes
    -----
    Nominal phase: SOF, 11-bit ID, RRS, IDE, FDF, res, BRS (17 bits, up to 4 stuff bits),
    then CRC delimiter, ACK slot and delimiter, EOF (7) and intermission (3): 13 bits.
    Data phase: ESI, DLC (4), the payload, then stuff count (4) and CRC (17 up to 16 bytes,
    21 above) with a fixed stuff bit every 4 bits.
    """
    nominal = 17 + (17 - 1) // 4 + 13
    body = 1 + 4 + 8 * n_data_bytes
    crc = 4 + (17 if n_data_bytes <= 16 else 21)
    data = body + (body - 1) // 4 + crc + -(-crc // 4)
    return nominal, data


def bus_load(n_channels: int, sample_rate_hz: float, nominal_bitrate: float, data_bitrate: float) -> tuple[float, float]:
    """(frames per second, fraction of bus time) that streaming needs, worst-case stuffing."""
    frames_per_s = n_channels * sample_rate_hz / SAMPLES_PER_FRAME
    nb, db = fd_frame_bits(64)
    return frames_per_s, frames_per_s * (nb / nominal_bitrate + db / data_bitrate)


def decode_codes(payload: bytes | bytearray) -> np.ndarray:
    """Signed 24-bit little-endian samples -> int32 array."""
    b = np.frombuffer(payload, dtype=np.uint8).reshape(-1, 3).astype(np.int32)
    v = b[:, 0] | (b[:, 1] << 8) | (b[:, 2] << 16)
    return np.where(v >= 1 << 23, v - (1 << 24), v)


@dataclass
class ChannelStream:
    """Reassembles one input's sample frames: detects lost, duplicated and reordered frames.

    Frames carry a per-input sequence counter (u16) and the sample-clock tick of their
    first sample. In-order frames are appended; a frame ahead of the expected one waits in
    a small reorder buffer, and is put in its place when the missing frame arrives
    (counted as reordered). When that buffer holds more than ``reorder_window`` frames the
    missing ones are declared lost: their samples are kept as a gap (NaN after decoding) so
    that every input stays aligned on the sample clock. A frame behind the expected one,
    or one already waiting, is a duplicate and is dropped.

    At the end of a finite acquisition no later frame overflows the buffer: the caller
    says when every frame has been sent (:meth:`end`), and what is still missing up to
    ``total`` samples (the scans asked for at START) is declared lost the same way.

    A stream is made at START, which restarts every input's ``seq`` and the sample clock
    at 0: the first frame expected is seq 0 at tick 0, not whichever frame arrives first.
    Frames lost before the first one received are then a gap like any other (a frame 1
    that arrives before frame 0 waits in the reorder buffer), and the input is not shifted
    against the others by the samples it missed.
    """

    name: str
    reorder_window: int = 8
    total: int | None = None  # samples of the acquisition (None: until STOP)
    next_seq: int = 0  # START restarts seq and the sample clock: frame 0 is expected at tick 0
    next_tick: int = 0
    payload: bytearray = field(default_factory=bytearray)
    base: int = 0  # sample index (since START) of payload[0]
    gaps: list = field(default_factory=list)  # [start, stop) sample indices of lost samples
    pending: dict = field(default_factory=dict)
    overload: bool = False
    finished: bool = False
    duplicates: int = 0
    reordered: int = 0
    lost_frames: int = 0
    frames: int = 0

    def push(self, data: bytes | bytearray) -> FramesLost | None:
        """Take one frame; returns a FramesLost when a gap was declared."""
        if len(data) != 64:
            raise ProtocolError(f"{self.name}: sample frame of {len(data)} bytes (want 64)")
        seq, tick, flags = _HDR.unpack_from(data)
        self.frames += 1
        d = (seq - self.next_seq) & 0xFFFF
        if d >= 0x8000 or seq in self.pending:
            self.duplicates += 1
            return None
        if d:
            self.pending[seq] = data
            if len(self.pending) <= self.reorder_window:
                return None
            return self._declare_gap()
        self._accept(seq, tick, flags, data)
        if self.pending:
            self.reordered += self._drain()
        return None

    @property
    def saw_end(self) -> bool:
        """The frame flagged last has arrived (accepted, or waiting behind a gap)."""
        return self.finished or any(_HDR.unpack_from(d)[2] & 2 for d in self.pending.values())

    def end(self) -> list[FramesLost]:
        """Every frame of the acquisition has been sent: declare the missing ones lost.

        Returns
        -------
        list of FramesLost
            One per gap: before each frame still waiting in the reorder buffer, and the
            tail up to ``total`` samples when the last frame itself was lost.
        """
        lost = []
        while self.pending:
            lost.append(self._declare_gap())
        if not self.finished and self.total is not None and self.total > self.next_tick:
            n_samples = self.total - self.next_tick
            lost.append(self._mark_lost(-(-n_samples // SAMPLES_PER_FRAME), n_samples))
        self.finished = True
        return lost

    def _declare_gap(self) -> FramesLost:
        first = min(self.pending, key=lambda s: (s - self.next_seq) & 0xFFFF)
        tick = _HDR.unpack_from(self.pending[first])[1]
        err = self._mark_lost((first - self.next_seq) & 0xFFFF, (tick - self.next_tick) & 0xFFFFFFFF)
        self._drain()
        return err

    def _mark_lost(self, n_lost: int, n_samples: int) -> FramesLost:
        """Keep ``n_samples`` lost samples (``n_lost`` frames) as a gap and step past them."""
        start = self.base + len(self.payload) // 3
        err = FramesLost(
            f"{self.name}: {n_lost} frame(s) lost (seq {self.next_seq}..{(self.next_seq + n_lost - 1) & 0xFFFF}, "
            f"{n_samples} samples from sample {start})"
        )
        self.gaps.append((start, start + n_samples))
        self.payload += bytes(3 * n_samples)
        self.lost_frames += n_lost
        self.next_seq = (self.next_seq + n_lost) & 0xFFFF
        self.next_tick = (self.next_tick + n_samples) & 0xFFFFFFFF
        return err

    def _accept(self, seq: int, tick: int, flags: int, data: bytes) -> None:
        if tick != self.next_tick:
            raise ProtocolError(f"{self.name}: frame {seq} starts at tick {tick}, expected {self.next_tick}")
        n = flags >> 3
        if not 1 <= n <= SAMPLES_PER_FRAME:
            raise ProtocolError(f"{self.name}: frame {seq} claims {n} samples")
        self.payload += data[7 : 7 + 3 * n]
        self.overload |= bool(flags & 1)
        self.finished |= bool(flags & 2)
        self.next_seq = (seq + 1) & 0xFFFF
        self.next_tick = (tick + n) & 0xFFFFFFFF

    def _drain(self) -> int:
        n = 0
        while self.next_seq in self.pending:
            data = self.pending.pop(self.next_seq)
            seq, tick, flags = _HDR.unpack_from(data)
            self._accept(seq, tick, flags, data)
            n += 1
        return n

    @property
    def available(self) -> int:
        return len(self.payload) // 3

    def take(self, n: int) -> tuple[np.ndarray, np.ndarray | None]:
        """The next ``n`` samples as int32 codes, and a mask of lost ones (None: no gap)."""
        codes = decode_codes(bytes(self.payload[: 3 * n]))
        del self.payload[: 3 * n]
        lo, hi = self.base, self.base + n
        mask = None
        for g0, g1 in self.gaps:
            if g0 < hi and g1 > lo:
                mask = np.zeros(n, bool) if mask is None else mask
                mask[max(g0, lo) - lo : min(g1, hi) - lo] = True
        self.gaps = [(g0, g1) for g0, g1 in self.gaps if g1 > hi]
        self.base = hi
        return codes, mask
