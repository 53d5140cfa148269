"""Device layer: the CAN FD DAQ front end (python-can transport, DBC protocol).

Configuration by request/response frames (``DAQ_REQUEST``/``DAQ_RESPONSE``), sample
streaming in ``DAQ_DATA`` frames with per-input sequence counters and sample-clock
timestamps (see :mod:`drivers.daq_protocol` and ``docs/drivers.md``).

The driver pulls frames from the bus inside its own calls (no background thread): a
request waits for its response while sample frames that arrive meanwhile are kept, and
:meth:`CanFdDaq.read` returns aligned scans of every configured channel. Every wait has a
deadline; a silent node, a bus-off error frame or a gap in the stream raises a clear error.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from urllib.parse import urlparse

import can
import cantools
import numpy as np
from can.interfaces.virtual import VirtualBus

from .daq_protocol import (
    CMD,
    COUPLING,
    MAX_INPUTS,
    QUANTITY,
    REQ_ID,
    RESULTS,
    RSP_ID,
    ChannelStream,
    bus_load,
    load_dbc,
)
from .daq_receive import CAN_ERR_BUSOFF, END_WAIT_S, MAX_FRAMES_PER_POLL, FrameReceiver  # noqa: F401
from .errors import (
    BusCapacityError,
    BusOff,
    ConnectionLost,
    DeviceError,
    InstrumentError,
    InstrumentTimeout,
    ProtocolError,
    RangeError,
    SensorOverload,
)
from .interrupts import interrupts_held

__all__ = ["CanFdDaq", "DaqChannel", "SampleBlock", "firmware_text", "open_can_bus"]

# CAN_ERR_BUSOFF, END_WAIT_S and MAX_FRAMES_PER_POLL (imported above, hence the noqa) were
# defined here before the receive path moved to drivers.daq_receive; they stay importable here.
log = logging.getLogger(__name__)
UNITS = {"acceleration": "m/s^2", "force": "N", "voltage": "V"}


@dataclass(frozen=True)
class DaqChannel:
    """One configured DAQ input.

    ``sensitivity_mv_per_unit`` is mV/(m/s^2) for acceleration, mV/N for force, and 1000
    (1 V/V) for a plain voltage. ``range_volt`` is the +- input range (0.1..10 V);
    ``coupling`` DC, AC or IEPE (AC with sensor excitation).
    """

    name: str
    input: int
    quantity: str = "acceleration"
    sensitivity_mv_per_unit: float = 10.0
    range_volt: float = 10.0
    coupling: str = "IEPE"

    @property
    def unit(self) -> str:
        return UNITS[self.quantity]


@dataclass
class SampleBlock:
    """Aligned scans of all configured channels, in engineering units.

    ``data[i, j]`` is channel ``i`` at sample ``first_index + j`` (NaN where frames were
    lost); ``overload`` names the channels whose frames in this block were flagged.
    """

    data: np.ndarray
    first_index: int
    sample_rate_hz: float
    names: tuple[str, ...]
    units: tuple[str, ...]
    overload: tuple[str, ...] = ()

    @property
    def time_s(self) -> np.ndarray:
        return (self.first_index + np.arange(self.data.shape[1])) / self.sample_rate_hz


def can_interfaces() -> tuple[str, ...]:
    """The CAN interfaces :func:`open_can_bus` takes: python-can's, and ``tcp``."""
    return tuple(sorted(set(can.VALID_INTERFACES) | {"tcp"}))


def open_can_bus(interface: str, channel: str, nominal_bitrate: int, data_bitrate: int, **kwargs) -> can.BusABC:
    """A CAN FD bus: ``virtual`` (in-process), ``tcp`` (``channel="host:port"``, the sim-lab
    gateway, see :mod:`drivers.can_tcp`), or any python-can interface (socketcan, ...)."""
    if interface == "virtual":
        return can.Bus(interface="virtual", channel=channel, protocol=can.CanProtocol.CAN_FD)
    if interface == "tcp":
        from .can_tcp import TcpCanBus

        u = urlparse(channel if "://" in channel else f"tcp://{channel}")
        return TcpCanBus(u.hostname or "127.0.0.1", int(u.port or 0))
    return can.Bus(interface=interface, channel=channel, fd=True, bitrate=nominal_bitrate,
                   data_bitrate=data_bitrate, **kwargs)


def firmware_text(fw_version) -> str:
    """IDENTIFY's firmware version as ``major.minor`` (high byte, low byte); anything but an
    integer as it is."""
    if isinstance(fw_version, int):
        return f"{fw_version >> 8}.{fw_version & 0xFF}"
    return str(fw_version)


class CanFdDaq(FrameReceiver):
    """Driver of the CAN FD DAQ front end.

    Parameters
    ----------
    bus : can.BusABC, optional
        An open bus; otherwise one is opened from ``interface``/``channel`` (and closed by
        :meth:`close`).
    nominal_bitrate, data_bitrate : int
        The bus's configured bit rates (arbitration and data phase), used for the capacity
        check.
    max_bus_load : float
        Largest fraction of bus time streaming may take (worst-case bit stuffing).
    timeout_s : float
        Response timeout of each request.
    stream_timeout_s : float
        A stream with no sample frame for this long is dead (node silent or bus-off). Time
        the caller spends between reads does not count: the frames queued meanwhile are
        read first.
    on_gap, on_overload : {"raise", "mark"}
        Lost frames: raise :class:`~drivers.errors.FramesLost` or return NaN samples.
        Overload: raise :class:`~drivers.errors.SensorOverload` (the block is attached as
        ``exc.block``) or only name the channels in ``SampleBlock.overload``.
    """

    def __init__(
        self,
        bus: can.BusABC | None = None,
        *,
        interface: str = "virtual",
        channel: str = "ssidlab-daq",
        nominal_bitrate: int = 1_000_000,
        data_bitrate: int = 5_000_000,
        max_bus_load: float = 0.8,
        timeout_s: float = 0.5,
        stream_timeout_s: float = 1.0,
        reorder_window: int = 8,
        on_gap: str = "raise",
        on_overload: str = "raise",
        name: str = "daq",
        **bus_kwargs,
    ) -> None:
        if on_gap not in ("raise", "mark") or on_overload not in ("raise", "mark"):
            raise ValueError("on_gap and on_overload must be 'raise' or 'mark'")
        self.name = name
        self.nominal_bitrate, self.data_bitrate = int(nominal_bitrate), int(data_bitrate)
        self.max_bus_load = float(max_bus_load)
        self.timeout_s, self.stream_timeout_s = float(timeout_s), float(stream_timeout_s)
        self.reorder_window = reorder_window
        self.on_gap, self.on_overload = on_gap, on_overload
        self.db = load_dbc()
        self._req = self.db.get_message_by_frame_id(REQ_ID)
        self._rsp = self.db.get_message_by_frame_id(RSP_ID)
        self._own_bus = bus is None
        if bus is None:
            try:
                bus = open_can_bus(interface, channel, self.nominal_bitrate, self.data_bitrate, **bus_kwargs)
            except (OSError, can.CanError) as exc:
                # A CAN adapter that is missing, down or renamed (can0 -> can1 after a
                # restart) is an instrument not reached, said with where it was looked for.
                raise ConnectionLost(f"{name}: cannot open the CAN bus {interface}:{channel}: {exc}") from exc
        self.bus = bus
        self._poll_s = 0.002 if isinstance(self.bus, VirtualBus) else 0.0
        self._token = 0
        self._responses: dict[int, dict | Exception] = {}
        self._waiting: int | None = None  # token of the request waiting for its response
        self._streams: dict[int, ChannelStream] = {}
        self._stale_frames = 0  # sample frames dropped for want of a stream (see start())
        self._errors: list[InstrumentError] = []
        self._last_data = time.monotonic()
        self.channels: tuple[DaqChannel, ...] = ()
        self.sample_rate_hz = 0.0
        self.running = False
        self.n_inputs = MAX_INPUTS
        self.identity: dict = {}
        try:
            self.identity = self.request("IDENTIFY")
            self.n_inputs = int(self.identity["n_inputs"])
        except BaseException:
            self._close_bus()
            raise

    # ------------------------------------------------------------------ requests
    # (frames in, sample streams and the wait for scans: drivers.daq_receive.FrameReceiver)
    def _on_response(self, data: bytes) -> None:
        """Keep the response the waiting request waits for, drop any other.

        A response to no waiting request (one that came after its request timed out, a
        duplicate) kept would answer a later request that reuses its 8-bit token. A
        malformed response to the waiting request is kept as the exception it raises: its
        request fails with the cause, not with a time-out blaming a silent DAQ.
        """
        # Byte 1 is the token; a frame too short to hold one can only be the waiting one's.
        token = data[1] if len(data) > 1 else self._waiting
        if self._waiting is None or token != self._waiting:
            log.debug("%s: response frame %s dropped: no request waits for it (token %s)", self.name, data.hex(), token)
            return
        try:
            self._responses[token] = self._rsp.decode(data)
        except Exception as exc:  # cantools raises several types for a malformed frame
            self._responses[token] = exc

    def request(self, cmd: str, channel: int = 0, timeout_s: float | None = None, **fields) -> dict:
        """Send one DAQ_REQUEST and wait for its response; raise on a non-ok result."""
        self._token = (self._token + 1) & 0xFF
        token = self._token
        sig = {"cmd": CMD[cmd], "token": token, "channel": channel, **fields}
        if CMD[cmd] >= 4:
            sig[f"pad_req{CMD[cmd]}"] = 0  # commands without fields: a reserved zero byte
        try:
            data = self._req.encode(sig, strict=True)
        except (cantools.database.errors.EncodeError, KeyError, ValueError) as exc:
            raise RangeError(f"{self.name}: {cmd}: {exc}") from None
        # The token's slot starts empty: nothing but this request's own response may answer it.
        self._responses.pop(token, None)
        self._waiting = token
        try:
            self._send_request(cmd, data)
            rsp = self._await_response(token, cmd, self.timeout_s if timeout_s is None else timeout_s)
        finally:
            self._waiting = None
        if int(rsp["cmd"]) != CMD[cmd]:
            raise ProtocolError(f"{self.name}: response to {cmd} echoes command {rsp['cmd']}")
        if int(rsp["result"]) != 0:
            raise DeviceError(f"{self.name}: {cmd} refused: {RESULTS.get(int(rsp['result']), rsp['result'])}")
        return rsp

    def _send_request(self, cmd: str, data: bytes) -> None:
        try:
            with interrupts_held:
                self.bus.send(can.Message(arbitration_id=REQ_ID, data=data, is_fd=True, bitrate_switch=True,
                                          is_extended_id=False), timeout=self.timeout_s)
        except can.CanError as exc:
            raise BusOff(f"{self.name}: cannot send {cmd}: {exc}") from exc

    def _await_response(self, token: int, cmd: str, timeout_s: float) -> dict:
        """The response with ``token``, pumping the bus (sample frames are kept) meanwhile."""
        deadline = time.monotonic() + timeout_s
        while token not in self._responses:
            for err in self._errors:
                if isinstance(err, BusOff):
                    self._errors.remove(err)
                    raise err
            left = deadline - time.monotonic()
            if left <= 0:
                raise InstrumentTimeout(f"{self.name}: no response to {cmd} within {self.timeout_s:g} s "
                                        "(DAQ silent or bus-off?)")
            self._pump(min(left, 0.05))
        rsp = self._responses.pop(token)
        if isinstance(rsp, Exception):
            raise ProtocolError(f"{self.name}: bad response frame to {cmd}: {rsp}") from rsp
        return rsp

    # ------------------------------------------------------------------ configuration
    def check_capacity(self, n_channels: int, sample_rate_hz: float) -> float:
        """Bus load of streaming ``n_channels`` at ``sample_rate_hz``; raises if too much."""
        fps, load = bus_load(n_channels, sample_rate_hz, self.nominal_bitrate, self.data_bitrate)
        if load > self.max_bus_load:
            raise BusCapacityError(
                f"{self.name}: {n_channels} channels x {sample_rate_hz:g} S/s needs {fps:.0f} frames/s, "
                f"{100 * load:.0f} % of the CAN FD bus at {self.nominal_bitrate / 1e3:g} kbit/s nominal / "
                f"{self.data_bitrate / 1e3:g} kbit/s data (limit {100 * self.max_bus_load:.0f} %); "
                f"use at most {int(self.max_bus_load / load * sample_rate_hz):d} S/s with {n_channels} channels, "
                "fewer channels, or a faster data bit rate"
            )
        return load

    def configure(self, channels: list[DaqChannel] | tuple[DaqChannel, ...], sample_rate_hz: float) -> None:
        """Set up the channels (others disabled) and the sample rate."""
        if self.running and self.status()["state"] == "acquiring":
            raise InstrumentError(f"{self.name}: stop the acquisition before configuring")
        self.running = False
        channels = tuple(channels)
        if not channels:
            raise RangeError(f"{self.name}: no channels")
        seen: set[int] = set()
        for c in channels:
            if not 0 <= c.input < self.n_inputs or c.input in seen:
                raise RangeError(f"{self.name}: channel {c.name!r}: input {c.input} invalid or used twice "
                                 f"(0..{self.n_inputs - 1})")
            seen.add(c.input)
            if c.quantity not in QUANTITY or c.coupling not in COUPLING:
                raise RangeError(f"{self.name}: channel {c.name!r}: quantity {c.quantity!r} / "
                                 f"coupling {c.coupling!r} unknown")
            if not 0.1 <= c.range_volt <= 10.0:
                raise RangeError(f"{self.name}: channel {c.name!r}: range {c.range_volt!r} V outside 0.1..10 V")
            if not (math.isfinite(c.sensitivity_mv_per_unit) and c.sensitivity_mv_per_unit > 0):
                raise RangeError(f"{self.name}: channel {c.name!r}: sensitivity must be > 0")
        if not (float(sample_rate_hz).is_integer() and 1 <= sample_rate_hz <= 102400):
            raise RangeError(f"{self.name}: sample rate must be a whole number of S/s in 1..102400")
        self.check_capacity(len(channels), sample_rate_hz)
        by_input = {c.input: c for c in channels}
        for k in range(self.n_inputs):
            c = by_input.get(k)
            self.request(
                "SET_CHANNEL", channel=k, enable=int(c is not None),
                coupling=COUPLING[c.coupling] if c else 0, range_mv=int(round((c.range_volt if c else 10.0) * 1000)),
                sensitivity_mv=float(c.sensitivity_mv_per_unit) if c else 1000.0,
                quantity=QUANTITY[c.quantity] if c else 0,
            )
        self.request("SET_RATE", sample_rate_hz=int(sample_rate_hz))
        self.channels, self.sample_rate_hz = channels, float(sample_rate_hz)

    # ------------------------------------------------------------------ acquisition
    def start(self, n_scans: int = 0) -> None:
        """Start a new acquisition of ``n_scans`` scans (0: until :meth:`stop`).

        The new acquisition takes no frame of an earlier one. An acquisition not stopped
        (a continuous one still running, a finite one not read to its end) is stopped
        first, and its scans not read yet are discarded: calling ``start`` says "acquire
        anew from here", as a finite ``start(n)``/``read(n)`` loop does without a
        :meth:`stop` between, and refusing would only make the user add the STOP the
        driver can send itself (the node itself refuses START while acquiring, with a
        "busy" that does not say what to do).

        Sample frames carry no acquisition number: every acquisition's streams start at
        seq 0, tick 0, so a frame of the earlier one still queued would pass for the new
        one's (and the new one's own frame be dropped as its duplicate). The node answers
        START only once the earlier acquisition is over, so the response is the boundary:
        every sample frame received before it is dropped, and the streams are made only
        once it is in.
        """
        if not self.channels:
            raise InstrumentError(f"{self.name}: configure channels first")
        total = int(n_scans) or None
        # A finite acquisition whose every last frame is in has ended at the node: no STOP
        # (a round trip per acquisition of a stepped-sine run) is needed.
        unfinished = self.running and not (self._streams and all(s.finished for s in self._streams.values()))
        # Cleared in place: a poll in progress holds this dict, and must drop the earlier
        # acquisition's frames from now on.
        self._streams.clear()
        self._errors.clear()
        self._stale_frames = 0
        self.running = False
        if unfinished:
            log.info("%s: the acquisition not stopped is stopped before a new one starts", self.name)
            self.request("STOP")
        self.request("START", n_scans=int(n_scans))
        if self._stale_frames:
            log.debug("%s: %d sample frame(s) of an earlier acquisition dropped at START", self.name,
                      self._stale_frames)
        self._streams.update({c.input: ChannelStream(c.name, self.reorder_window, total) for c in self.channels})
        self.running = True
        self._last_data = time.monotonic()

    def stop(self) -> None:
        self.running = False
        self.request("STOP")

    def status(self) -> dict:
        r = self.request("STATUS")
        return {"state": ("idle", "acquiring", "finished")[int(r["state"])], "n_enabled": int(r["n_enabled"]),
                "overload_mask": int(r["overload_mask"]), "sample_rate_hz": int(r["status_rate_hz"])}

    @property
    def stats(self) -> dict:
        """Frame counters per channel: frames, duplicates, reordered, lost."""
        return {s.name: {"frames": s.frames, "duplicates": s.duplicates, "reordered": s.reordered,
                         "lost": s.lost_frames}
                for s in self._streams.values()}

    def read(self, n_scans: int, timeout_s: float | None = None) -> SampleBlock:
        """The next ``n_scans`` aligned scans of every channel.

        Raises
        ------
        BusOff
            Error frame from the controller, or no sample frame for ``stream_timeout_s``.
        FramesLost
            With ``on_gap="raise"``, when frames were lost.
        StreamError
            The acquisition ended before ``n_scans`` more scans.
        InstrumentTimeout
            ``timeout_s`` passed while frames were still arriving (too slow).
        SensorOverload
            With ``on_overload="raise"``, when a channel was flagged over range.
        """
        if not self._streams:
            raise InstrumentError(f"{self.name}: not acquiring")
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        streams = [self._streams[c.input] for c in self.channels]
        self._await_scans(streams, n_scans, deadline, timeout_s)
        self._raise_errors()
        first = streams[0].base
        data = np.empty((len(streams), n_scans))
        for i, (c, s) in enumerate(zip(self.channels, streams)):
            codes, lost = s.take(n_scans)
            scale = c.range_volt / 2**23 * 1000.0 / c.sensitivity_mv_per_unit
            data[i] = codes * scale
            if lost is not None:
                data[i, lost] = np.nan
        over = tuple(s.name for s in streams if s.overload)
        for s in streams:
            s.overload = False
        block = SampleBlock(data, first, self.sample_rate_hz, tuple(c.name for c in self.channels),
                            tuple(c.unit for c in self.channels), over)
        if over and self.on_overload == "raise":
            exc = SensorOverload(f"{self.name}: over range on {', '.join(over)} (samples clipped)", over)
            exc.block = block
            raise exc
        return block

    # ------------------------------------------------------------------ safety
    def safe_state(self) -> None:
        """Acquisition stopped (retried across a short bus-off); never hangs."""
        self.running = False
        last: Exception | None = None
        for _ in range(3):
            try:
                self.request("STOP")
                self._streams = {}
                return
            except InstrumentError as exc:
                last = exc
        self._streams = {}
        raise InstrumentError(f"{self.name}: could not confirm acquisition stopped: {last}")

    def _close_bus(self) -> None:
        if self._own_bus and self.bus is not None:
            self.bus.shutdown()
        self.bus = None

    def close(self) -> None:
        try:
            if self.bus is not None:
                self.safe_state()
        finally:
            self._close_bus()

    def release(self) -> None:
        """Close the bus without another stop request (as ``SignalGenerator.release``)."""
        self.running = False
        self._streams = {}
        self._close_bus()

    def __enter__(self) -> CanFdDaq:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
