"""Signal generator driver against the simulated SCPI generator, over a pty and a socket."""

from __future__ import annotations

import time

import numpy as np
import pytest
from conftest import two_shaker_world

from drivers.errors import (
    ConnectionLost,
    DeviceError,
    InstrumentError,
    InstrumentTimeout,
    ProtocolError,
    RangeError,
)
from drivers.siggen import SignalGenerator
from sim_devices.siggen_sim import SimSignalGenerator

FAST = dict(timeout_s=0.25, ramp_time_s=0.05, ramp_step_s=0.005)


@pytest.fixture
def world():
    return two_shaker_world()


@pytest.fixture(params=["pty", "tcp"])
def sim(request, world):
    with SimSignalGenerator(world, 0, transport=request.param) as s:
        yield s


def test_settings_reach_the_instrument(sim, world):
    ch1 = world.generators[0].channels[0]
    with SignalGenerator(sim.url, **FAST) as gen:
        assert gen.idn.startswith("ssidlab,SIM-33522")
        gen.set_function(1, "SIN")
        gen.set_frequency(1, 123.5)
        gen.set_offset(1, 0.25)
        gen.set_amplitude(1, 1.5)  # output off: set directly
        assert (ch1.function, ch1.freq_hz, ch1.offset_volt, ch1.vpp) == ("SIN", 123.5, 0.25, 1.5)
        gen.set_function(2, "NOIS")
        assert world.generators[0].channels[1].function == "NOIS"
        assert gen.scpi.query("SOUR1:FREQ?") == "123.5"
    assert not ch1.output_on


def test_amplitude_is_ramped_while_on_and_exit_switches_off(sim, world):
    ch1 = world.generators[0].channels[0]
    with SignalGenerator(sim.url, **FAST) as gen:
        gen.output_on(1, vpp=4.0)
        assert ch1.output_on and ch1.vpp == pytest.approx(4.0)
        volts = [float(line.split()[1].split(";")[0]) for line in sim.log if line.upper().startswith("SOUR1:VOLT ")]
        assert volts[0] == pytest.approx(2e-3) and len(volts) >= 3 and np.all(np.diff(volts) > 0)
        sim.log.clear()
    # Exit: ramped down, then off.
    downs = [float(line.split()[1].split(";")[0]) for line in sim.log if line.upper().startswith("SOUR1:VOLT ")]
    assert len(downs) >= 2 and np.all(np.diff(downs) < 0)
    assert not ch1.output_on and not world.generators[0].channels[1].output_on


def test_a_ctrl_c_while_close_ramps_down_leaves_every_output_off(sim, world, ctrl_c_after):
    """close() ramps each output down in turn. A Ctrl-C (Python's own handler, as in a user's
    script) landing in the first ramp stopped the safe state there: the first output was
    switched off by its ramp's ``finally``, the second stayed on at full level. It is now
    raised once close() has ended."""
    chans = world.generators[0].channels
    gen = SignalGenerator(sim.url, **FAST)
    gen.output_on(1, vpp=9.0)
    gen.output_on(2, vpp=9.0)
    # safe_state ramps each output down over 0.1 s per 10 Vpp: the first ramp, from 9 Vpp,
    # takes some 45 ms here, and the Ctrl-C lands in it.
    ctrl_c_after(0.015)
    with pytest.raises(KeyboardInterrupt):
        gen.close()
        time.sleep(1.0)  # the old code: the interrupt comes in close(), or here at the latest
    assert not chans[0].output_on and not chans[1].output_on


def test_ranges_checked_before_sending_and_errors_from_the_queue(sim):
    with SignalGenerator(sim.url, max_vpp=5.0, **FAST) as gen:
        n = len(sim.log)
        for bad in (lambda: gen.set_amplitude(1, 6.0), lambda: gen.set_frequency(1, 30e6),
                    lambda: gen.set_frequency(1, float("nan")), lambda: gen.set_function(1, "SQU"),
                    lambda: gen.set_offset(1, 10.5), lambda: gen.set_amplitude(3, 1.0)):
            with pytest.raises(RangeError):
                bad()
        assert len(sim.log) == n  # nothing was sent
        # The instrument's own check, through the error queue:
        with pytest.raises(DeviceError, match="-222"):
            gen.scpi.write("SOUR1:FREQ 1e9")
        with pytest.raises(DeviceError, match="-113"):
            gen.scpi.write("SOUR1:BOGUS 1")
        with pytest.raises(DeviceError, match="-221"):
            gen.set_function(1, "ARB")  # no waveform uploaded yet
        gen.scpi.check_errors()  # the queue is empty again


def test_the_peak_with_the_offset_is_checked_before_sending(sim, world):
    """An amplitude whose peak with the channel's offset (set by the driver, or found at
    connect) exceeds 10 V is refused before anything is sent: before, only Vpp was checked,
    and the instrument refused mid-ramp, leaving the output on at a partial level."""
    ch1, ch2 = world.generators[0].channels
    ch2.offset_volt = -6.0  # left by an earlier session
    with SignalGenerator(sim.url, **FAST) as gen:
        gen.set_offset(1, 5.0)
        n = len(sim.log)
        with pytest.raises(RangeError, match=r"\|offset\| \+ Vpp/2"):
            gen.output_on(1, vpp=12.0)  # 5 + 6 V
        with pytest.raises(RangeError, match=r"\|offset\| \+ Vpp/2"):
            gen.set_amplitude(2, 9.0)  # 6 + 4.5 V
        assert len(sim.log) == n and not ch1.output_on and ch1.vpp == ch2.vpp == 0.1  # as they were
        gen.output_on(1, vpp=10.0)  # 5 + 5 V: allowed
        assert ch1.vpp == pytest.approx(10.0)


def test_arbitrary_waveform_upload(sim, world):
    x = np.random.default_rng(0).standard_normal(512)
    with SignalGenerator(sim.url, **FAST) as gen:
        scale = gen.upload_arb(1, x, 5120.0, name="PRAND")
        ch1 = world.generators[0].channels[0]
        assert ch1.function == "ARB" and ch1.arb_srate_hz == 5120.0
        np.testing.assert_allclose(ch1.arb, x * scale, atol=1e-6)
        with pytest.raises(RangeError):
            gen.upload_arb(1, np.zeros(16), 5120.0)
        with pytest.raises(RangeError):
            gen.upload_arb(1, [1.0, 2.0], 5120.0)


def test_noise_bandwidth(sim, world):
    with SignalGenerator(sim.url, **FAST) as gen:
        gen.set_function(1, "NOIS")
        gen.set_noise_bandwidth(1, 1000.0)
        assert float(gen.scpi.query("SOUR1:FUNC:NOIS:BAND?")) == 1000.0
        assert world.generators[0].channels[0].noise_bw_hz == 1000.0
        for bad in (0.0, float("nan"), 1e9):
            with pytest.raises(RangeError):
                gen.set_noise_bandwidth(1, bad)
        gen.scpi.check_errors()


@pytest.mark.parametrize("fault,error", [("silent", InstrumentTimeout), ("partial", InstrumentTimeout),
                                         ("garbage", ProtocolError)])
def test_serial_faults_give_clear_errors_and_recover(sim, world, fault, error):
    with SignalGenerator(sim.url, **FAST) as gen:
        gen.output_on(1, vpp=1.0)
        sim.inject(fault)
        t0 = time.monotonic()
        with pytest.raises(error) as info:
            gen.scpi.query("*IDN?")
        assert time.monotonic() - t0 < 1.0  # bounded by the timeout, never a hang
        if fault == "partial":
            assert "partial line" in str(info.value)
        gen.recover()
        assert gen.scpi.query("*IDN?").startswith("ssidlab")
        sim.inject(fault)  # the fault hits the exit path too: still ends safe
    assert not world.generators[0].channels[0].output_on


def test_dead_instrument_safe_state_is_bounded_and_reports(world):
    sim = SimSignalGenerator(world, 0, transport="tcp").start()
    gen = SignalGenerator(sim.url, **FAST)
    gen.output_on(1, vpp=1.0)
    sim.inject("silent", count=1000)  # the instrument stops answering altogether
    t0 = time.monotonic()
    with pytest.raises(InstrumentError, match="could not confirm outputs off"):
        gen.close()
    assert time.monotonic() - t0 < 10.0
    assert not gen.line.is_open  # the port is released anyway
    sim.stop()


def test_unreachable_port_is_a_clear_error():
    with pytest.raises(ConnectionLost, match="cannot open"):
        SignalGenerator("/dev/does-not-exist", **FAST)
