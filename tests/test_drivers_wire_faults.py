"""Drivers against simulated instruments that misbehave on the wire (late, cut or garbled
replies, a dropped link), over the real transports: the DAQ on a python-can virtual bus, the
generator on a pty and a TCP socket. Each simulator is the stock one with one fault added."""

from __future__ import annotations

import itertools
import logging
import socket
import struct
import time

import can
import pytest
from conftest import driven_world, two_shaker_world

from drivers.daq import CanFdDaq, DaqChannel
from drivers.errors import ConnectionLost, DeviceError, InstrumentError, InstrumentTimeout, ProtocolError
from drivers.siggen import SignalGenerator
from sim_devices.daq_sim import CMD_STATUS, RSP_ID, SimDaq
from sim_devices.siggen_sim import SimSignalGenerator
from sim_devices.world import World

FS = 5120
FAST = dict(timeout_s=0.25, ramp_time_s=0.05, ramp_step_s=0.005)
CHANNELS = [DaqChannel("force 1+Z", 0, "force", 22.5, 10.0, "DC"), DaqChannel("acc 1+Z", 2)]
_names = itertools.count()


class MisbehavingDaq(SimDaq):
    """The simulated DAQ, answering commands in :attr:`late` (command -> delay, once) that
    late, and cutting the response to a command in :attr:`short` (once) to 8 bytes."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.late: dict[int, float] = {}
        self.short: set[int] = set()

    def _send(self, msg: can.Message) -> None:
        if msg.arbitration_id == RSP_ID and not msg.is_error_frame:
            cmd = msg.data[0]
            if cmd in self.late:
                time.sleep(self.late.pop(cmd))
            if cmd in self.short:
                self.short.discard(cmd)
                msg = can.Message(arbitration_id=RSP_ID, data=bytes(msg.data[:8]), is_fd=True, is_extended_id=False)
        super()._send(msg)


@pytest.fixture
def bad_daq():
    """(misbehaving simulated DAQ, driver) on a fresh virtual channel, the channels configured."""
    name = f"test-wire-daq-{next(_names)}"
    sim = MisbehavingDaq(driven_world(), name).start()
    daq = CanFdDaq(channel=name, timeout_s=0.2, stream_timeout_s=0.5)
    daq.configure(CHANNELS, FS)
    yield sim, daq
    daq.close()
    sim.stop()


def test_a_late_response_answers_no_later_request(bad_daq, caplog):
    """A STATUS response that comes after its request timed out is dropped (a debug note),
    not kept for the request 256 later that reuses its 8-bit token: that one gets its own
    answer (before: the stale 'idle' while the DAQ was acquiring)."""
    sim, daq = bad_daq
    sim.late[CMD_STATUS] = 1.5 * daq.timeout_s
    with pytest.raises(InstrumentTimeout, match="no response to STATUS"):
        daq.status()
    late_token = daq._token
    time.sleep(daq.timeout_s)  # the late response is on the bus now
    with caplog.at_level(logging.DEBUG, logger="drivers.daq"):
        for _ in range(254):
            daq.request("SET_RATE", sample_rate_hz=FS)
        daq.start()
        assert (daq._token + 1) & 0xFF == late_token  # the next request reuses the late one's token
        assert daq.status()["state"] == "acquiring"
    dropped = [r for r in caplog.records if "dropped: no request waits for it" in r.getMessage()]
    assert len(dropped) == 1 and dropped[0].levelno == logging.DEBUG
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_a_cut_response_fails_its_request_with_the_cause(bad_daq):
    """A truncated (8-byte) response to the waiting request fails it at once with the
    ProtocolError that says so (before: a time-out blaming a silent DAQ, the cause left
    queued for the next read); the next request is answered normally."""
    sim, daq = bad_daq
    sim.short.add(CMD_STATUS)
    t0 = time.monotonic()
    with pytest.raises(ProtocolError, match="bad response frame to STATUS: .*8 instead of 16 bytes"):
        daq.status()
    assert time.monotonic() - t0 < daq.timeout_s
    assert daq.status()["state"] == "idle"
    assert not daq._errors


# ---------------------------------------------------------------------- signal generator
class MisbehavingGenerator(SimSignalGenerator):
    """The simulated generator, answering the first line that contains :attr:`late_match`
    :attr:`late_s` late, and a line that contains a key of :attr:`garble` with its value;
    on TCP, resetting the connection on the first line that contains :attr:`reset_match`."""

    late_match: str = ""
    late_s: float = 0.0
    reset_match: str = ""
    _line: str = ""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.garble: dict[str, str] = {}

    def _handle_line(self, line: str) -> str | None:
        self._line = line
        if self.reset_match and self.reset_match in line and self._conn is not None:
            self.reset_match = ""
            # Linger 0: close() sends a RST, as a converter or instrument that restarts does.
            self._conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            self._conn.close()
            self._conn = None
            return None
        reply = super()._handle_line(line)
        return next((v for k, v in self.garble.items() if k in line), reply)

    def _send_reply(self, reply: str) -> None:
        if self.late_match and self.late_match in self._line:
            self.late_match = ""
            time.sleep(self.late_s)
        super()._send_reply(reply)


@pytest.fixture
def gen_world() -> World:
    return two_shaker_world()


@pytest.fixture(params=["pty", "tcp"])
def bad_gen(request, gen_world):
    with MisbehavingGenerator(gen_world, 0, transport=request.param) as sim:
        yield sim


def test_a_non_numeric_amplitude_reply_is_a_protocol_error(bad_gen):
    """ASCII garbage as the reply to 'SOURn:VOLT?', on connect and after reset(): a
    ProtocolError naming the generator, the query and the reply (before: a bare ValueError
    from float(), which a run does not take for an instrument fault)."""
    bad_gen.garble = {"SOUR1:VOLT?": "#@!garbage"}
    with pytest.raises(ProtocolError, match=r"^siggen: unexpected SOUR1:VOLT\? reply '#@!garbage'"):
        SignalGenerator(bad_gen.url, **FAST)
    bad_gen.garble = {}
    with SignalGenerator(bad_gen.url, **FAST) as gen:
        bad_gen.garble = {"SOUR2:VOLT?": "1.5 V"}
        with pytest.raises(ProtocolError, match=r"^siggen: unexpected SOUR2:VOLT\? reply '1.5 V'"):
            gen.reset()
        bad_gen.garble = {}


def test_a_reply_after_the_time_out_answers_no_later_command(bad_gen, gen_world):
    """The reply to 'OUTP1 ON' comes just after the time-out: the next command still gets
    its own reply (before: each got its predecessor's, a refused frequency was taken as
    accepted and the next valid one was refused with its error)."""
    with SignalGenerator(bad_gen.url, **FAST) as gen:
        bad_gen.late_match, bad_gen.late_s = "OUTP1 ON", 1.2 * FAST["timeout_s"]
        with pytest.raises(InstrumentTimeout, match=r"siggen: 'OUTP1 ON;:SYST:ERR\?': .*no reply within 0.25 s"):
            gen.output_on(1)
        with pytest.raises(DeviceError, match=r"after 'SOUR1:FREQ 1e\+12': -222"):
            gen.scpi.write("SOUR1:FREQ 1e+12")
        gen.set_frequency(1, 100.0)
        assert gen_world.generators[0].channels[0].freq_hz == 100.0
        assert gen.scpi.query("SOUR1:FREQ?") == "100"


def test_a_reset_link_names_the_generator(gen_world):
    """A TCP reset while the generator is being set: ConnectionLost names the generator and
    the command, as a time-out does (before: only the socket's address)."""
    with MisbehavingGenerator(gen_world, 0, transport="tcp") as sim:
        gen = SignalGenerator(sim.url, name="gen-A", **FAST)
        try:
            sim.reset_match = "SOUR1:FREQ"
            with pytest.raises(ConnectionLost, match=r"^gen-A: 'SOUR1:FREQ 100;:SYST:ERR\?': socket://127.0.0.1:\d+: "):
                gen.set_frequency(1, 100.0)
            with pytest.raises(InstrumentError, match=r"could not confirm outputs off: channel 1: gen-A: "):
                gen.safe_state()  # the link stays broken: every failure names the generator
        finally:
            gen.release()
