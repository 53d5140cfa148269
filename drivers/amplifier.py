"""Device layer: a shaker power amplifier on Modbus TCP (pymodbus async client).

Transport and protocol are pymodbus's (TCP, Modbus application protocol); this module is
the device: the register map (``docs/drivers.md``), the rules "enable only with the
interlock closed and no fault", a status monitor that polls periodically and treats a
stalled heartbeat as a fault, and a safe state (output disabled) on every exit.

:class:`ShakerAmplifier` is the asyncio driver; :class:`drivers.amplifier_sync.SyncShakerAmplifier`
runs it on a private event loop in a thread for callers that are not async.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass

from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ModbusException, ModbusIOException

from .errors import (
    AmplifierFault,
    ConnectionLost,
    DeviceError,
    HeartbeatLost,
    InstrumentError,
    InstrumentTimeout,
    InterlockOpen,
    ProtocolError,
    RangeError,
)

__all__ = ["FAULT_NAMES", "MODEL_ID", "REG", "AmpStatus", "ShakerAmplifier", "modbus_log_held_back"]

log = logging.getLogger(__name__)


def _modbus_log_to_the_application() -> None:
    """Give pymodbus's logger a NullHandler, as the logging HOWTO asks of a library.

    pymodbus adds no handler of its own, so with none configured Python's last-resort
    handler wrote its errors to the user's stderr, each with a dump of the last 20 frames
    (after a reply that came late, or a call interrupted). The driver raises its own
    error for the same failure, with pymodbus's exception as the cause. Nothing is
    disabled: the level and propagation stay, so an application that configures logging
    (``logging.basicConfig``) still sees pymodbus's lines; the driver's own logger is not
    touched.
    """
    modbus = logging.getLogger("pymodbus")
    if not any(isinstance(h, logging.NullHandler) for h in modbus.handlers):
        modbus.addHandler(logging.NullHandler())


_modbus_log_to_the_application()

REG = {
    "ENABLE": 0, "GAIN": 1, "FAULT_RESET": 2, "WATCHDOG_MS": 3,
    "STATUS": 16, "FAULT_CODE": 17, "CURRENT_MA": 18, "TRAVEL_UM": 19,
    "TEMPERATURE_DC": 20, "HEARTBEAT": 21, "INTERLOCK": 22, "MODEL_ID": 23,
    "SERIAL_HI": 24, "SERIAL_LO": 25,
}
MODEL_ID = 0x5A01
FAULT_NAMES = {
    0: "none", 1: "interlock open", 2: "over-temperature", 3: "armature over-travel",
    4: "over-current", 5: "comms watchdog",
}
MODBUS_EXCEPTIONS = {
    1: "illegal function", 2: "illegal data address", 3: "illegal data value (refused)",
    4: "server device failure", 5: "acknowledge", 6: "server device busy",
    10: "gateway path unavailable", 11: "gateway target failed to respond",
}


@contextlib.contextmanager
def modbus_log_held_back() -> Iterator[None]:
    """Hold the Modbus library's own log lines back for the block. The drivers say what
    failed in their own words; pymodbus's lines of the same failure ("No response
    received ...", when an amplifier stops answering) would only be noise on a terminal, and
    garble a full-screen UI."""
    log = logging.getLogger("pymodbus")
    level = log.level
    log.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        log.setLevel(level)


@dataclass(frozen=True)
class AmpStatus:
    """One reading of the amplifier's status registers (SI units)."""

    enabled: bool
    interlock_closed: bool
    fault_latched: bool
    fault_code: int
    current_a: float
    travel_m: float
    temperature_c: float
    heartbeat: int

    @property
    def fault_name(self) -> str:
        return FAULT_NAMES.get(self.fault_code, f"code {self.fault_code}")


class ShakerAmplifier:
    """Async driver of one shaker amplifier.

    Parameters
    ----------
    host, port : str, int
        Modbus TCP address.
    device_id : int
        Modbus unit id.
    timeout_s : float
        Time to wait for one reply.
    retries : int
        Resends of a request that got no reply in ``timeout_s`` (same transaction id, so a
        late reply to the first send still counts). A busy network or controller that misses
        one reply is not a lost instrument; one silent for ``(retries + 1) * timeout_s`` is.
        Every Modbus write we make is idempotent (a register set to a value), so resending
        is safe.
    resync_s : float or None
        After a request went unanswered (no reply to any try, or the call was cancelled),
        how long from then on the next request waits for the amplifier to answer a probe
        before it is sent (see :meth:`_resync`). None: ``2 * (retries + 1) * timeout_s``.
    poll_interval_s : float
        Status polling period of the monitor (also keeps the amplifier's comms watchdog fed).
    heartbeat_timeout_s : float
        A heartbeat counter that does not move for this long, or a status that cannot be
        read for this long, is a fault: the driver disables the amplifier and every later
        call raises :class:`~drivers.errors.HeartbeatLost` until :meth:`reset_fault`.
    max_gain_v_per_v : float
        Safety limit on the gain for this set-up (the instrument allows 0..50 V/V).
    watchdog_ms : int
        Comms watchdog set in the amplifier on connect (0: off).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 502,
        *,
        device_id: int = 1,
        name: str = "amp",
        timeout_s: float = 0.5,
        retries: int = 1,
        resync_s: float | None = None,
        poll_interval_s: float = 0.2,
        heartbeat_timeout_s: float = 1.0,
        max_gain_v_per_v: float = 50.0,
        gain_ramp_step_s: float = 0.02,
        watchdog_ms: int = 1000,
    ) -> None:
        if not 0 < max_gain_v_per_v <= 50.0:
            raise RangeError(f"{name}: max_gain_v_per_v must be in (0, 50]")
        self.host, self.port, self.device_id, self.name = host, port, device_id, name
        self.timeout_s = float(timeout_s)
        if retries < 0:
            raise RangeError(f"{name}: retries must be >= 0")
        self.retries = int(retries)
        self.resync_s = 2 * (self.retries + 1) * self.timeout_s if resync_s is None else float(resync_s)
        if not self.resync_s >= 0:
            raise RangeError(f"{name}: resync_s must be >= 0")
        self.poll_interval_s = float(poll_interval_s)
        self.heartbeat_timeout_s = float(heartbeat_timeout_s)
        self.max_gain_v_per_v = float(max_gain_v_per_v)
        self.gain_ramp_step_s = float(gain_ramp_step_s)
        self.watchdog_ms = int(watchdog_ms)
        self.client: AsyncModbusTcpClient | None = None
        self.serial: int | None = None  # the unit's serial number, read on connect
        self.last_status: AmpStatus | None = None
        self._fault: InstrumentError | None = None
        self._monitor_task: asyncio.Task | None = None
        self._want_enabled = False
        self._lock = asyncio.Lock()
        # When a request ended without its reply (None: none since the last reply): the
        # amplifier may still be busy with it, so the next request waits until it answers.
        self._unanswered_since: float | None = None

    # ------------------------------------------------------------------ link
    async def connect(self) -> None:
        """Open the connection, check the model id, read the serial number, set the watchdog,
        start the monitor."""
        self.client = AsyncModbusTcpClient(
            self.host, port=self.port, timeout=self.timeout_s, retries=self.retries,
            reconnect_delay=0.1, reconnect_delay_max=1.0,
        )
        try:
            ok = await asyncio.wait_for(self.client.connect(), 2 * self.timeout_s + 1.0)
        except TimeoutError:
            ok = False
        if not ok:
            self.client.close()
            raise ConnectionLost(f"{self.name}: cannot connect to {self.host}:{self.port}")
        try:
            model, serial_hi, serial_lo = await self._read(REG["MODEL_ID"], 3)
            if model != MODEL_ID:
                raise ProtocolError(f"{self.name}: unexpected model id 0x{model:04X} (want 0x{MODEL_ID:04X})")
            self.serial = serial_hi << 16 | serial_lo
            await self._write(REG["WATCHDOG_MS"], self.watchdog_ms)
            self.last_status = await self.read_status()
        except BaseException:
            # A peer that accepts and then drops the link (or answers as another device):
            # left open, pymodbus's reconnect task outlived the loop ("Task was destroyed
            # but it is pending!" on stderr).
            self.client.close()
            raise
        self._monitor_task = asyncio.get_running_loop().create_task(self._monitor())

    async def _request(self, make):
        """Run one pymodbus request, after re-synchronising if an earlier one went unanswered;
        a Modbus exception reply is a :class:`~drivers.errors.DeviceError`."""
        if self.client is None:
            raise ConnectionLost(f"{self.name}: not connected")
        async with self._lock:
            if self._unanswered_since is not None:
                await self._resync()
            rr = await self._exchange(make)
        if rr.isError():
            code = getattr(rr, "exception_code", 0)
            raise DeviceError(f"{self.name}: Modbus exception {code} ({MODBUS_EXCEPTIONS.get(code, 'unknown')})")
        return rr

    async def _exchange(self, make):
        """One request and its reply (a Modbus exception reply included), with pymodbus's
        failures as ours. A request that ends without its reply puts the link out of step.

        ``make`` builds the request coroutine; pymodbus raises at once (not when awaited)
        when the link is down, so the call must happen inside the ``try``.
        """
        tries = self.retries + 1
        # pymodbus times each try itself; the outer guard (one try more) is for a hang.
        guard_s = (tries + 1) * self.timeout_s
        try:
            rr = await asyncio.wait_for(make(), guard_s)
        except TimeoutError:
            self._unanswered()
            raise InstrumentTimeout(f"{self.name}: no Modbus reply within {guard_s:g} s") from None
        except ModbusIOException as exc:  # pymodbus: no reply (or an undecodable one) to any try
            self._unanswered()
            raise InstrumentTimeout(
                f"{self.name}: no valid Modbus reply in {tries} tries of {self.timeout_s:g} s") from exc
        except ModbusException as exc:
            raise ConnectionLost(f"{self.name}: Modbus link failed: {exc}") from exc
        except OSError as exc:
            raise ConnectionLost(f"{self.name}: Modbus link failed: {exc}") from exc
        except asyncio.CancelledError:
            # A caller's deadline or Ctrl-C: the request is on the wire all the same.
            self._unanswered()
            raise
        # Its transaction id matched (pymodbus skips replies with another): every request
        # sent before this one has been dealt with.
        self._unanswered_since = None
        return rr

    def _unanswered(self) -> None:
        """Note that a request ended without its reply (the first since the last reply)."""
        if self._unanswered_since is None:
            self._unanswered_since = time.monotonic()

    async def _resync(self) -> None:
        """Probe (read ``MODEL_ID``) until the amplifier answers, for up to ``resync_s`` from
        the request that went unanswered; at least once.

        A request left without its reply may still be in the amplifier's hands, with the
        resend pymodbus made of it behind it. A command sent at once joined that queue: a
        Modbus TCP server that handles one transaction at a time may drop requests that
        reach it while it is busy (pymodbus's own server, the simulator's, answers the first
        of those that arrived together and discards the rest), so the command failed
        although the amplifier answered again a moment later, and ``close()`` could not
        confirm the safe state. A reply carries its request's transaction id and pymodbus
        skips replies with any other: once a probe is answered, every request sent before
        it has been dealt with, and no late reply can come ahead of the next one. An
        amplifier silent past ``resync_s`` is lost (:class:`~drivers.errors.InstrumentTimeout`);
        later requests then probe once each, as long as a request would have waited.
        """
        start = time.monotonic()
        probes = 0
        while True:
            probes += 1
            try:
                await self._exchange(
                    lambda: self.client.read_holding_registers(REG["MODEL_ID"], count=1, device_id=self.device_id)
                )
            except InstrumentTimeout as exc:
                silent = time.monotonic() - self._unanswered_since  # since the first unanswered one
                if silent >= self.resync_s:
                    raise InstrumentTimeout(
                        f"{self.name}: no Modbus reply for {silent:.1f} s after a request went unanswered "
                        f"({probes} probe{'s' if probes > 1 else ''})") from exc
                continue
            log.info("%s: answering again after %.2f s (%d probes)", self.name, time.monotonic() - start, probes)
            return

    async def _read(self, address: int, count: int) -> list[int]:
        rr = await self._request(
            lambda: self.client.read_holding_registers(address, count=count, device_id=self.device_id)
        )
        if len(rr.registers) != count:
            raise ProtocolError(f"{self.name}: asked for {count} registers, got {len(rr.registers)}")
        return list(rr.registers)

    async def _write(self, address: int, value: int) -> None:
        await self._request(lambda: self.client.write_register(address, value, device_id=self.device_id))

    # ------------------------------------------------------------------ device
    async def read_status(self) -> AmpStatus:
        w = await self._read(REG["STATUS"], 7)
        st = AmpStatus(
            enabled=bool(w[0] & 1), interlock_closed=bool(w[0] & 2), fault_latched=bool(w[0] & 4),
            fault_code=w[1], current_a=w[2] / 1000.0, travel_m=w[3] * 1e-6,
            temperature_c=w[4] / 10.0, heartbeat=w[5],
        )
        self.last_status = st
        return st

    def check(self) -> None:
        """Raise the fault the monitor found, if any."""
        if self._fault is not None:
            raise self._fault

    async def enable(self) -> None:
        """Enable the output stage: only with the interlock closed and no fault latched."""
        self.check()
        st = await self.read_status()
        self._refuse_unless_ready(st)
        try:
            await self._write(REG["ENABLE"], 1)
        except DeviceError:
            self._refuse_unless_ready(await self.read_status())  # say why, if we can
            raise
        st = await self.read_status()
        if not st.enabled:
            raise AmplifierFault(f"{self.name}: did not enable (fault: {st.fault_name})", st.fault_code)
        self._want_enabled = True

    def _refuse_unless_ready(self, st: AmpStatus) -> None:
        if not st.interlock_closed:
            raise InterlockOpen(f"{self.name}: interlock open (door or E-stop): will not enable")
        if st.fault_latched:
            raise AmplifierFault(f"{self.name}: fault latched ({st.fault_name}); clear the cause and reset", st.fault_code)

    async def disable(self) -> None:
        self._want_enabled = False
        await self._write(REG["ENABLE"], 0)

    async def set_gain(self, gain_v_per_v: float) -> None:
        """Set the voltage gain; ramped in 10 % steps while the output is enabled, then read back
        (``DeviceError`` if the amplifier holds another)."""
        if not (math.isfinite(gain_v_per_v) and 0 <= gain_v_per_v <= self.max_gain_v_per_v):
            raise RangeError(f"{self.name}: gain {gain_v_per_v!r} V/V outside [0, {self.max_gain_v_per_v:g}]")
        self.check()
        target = int(round(gain_v_per_v * 100))
        if self._want_enabled:
            now = (await self._read(REG["GAIN"], 1))[0]
            span = max(1, int(math.ceil(abs(target - now) / (0.1 * self.max_gain_v_per_v * 100))))
            for k in range(1, span + 1):
                await self._write(REG["GAIN"], int(round(now + (target - now) * k / span)))
                if k < span:
                    await asyncio.sleep(self.gain_ramp_step_s)
        else:
            await self._write(REG["GAIN"], target)
        # An amplifier acknowledges a gain it then limits: read back, the drive's volts per
        # volt are what the level control and the drive limits count on.
        got = (await self._read(REG["GAIN"], 1))[0]
        if got != target:
            raise DeviceError(f"{self.name}: gain set to {gain_v_per_v:g} V/V reads back {got / 100:g} V/V "
                              "(does the amplifier limit it?)")

    async def reset_fault(self) -> None:
        """Clear a latched fault in the amplifier and in the driver (the cause must be gone)."""
        try:
            await self._write(REG["FAULT_RESET"], 1)
        except DeviceError as exc:
            raise AmplifierFault(f"{self.name}: fault reset refused: its cause is still present") from exc
        self._fault = None

    # ------------------------------------------------------------------ monitor
    async def _monitor(self) -> None:
        last_beat, last_change, last_ok = None, time.monotonic(), time.monotonic()
        while True:
            await asyncio.sleep(self.poll_interval_s)
            now = time.monotonic()
            try:
                st = await self.read_status()
            except InstrumentError as exc:
                if now - last_ok > self.heartbeat_timeout_s and self._fault is None:
                    await self._set_fault(HeartbeatLost(f"{self.name}: status unreadable for {now - last_ok:.1f} s: {exc}"))
                continue
            last_ok = now
            if st.heartbeat != last_beat:
                last_beat, last_change = st.heartbeat, now
            elif now - last_change > self.heartbeat_timeout_s and self._fault is None:
                await self._set_fault(HeartbeatLost(f"{self.name}: heartbeat stopped at {st.heartbeat} for {now - last_change:.1f} s"))
            if self._fault is None and self._want_enabled and not st.enabled:
                cls = InterlockOpen if st.fault_code == 1 else AmplifierFault
                err = cls(f"{self.name}: amplifier tripped ({st.fault_name})")
                if isinstance(err, AmplifierFault):
                    err.code = st.fault_code
                await self._set_fault(err)

    async def _set_fault(self, err: InstrumentError) -> None:
        log.error("%s", err)
        self._fault = err
        self._want_enabled = False
        try:
            await self._write(REG["ENABLE"], 0)
        except InstrumentError:
            pass  # the amplifier's own watchdog disables it if we cannot reach it

    # ------------------------------------------------------------------ safety
    async def safe_state(self) -> None:
        """Output disabled and confirmed; reconnects once if the link dropped. Never hangs.

        A second attempt after a request went unanswered waits (up to ``resync_s`` from it)
        for the amplifier to answer again, so a controller that answered late is still
        confirmed disabled.
        """
        self._want_enabled = False
        last: Exception | None = None
        for attempt in range(2):
            try:
                await self._write(REG["ENABLE"], 0)
                if not (await self.read_status()).enabled:
                    return
                last = InstrumentError("it acknowledged ENABLE = 0 but still reads enabled")
            except InstrumentError as exc:
                last = exc
            if attempt == 0 and self.client is not None:
                # pymodbus reconnects by itself (reconnect_delay); wait for that rather than
                # starting a second connection that would race with it.
                deadline = time.monotonic() + 2 * self.timeout_s + 1.0
                while not self.client.connected and time.monotonic() < deadline:
                    await asyncio.sleep(0.05)
        raise InstrumentError(f"{self.name}: could not confirm the amplifier disabled: {last}")

    async def close(self, safe_state: bool = True) -> None:
        """Safe state (unless ``safe_state`` is False: the caller has just tried it), stop the
        monitor, close the link (always, even if safe_state fails)."""
        try:
            if self.client is not None and safe_state:
                await self.safe_state()
        finally:
            if self._monitor_task is not None:
                # Python 3.11's wait_for drops a cancel that lands in the loop iteration where
                # the monitor's request has just finished (it returns the reply instead), and
                # the monitor polls on: cancel again until it has ended.
                while not self._monitor_task.done():
                    self._monitor_task.cancel()
                    await asyncio.wait([self._monitor_task], timeout=self.poll_interval_s)
                await asyncio.gather(self._monitor_task, return_exceptions=True)
                self._monitor_task = None
            if self.client is not None:
                self.client.close()
                self.client = None

    async def __aenter__(self) -> ShakerAmplifier:
        await self.connect()
        return self

    async def __aexit__(self, *exc) -> None:
        await self.close()


def __getattr__(name: str):
    """``drivers.amplifier.SyncShakerAmplifier`` stays importable (scripts name it so); it
    lives in :mod:`drivers.amplifier_sync`, which imports this module."""
    if name == "SyncShakerAmplifier":
        from .amplifier_sync import SyncShakerAmplifier

        return SyncShakerAmplifier
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
