"""Drivers against simulated instruments that misbehave on the wire (late, cut or garbled
replies, a dropped link), over the real transports: the DAQ on a python-can virtual bus, the
generator on a pty and a TCP socket. Each simulator is the stock one with one fault added."""

from __future__ import annotations

import itertools
import logging
import time

import can
import pytest
from conftest import driven_world

from drivers.daq import CanFdDaq, DaqChannel
from drivers.errors import InstrumentTimeout, ProtocolError
from sim_devices.daq_sim import CMD_STATUS, RSP_ID, SimDaq

FS = 5120
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
