"""Simulated shaker power amplifier: a Modbus TCP server (pymodbus) on 127.0.0.1.

Register map (holding registers, device id 1, function codes 3/4 read, 6/16 write; the
same table is in ``docs/drivers.md`` and in ``drivers.amplifier``)::

    addr  name              access  meaning
    0     ENABLE            rw      1 = output stage on; refused (exception 03) unless the
                                    interlock is closed and no fault is latched
    1     GAIN              rw      voltage gain x100 (0..5000 = 0..50 V/V)
    2     FAULT_RESET       w       write 1 to clear a latched fault whose cause is gone
    3     WATCHDOG_MS       rw      comms watchdog: no request for this long while enabled
                                    trips the amplifier (0 = off; default 1000)
    16    STATUS            r       bit0 enabled, bit1 interlock closed, bit2 fault latched,
                                    bit3 over-temperature, bit4 over-travel, bit5 over-current
    17    FAULT_CODE        r       0 none, 1 interlock, 2 over-temperature, 3 over-travel,
                                    4 over-current, 5 comms watchdog
    18    CURRENT_MA        r       output current, RMS over the last block, mA
    19    TRAVEL_UM         r       armature peak travel over the last block, micrometres
    20    TEMPERATURE_DC    r       coil temperature, 0.1 degC
    21    HEARTBEAT         r       counter, +1 every 100 ms while the controller runs
    22    INTERLOCK         r       1 closed, 0 open
    23    MODEL_ID          r       0x5A01
    24    SERIAL_HI         r       serial number, high 16 bits
    25    SERIAL_LO         r       serial number, low 16 bits

The server runs on an asyncio loop in a thread owned by :class:`AmpServerThread` (one loop
can host several amplifiers). Faults for tests: :meth:`SimAmplifier.inject` with
``"exception"`` (the next requests answered with a Modbus exception), ``"delay"`` (the next
requests answered late, as by a busy controller or network), ``"drop"`` (close every
open connection now), ``"heartbeat_stall"``; :meth:`set_interlock`,
:meth:`inject_over_temperature`.
"""

from __future__ import annotations

import asyncio
import threading
import time

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from .components import (
    AMP_FAULT_COMMS_WATCHDOG,
    AMP_FAULT_OVER_CURRENT,
    AMP_FAULT_OVER_TEMPERATURE,
    AMP_FAULT_OVER_TRAVEL,
    AmplifierModel,
)

__all__ = ["REG", "AmpServerThread", "SimAmplifier"]

REG = {
    "ENABLE": 0, "GAIN": 1, "FAULT_RESET": 2, "WATCHDOG_MS": 3,
    "STATUS": 16, "FAULT_CODE": 17, "CURRENT_MA": 18, "TRAVEL_UM": 19,
    "TEMPERATURE_DC": 20, "HEARTBEAT": 21, "INTERLOCK": 22, "MODEL_ID": 23,
    "SERIAL_HI": 24, "SERIAL_LO": 25,
}
N_CONTROL, N_STATUS = 4, 10
MODEL_ID = 0x5A01
GAIN_MAX_CENTI = 5000
DEVICE_ID = 1
_WRITE_FUNCTIONS = (6, 16)  # write single / multiple registers


class AmpServerThread:
    """An asyncio event loop in a daemon thread, hosting simulated Modbus servers."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, name="sim-modbus", daemon=True)
        self._thread.start()

    def run(self, coro, timeout_s: float = 5.0):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout_s)

    def stop(self) -> None:
        if not self._thread.is_alive():
            return

        async def _cancel_all() -> None:
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

        try:
            self.run(_cancel_all())
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(timeout=5.0)
            self.loop.close()


class SimAmplifier:
    """Modbus TCP front end of one :class:`~sim_devices.components.AmplifierModel`.

    Parameters
    ----------
    model : AmplifierModel
        The amplifier state shared with the world.
    host_thread : AmpServerThread
        Event loop that runs the server.
    port : int
        TCP port on 127.0.0.1 (0: an ephemeral port, see :attr:`port` after start).
    serial : int
        The unit's serial number (32 bits); tests set another for a replaced unit.
    """

    def __init__(self, model: AmplifierModel, host_thread: AmpServerThread, port: int = 0, name: str = "amp",
                 serial: int = 1) -> None:
        if not 0 <= serial < 1 << 32:
            raise ValueError(f"{name}: serial must fit in 32 bits, got {serial}")
        self.model = model
        self.serial = serial
        self.host = "127.0.0.1"
        self.port = port
        self.name = name
        self._loop_thread = host_thread
        self._server: ModbusTcpServer | None = None
        self._tick_task: asyncio.Task | None = None
        self.heartbeat = 0
        self.heartbeat_stalled = False
        self.watchdog_ms = 1000
        self._last_request = time.monotonic()
        self._exceptions_left = 0
        self._delays_left, self._delay_s = 0, 0.0
        self._exception_code = ExcCodes.DEVICE_BUSY
        self.requests = 0

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> SimAmplifier:
        self._loop_thread.run(self._start())
        return self

    async def _start(self) -> None:
        control = SimData(0, values=[0, 100, 0, self.watchdog_ms], datatype=DataType.REGISTERS)
        status = SimData(REG["STATUS"], values=[0] * N_STATUS, datatype=DataType.REGISTERS, readonly=True)
        device = SimDevice(id=DEVICE_ID, simdata=[control, status], action=self._action)
        self._server = ModbusTcpServer(device, address=(self.host, self.port))  # loopback only
        await self._server.serve_forever(background=True)
        self.port = self._server.transport.sockets[0].getsockname()[1]
        self._tick_task = asyncio.get_running_loop().create_task(self._tick())

    def stop(self) -> None:
        if self._server is None:
            return
        try:
            self._loop_thread.run(self._stop())
        finally:
            self._server = None

    async def _stop(self) -> None:
        if self._tick_task:
            self._tick_task.cancel()
        await self._server.shutdown()

    # ------------------------------------------------------------------ faults
    def inject(self, kind: str, count: int = 1, code: int = ExcCodes.DEVICE_BUSY, delay_s: float = 0.0) -> None:
        """``exception`` (next ``count`` requests), ``delay`` (next ``count`` replies sent
        ``delay_s`` late; it stalls the server's loop, so every amplifier that loop hosts),
        ``drop`` (connections) or ``heartbeat_stall``.

        Requests that reach a stalled server together (a client's resend, its next request)
        are not all answered: pymodbus's server answers the first of those that one read
        from the socket returns and discards the rest, as a device that handles one
        transaction at a time may.
        """
        if kind == "exception":
            self._exception_code = ExcCodes(code)
            self._exceptions_left = count
        elif kind == "delay":
            self._delay_s, self._delays_left = float(delay_s), count
        elif kind == "drop":
            self._loop_thread.run(self._drop())
        elif kind == "heartbeat_stall":
            self.heartbeat_stalled = True
        else:
            raise ValueError(f"unknown amplifier fault {kind!r}")

    async def _drop(self) -> None:
        for conn in list(self._server.active_connections.values()):
            conn.close()

    def set_interlock(self, closed: bool) -> None:
        """Open (trips the amplifier) or close the interlock loop."""
        self.model.set_interlock(closed)

    def inject_over_temperature(self) -> None:
        """Coil temperature jumps above its limit: the amplifier trips."""
        with self.model.lock:
            self.model.temperature_c = 150.0
            self.model.trip(AMP_FAULT_OVER_TEMPERATURE)

    # ------------------------------------------------------------------ controller
    async def _tick(self) -> None:
        """The amplifier's controller loop: heartbeat and comms watchdog, every 100 ms."""
        while True:
            await asyncio.sleep(0.1)
            if not self.heartbeat_stalled:
                self.heartbeat = (self.heartbeat + 1) & 0xFFFF
            if self.watchdog_ms and self.model.enabled:
                if (time.monotonic() - self._last_request) * 1000 > self.watchdog_ms:
                    self.model.trip(AMP_FAULT_COMMS_WATCHDOG)

    def _status_words(self) -> list[int]:
        m = self.model
        with m.lock:
            bits = (
                int(m.enabled)
                | int(m.interlock_closed) << 1
                | int(m.fault_code != 0) << 2
                | int(m.fault_code == AMP_FAULT_OVER_TEMPERATURE) << 3
                | int(m.fault_code == AMP_FAULT_OVER_TRAVEL) << 4
                | int(m.fault_code == AMP_FAULT_OVER_CURRENT) << 5
            )
            clamp = lambda v: max(0, min(0xFFFF, int(round(v))))
            return [
                bits,
                m.fault_code,
                clamp(m.current_rms_a * 1000),
                clamp(m.travel_peak_m * 1e6),
                clamp(m.temperature_c * 10),
                self.heartbeat,
                int(m.interlock_closed),
                MODEL_ID,
                self.serial >> 16,
                self.serial & 0xFFFF,
            ]

    async def _action(self, func_code, start_address, address, count, registers, set_values):
        """Called by pymodbus before registers are read or written: once for a read, twice for
        a write (the write, then the read-back of the registers its reply echoes)."""
        if not (func_code in _WRITE_FUNCTIONS and not set_values):
            # Once per request: a write's read-back half took a second delay (a write with
            # ``inject("delay", count=1)`` was answered 2 * delay_s late, and count=2 made one
            # reply late, not two) and counted as a second request.
            self.requests += 1
            self._last_request = time.monotonic()
            if self._delays_left:
                self._delays_left -= 1
                # A busy controller: everything stops, heartbeat included. Blocking, because the
                # pymodbus server mixes up replies on one connection when an action awaits.
                time.sleep(self._delay_s)
            if self._exceptions_left:
                self._exceptions_left -= 1
                return self._exception_code
        if set_values:
            for k, value in enumerate(set_values):
                err = self._write(address + k, int(value))
                if err is not None:
                    return err
                if address + k == REG["FAULT_RESET"]:
                    set_values[k] = 0  # a command, not a setting: it reads back 0
                elif address + k == REG["GAIN"]:  # reads back the gain the amplifier holds
                    set_values[k] = int(round(self.model.gain_v_per_v * 100))
        # Refresh live values so that this very read (and the next) sees the present state.
        s = REG["STATUS"] - start_address
        registers[s : s + N_STATUS] = self._status_words()
        registers[REG["ENABLE"] - start_address] = int(self.model.enabled)
        return None

    def _write(self, addr: int, value: int):
        m = self.model
        if addr == REG["ENABLE"]:
            if value not in (0, 1):
                return ExcCodes.ILLEGAL_VALUE
            if value == 0:
                m.disable()
            elif m.request_enable() != 0:
                return ExcCodes.ILLEGAL_VALUE  # interlock open or fault latched: refused
        elif addr == REG["GAIN"]:
            if not 0 <= value <= GAIN_MAX_CENTI:
                return ExcCodes.ILLEGAL_VALUE
            with m.lock:
                m.gain_v_per_v = value / 100.0
        elif addr == REG["FAULT_RESET"]:
            if value == 1 and not m.reset_fault():
                return ExcCodes.ILLEGAL_VALUE  # cause still present
        elif addr == REG["WATCHDOG_MS"]:
            self.watchdog_ms = value
        return None
