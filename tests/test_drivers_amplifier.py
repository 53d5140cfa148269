"""Amplifier driver against the simulated amplifier: Modbus TCP on 127.0.0.1, real pymodbus."""

from __future__ import annotations

import asyncio
import contextlib
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from drivers.amplifier import REG, ShakerAmplifier
from drivers.amplifier_sync import SyncShakerAmplifier
from drivers.errors import (
    AmplifierFault,
    ConnectionLost,
    DeviceError,
    HeartbeatLost,
    InstrumentError,
    InstrumentTimeout,
    InterlockOpen,
    RangeError,
)
from sim_devices import amp_sim
from sim_devices.amp_sim import AmpServerThread, SimAmplifier
from sim_devices.components import AMP_FAULT_COMMS_WATCHDOG, AmplifierModel

FAST = dict(timeout_s=0.3, poll_interval_s=0.05, heartbeat_timeout_s=0.35, gain_ramp_step_s=0.0)


@pytest.fixture
def sim():
    host = AmpServerThread()
    s = SimAmplifier(AmplifierModel(), host).start()
    yield s
    s.stop()
    host.stop()


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 20.0))  # a hang fails the test instead of blocking it


def test_register_maps_agree():
    assert REG == amp_sim.REG


def test_enable_only_with_interlock_closed_and_no_fault(sim):
    m = sim.model

    async def go():
        async with ShakerAmplifier("127.0.0.1", sim.port, **FAST) as amp:
            await amp.set_gain(4.0)
            assert m.gain_v_per_v == 4.0
            with pytest.raises(RangeError):
                await amp.set_gain(80.0)
            sim.set_interlock(False)
            with pytest.raises(InterlockOpen):
                await amp.enable()
            # The device refuses too, if a client skips the check (Modbus exception 03).
            with pytest.raises(DeviceError, match="exception 3"):
                await amp._write(REG["ENABLE"], 1)
            assert not m.enabled
            sim.set_interlock(True)
            with pytest.raises(AmplifierFault, match="interlock"):
                await amp.enable()  # the trip is latched until reset
            await amp.reset_fault()
            await amp.enable()
            assert m.enabled
            await amp.set_gain(10.0)  # ramped while enabled
            assert m.gain_v_per_v == 10.0
            st = await amp.read_status()
            assert st.enabled and st.interlock_closed and st.fault_code == 0
        assert not m.enabled  # exit: safe state

    run(go())


def test_interlock_trip_during_run(sim):
    async def go():
        async with ShakerAmplifier("127.0.0.1", sim.port, **FAST) as amp:
            await amp.enable()
            sim.set_interlock(False)  # somebody opens the door
            await asyncio.sleep(0.3)
            with pytest.raises(InterlockOpen):
                amp.check()
            with pytest.raises(InterlockOpen):
                await amp.set_gain(2.0)
            assert not sim.model.enabled
        assert not sim.model.enabled

    run(go())


def test_over_temperature_trip_and_reset_rules(sim):
    async def go():
        async with ShakerAmplifier("127.0.0.1", sim.port, **FAST) as amp:
            await amp.enable()
            sim.inject_over_temperature()
            await asyncio.sleep(0.3)
            with pytest.raises(AmplifierFault, match="over-temperature") as info:
                amp.check()
            assert info.value.code == 2
            with pytest.raises(AmplifierFault, match="still present"):
                await amp.reset_fault()  # coil still hot
            sim.model.temperature_c = 30.0
            await amp.reset_fault()
            await amp.enable()
            assert sim.model.enabled

    run(go())


def test_modbus_exception_responses(sim):
    async def go():
        async with ShakerAmplifier("127.0.0.1", sim.port, **FAST) as amp:
            sim.inject("exception", count=2, code=4)
            with pytest.raises(DeviceError, match="exception 4"):
                await amp.read_status()
            with pytest.raises(DeviceError, match="exception 4"):
                await amp.enable()
            await amp.enable()  # the device answers normally again
            assert sim.model.enabled
            sim.inject("exception", count=50)  # busy on the way out: safe_state must still end

    # With 50 busy answers queued, exit cannot confirm the disable by Modbus; it says so.
    with pytest.raises(InstrumentError, match="could not confirm"):
        run(go())
    # The amplifier's comms watchdog is the last line of defence: no valid request -> trip.
    deadline = time.monotonic() + 3.0
    while sim.model.enabled and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not sim.model.enabled and sim.model.fault_code == AMP_FAULT_COMMS_WATCHDOG


def test_dropped_connection_is_detected_and_recovered(sim):
    async def go():
        async with ShakerAmplifier("127.0.0.1", sim.port, **FAST) as amp:
            await amp.enable()
            sim.inject("drop")
            await asyncio.sleep(0.02)
            with pytest.raises(ConnectionLost):
                await amp.read_status()
            # pymodbus reconnects by itself; the driver can carry on.
            for _ in range(40):
                try:
                    st = await amp.read_status()
                    break
                except ConnectionLost:
                    await asyncio.sleep(0.05)
            assert st.enabled
            sim.inject("drop")  # and drops again just before exit: safe_state reconnects
        assert not sim.model.enabled

    run(go())


def test_a_late_reply_is_waited_for_and_a_silent_amplifier_is_no_reply(sim):
    """One reply later than the timeout (a busy controller or network, as a loaded CI machine
    once produced) is not a lost instrument: the driver resends with the same transaction id
    and takes the late reply. Replies later than every try are "no reply", not "link down"."""
    t = FAST["timeout_s"]
    # The stalled controller's heartbeat is not the point, and a monitor poll would take a delay.
    patient = dict(FAST, heartbeat_timeout_s=10 * t, poll_interval_s=30.0)

    async def go():
        async with ShakerAmplifier("127.0.0.1", sim.port, **patient) as amp:
            assert amp.retries == 1
            n0 = sim.requests
            sim.inject("delay", count=1, delay_s=1.5 * t)
            assert (await amp.read_status()).interlock_closed
            # The resend is counted when the server's loop, free again after the late reply, reads
            # it: a millisecond or so after that reply can reach us (CI once saw 1 here).
            deadline = time.monotonic() + 2.0
            while sim.requests - n0 < 2 and time.monotonic() < deadline:
                await asyncio.sleep(0.01)
            assert sim.requests - n0 == 2  # sent again after t, answered
            assert (await amp.read_status()).interlock_closed  # the stray second reply is skipped
            sim.inject("delay", count=2, delay_s=3 * t)  # each try answered after both timed out
            with pytest.raises(InstrumentTimeout, match="no valid Modbus reply in 2 tries of 0.3 s"):
                await amp.read_status()
            await asyncio.sleep(2 * 3 * t)  # the controller catches up: the link was never dropped
            assert (await amp.read_status()).interlock_closed
        assert not sim.model.enabled

    run(go())


def test_the_simulator_delays_and_counts_a_write_once(sim):
    """pymodbus calls the simulator's action twice for a write (the write, then the read-back
    its reply echoes): ``inject("delay", count=1)`` answered a write 2 * delay_s late (and
    count=2 made one reply late, not two), and ``requests`` counted each write twice."""
    async def go():
        async with ShakerAmplifier("127.0.0.1", sim.port, **dict(FAST, timeout_s=1.0, poll_interval_s=30.0)) as amp:
            n0 = sim.requests
            await amp._write(REG["GAIN"], 250)
            assert sim.requests - n0 == 1
            sim.inject("delay", count=2, delay_s=0.2)
            for value in (300, 350):
                t0 = time.monotonic()
                await amp._write(REG["GAIN"], value)
                assert 0.2 <= time.monotonic() - t0 < 0.35
            t0 = time.monotonic()
            await amp._write(REG["GAIN"], 400)
            assert time.monotonic() - t0 < 0.1 and sim.model.gain_v_per_v == 4.0

    run(go())


# A controller busy for longer than a call waits (two tries of timeout_s): every request in
# these tests is answered LATE_S late, the two tries of one call among them. The monitor does
# not poll (a poll would take a delay), and the amplifier's own watchdog is off (its stalled
# controller would see no request for over a second and trip).
LATE_S = 0.7
PATIENT = dict(FAST, heartbeat_timeout_s=30.0, poll_interval_s=30.0, watchdog_ms=0)


def test_commands_after_late_replies_are_answered_with_their_own_values(sim):
    """A call whose requests are answered after it gave up leaves the amplifier busy with
    them; the next command, sent at once, went in behind them and was dropped unanswered by
    the busy server ("no valid Modbus reply"). Now the driver waits until the amplifier
    answers a probe, then sends it: the gain reads back as set (not the late replies' old
    gain), and enable/disable reach the amplifier."""
    async def go():
        async with ShakerAmplifier("127.0.0.1", sim.port, **PATIENT) as amp:
            await amp.set_gain(2.0)
            await amp.enable()
            sim.inject("delay", count=2, delay_s=LATE_S)  # the gain read that starts the ramp, and its resend
            with pytest.raises(InstrumentTimeout, match="no valid Modbus reply in 2 tries"):
                await amp.set_gain(3.0)
            await amp.set_gain(4.0)  # at once: the late replies (gain 2 V/V) are still to come
            assert sim.model.gain_v_per_v == 4.0 and (await amp._read(REG["GAIN"], 1)) == [400]
            await amp.disable()
            assert not sim.model.enabled and not (await amp.read_status()).enabled
            await amp.enable()
            assert sim.model.enabled and (await amp.read_status()).enabled
        assert not sim.model.enabled

    run(go())


def test_close_confirms_the_safe_state_after_late_replies(sim):
    """close() whose ENABLE = 0 is answered late (its resend too): its second attempt went
    in behind them and was dropped or answered after it gave up, and close() raised "could
    not confirm the amplifier disabled" just as the amplifier could answer again. The second
    attempt now waits for the amplifier to answer (up to resync_s), then disables it and
    reads it back."""
    amp = SyncShakerAmplifier("127.0.0.1", sim.port, **PATIENT)
    try:
        amp.set_gain(2.0)
        amp.enable()
        assert sim.model.enabled
        sim.inject("delay", count=2, delay_s=LATE_S)
        t0 = time.monotonic()
        amp.close()
        assert time.monotonic() - t0 < 2 * LATE_S + 2 * FAST["timeout_s"] + 0.5  # waited, not more
    finally:
        amp.close()
    assert not sim.model.enabled and not sim.model.fault_code


def test_an_amplifier_still_silent_after_a_late_reply_is_lost_then_recovers(sim):
    """Waiting for the amplifier to answer again has its limit: silent for resync_s (two
    unanswered calls' time by default) it is reported lost, with what the driver waited for.
    The link stays up, and once the amplifier answers again so does the driver."""
    async def go():
        async with ShakerAmplifier("127.0.0.1", sim.port, **PATIENT) as amp:
            assert amp.resync_s == 2 * 2 * FAST["timeout_s"]
            sim.inject("delay", count=1, delay_s=2.5)
            with pytest.raises(InstrumentTimeout, match="no valid Modbus reply in 2 tries"):
                await amp.read_status()
            t0 = time.monotonic()
            with pytest.raises(InstrumentTimeout, match=r"no Modbus reply for 1\.\d s after a request went unanswered"):
                await amp.read_status()
            assert amp.resync_s <= time.monotonic() - t0 < amp.resync_s + 0.3
            await asyncio.sleep(2.5 - 0.6 - amp.resync_s + 0.1)  # the controller catches up
            assert (await amp.read_status()).interlock_closed
        assert not sim.model.enabled

    run(go())


def test_lost_heartbeat_is_a_fault(sim):
    async def go():
        async with ShakerAmplifier("127.0.0.1", sim.port, **FAST) as amp:
            await amp.enable()
            sim.inject("heartbeat_stall")
            await asyncio.sleep(0.8)
            with pytest.raises(HeartbeatLost, match="heartbeat stopped"):
                amp.check()
            assert not sim.model.enabled  # the driver disabled it
            with pytest.raises(HeartbeatLost):
                await amp.enable()

    run(go())


def test_unreachable_amplifier():
    async def go():
        with pytest.raises(ConnectionLost, match="cannot connect"):
            await ShakerAmplifier("127.0.0.1", 1, **FAST).connect()

    run(go())


@contextlib.contextmanager
def _loopback_listener(handle):
    """Something other than an amplifier at a loopback address: each connection it accepts
    goes to ``handle(conn)``. Yields its port."""
    srv = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def serve() -> None:
        srv.settimeout(0.1)
        while not stop.is_set():
            try:
                conn, _ = srv.accept()
            except TimeoutError:
                continue
            handle(conn)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield srv.getsockname()[1]
    finally:
        stop.set()
        thread.join(5)
        srv.close()


def test_something_else_at_the_amplifiers_address_is_no_modbus_reply():
    """A web server (or a network's interceptor) at the setup's address accepts the
    connection and answers every request with HTTP. The blocking facade says so - no valid
    Modbus reply - rather than blaming its own deadline for a call that ended at once."""
    def answer_http(conn) -> None:
        with conn:
            conn.settimeout(2.0)
            try:
                while conn.recv(256):
                    conn.sendall(b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n")
            except OSError:
                pass

    with _loopback_listener(answer_http) as port, \
            pytest.raises(InstrumentTimeout, match="no valid Modbus reply in 2 tries of 0.3 s"):
        SyncShakerAmplifier("127.0.0.1", port, **FAST)


def test_a_peer_that_drops_the_link_leaves_no_library_task_behind(caplog, capfd):
    """A listener that accepts and closes at once: pymodbus reconnects, and the failed
    connect left that task pending in the facade's loop when it closed ("Task was destroyed
    but it is pending!" on stderr after `ssidlab check`'s table, where nothing else belongs)."""
    import gc

    with _loopback_listener(lambda conn: conn.close()) as port, pytest.raises(InstrumentError):
        SyncShakerAmplifier("127.0.0.1", port, **FAST)
    gc.collect()  # where a task still pending with its closed loop says so
    said = caplog.text + capfd.readouterr().err
    assert "Task was destroyed" not in said, said


def test_sync_facade(sim):
    with SyncShakerAmplifier("127.0.0.1", sim.port, **FAST) as amp:
        amp.set_gain(3.0)
        amp.enable()
        assert sim.model.enabled and amp.read_status().enabled
        sim.set_interlock(False)
        time.sleep(0.3)
        with pytest.raises(InterlockOpen):
            amp.check()
    assert not sim.model.enabled


def test_a_gain_the_amplifier_limits_is_an_error():
    """An amplifier that acknowledges a gain and clamps it (here to 20 V/V): set_gain(40)
    returned as if set, and the drive was half what the run counted on."""

    class Clamping(SimAmplifier):
        def _write(self, addr, value):
            if addr == amp_sim.REG["GAIN"]:
                value = min(value, 2000)
            return super()._write(addr, value)

    host = AmpServerThread()
    clamping = Clamping(AmplifierModel(), host).start()
    try:
        with SyncShakerAmplifier("127.0.0.1", clamping.port, **FAST) as amp:
            amp.set_gain(10.0)
            with pytest.raises(DeviceError, match="gain set to 40 V/V reads back 20 V/V"):
                amp.set_gain(40.0)
    finally:
        clamping.stop()
        host.stop()


def test_an_amplifier_that_stays_enabled_is_reported_with_why():
    """An amplifier that acknowledges ENABLE = 0 and stays on (a stuck contactor): the safe
    state's error said "could not confirm the amplifier disabled: None"."""

    class StuckOn(SimAmplifier):
        def _write(self, addr, value):
            if addr == amp_sim.REG["ENABLE"] and value == 0:
                return None  # acknowledged, not done
            return super()._write(addr, value)

    host = AmpServerThread()
    stuck = StuckOn(AmplifierModel(), host).start()
    try:
        amp = SyncShakerAmplifier("127.0.0.1", stuck.port, **FAST)
        amp.enable()
        with pytest.raises(InstrumentError, match="acknowledged ENABLE = 0 but still reads enabled"):
            amp.close()
    finally:
        stuck.stop()
        host.stop()


def test_a_ctrl_c_during_close_lets_the_safe_state_finish(sim, ctrl_c_after):
    """close() waits for the amplifier to confirm it is disabled. A Ctrl-C (Python's own
    handler, as in a user's script) landing in that wait cancelled the safe state and stopped
    the event loop: the amplifier stayed enabled (its own watchdog off here), and a second
    close() had no loop to do it with. The interrupt is now raised once close() has ended."""
    amp = SyncShakerAmplifier("127.0.0.1", sim.port, **{**FAST, "heartbeat_timeout_s": 5.0}, watchdog_ms=0)
    amp.set_gain(5.0)
    amp.enable()
    sim.inject("delay", count=1, delay_s=1.0)  # the next request (a monitor poll) answered 1 s late
    time.sleep(0.12)  # that poll is in flight: close()'s disable waits behind it
    ctrl_c_after(0.2)
    try:
        with pytest.raises(KeyboardInterrupt):
            amp.close()
            time.sleep(2.0)  # the old code: the interrupt comes in close(), or here at the latest
    finally:
        amp.close()
    assert not sim.model.enabled
    assert not any(t.is_alive() and t.name.startswith("amp-") for t in threading.enumerate())


def test_close_ends_the_monitor_when_its_cancel_lands_as_a_poll_finishes():
    """Python 3.11's asyncio.wait_for returns the inner result and drops a cancel that lands in
    the loop iteration where that result has just arrived (gh-86296). The monitor then polled on,
    close() waited on it, and the release after a Ctrl-C hung 15 s with a thread dump (QA: 1 in
    146 interrupted runs). The window is one event-loop iteration, which no transport places
    on demand: a stand-in client holds the first poll's reply until the cancel is queued
    right behind it."""
    import types

    async def scenario() -> tuple[bool, bool]:
        loop = asyncio.get_running_loop()
        amp = ShakerAmplifier(name="ampX", poll_interval_s=0.01)
        reply = loop.create_future()
        polls = 0

        class HeldReplyClient:
            connected = True

            def read_holding_registers(self, address, count, device_id):
                nonlocal polls
                polls += 1

                async def request():
                    if polls == 1:
                        await reply  # the first poll waits for its reply
                    return types.SimpleNamespace(registers=[3, 0, 0, 0, 250, polls, 1], isError=lambda: False)
                return request()

            def close(self):
                pass

        amp.client = HeldReplyClient()
        amp._monitor_task = loop.create_task(amp._monitor())
        while not polls:
            await asyncio.sleep(0.005)
        await asyncio.sleep(0.005)
        reply.set_result(None)  # the request finishes in the next iteration ...
        closing = loop.create_task(amp.close(safe_state=False))  # ... and close() cancels in the same one
        done, _ = await asyncio.wait([closing], timeout=2.0)
        monitor_running = amp._monitor_task is not None and not amp._monitor_task.done()
        for task in asyncio.all_tasks() - {asyncio.current_task()}:
            task.cancel()
        return bool(done), monitor_running

    closed, monitor_running = asyncio.run(scenario())
    assert closed and not monitor_running


# A user's own script: the simulated amplifier answers one request late, so the call fails
# ("late") or is interrupted by Ctrl-C ("interrupted") and its reply comes after it. Run as
# a process of its own: under pytest the root logger has pytest's handlers, and pymodbus's
# lines would never reach Python's last-resort handler, the one that wrote them to stderr.
USER_SCRIPT = """
import _thread, logging, sys, threading, time
from drivers.amplifier import SyncShakerAmplifier
from drivers.errors import InstrumentError
from sim_devices.amp_sim import AmpServerThread, SimAmplifier
from sim_devices.components import AmplifierModel

mode, with_logging = sys.argv[1], sys.argv[2] == "logging"
if with_logging:
    logging.basicConfig(level=logging.WARNING)
host = AmpServerThread()
sim = SimAmplifier(AmplifierModel(), host).start()
amp = SyncShakerAmplifier("127.0.0.1", sim.port, timeout_s=0.2, retries=1, poll_interval_s=5.0,
                          heartbeat_timeout_s=30.0)
sim.inject("delay", count=1, delay_s=0.6)
if mode == "interrupted":
    threading.Timer(0.1, _thread.interrupt_main).start()
try:
    amp.read_status()
except InstrumentError as exc:
    print(f"{type(exc).__name__}: {exc} | cause: {exc.__cause__}")
except KeyboardInterrupt:
    print("interrupted")
time.sleep(0.8)  # the late reply comes in meanwhile
amp.read_status()
amp.close()
sim.stop()
host.stop()
"""


def _user_script(mode: str, logging_on: bool) -> subprocess.CompletedProcess:
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")])))
    return subprocess.run([sys.executable, "-c", USER_SCRIPT, mode, "logging" if logging_on else "plain"],
                          capture_output=True, text=True, env=env, timeout=60)


@pytest.mark.parametrize("mode", ["late", "interrupted"])
def test_pymodbus_writes_nothing_to_a_user_scripts_stderr(mode):
    """A failed or interrupted amplifier call leaves the user's stderr clean: before, pymodbus
    wrote "No response received ..." or "received pdu without a corresponding request" there,
    each with a dump of its last 20 frames (">>>>> send: 0x0 0x1 ..."). The driver's error
    still says what failed and carries pymodbus's exception as its cause."""
    p = _user_script(mode, logging_on=False)
    assert p.returncode == 0, p.stderr
    assert p.stderr == ""
    if mode == "late":
        assert p.stdout.startswith("InstrumentTimeout: amp: no valid Modbus reply in 2 tries of 0.2 s")
        assert "| cause: Modbus Error: [Input/Output] No response received after 1 retries" in p.stdout
    else:
        assert p.stdout.strip() == "interrupted"


def test_pymodbus_lines_show_when_the_application_enables_logging():
    """The driver holds pymodbus's log back only from Python's last resort, not from the
    application: with logging configured, its lines are there as before."""
    p = _user_script("late", logging_on=True)
    assert p.returncode == 0, p.stderr
    assert "No response received after 1 retries" in p.stderr
