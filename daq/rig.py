"""The rig: every instrument of a test behind one small interface.

The run logic (stepped sine, random) talks only to a :class:`Rig`. :class:`InstrumentRig`
is the real one: it opens the drivers named in the setup (``drivers.siggen``,
``drivers.amplifier``, ``drivers.daq``) and knows which generator output and amplifier
feed each shaker. Benchmarks may implement the same interface on a physics world
directly (``bench/sweep_time.py``); the acquisition code never imports the simulator.

Acquisition is *chunked*: every :meth:`Rig.acquire` starts the DAQ for exactly ``n``
scans and reads them, and the rig's sample clock (:attr:`Rig.clock`) counts the scans
acquired so far. Successive chunks are treated as one continuous record. That holds for
the simulated lab, whose world only advances while the DAQ acquires; a real front end
would need continuous streaming instead (not implemented, see ``docs/acquisition.md``).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import logging

import numpy as np

from drivers.amplifier import MODEL_ID
from drivers.amplifier_sync import SyncShakerAmplifier
from drivers.daq import CanFdDaq, DaqChannel
from drivers.errors import AmplifierFault, BusCapacityError, HeartbeatLost, InstrumentError, InterlockOpen
from drivers.siggen import SignalGenerator
from ssid.errors import InputError

from .setup import TestSetup

__all__ = ["InstrumentRig", "Rig"]

log = logging.getLogger(__name__)


class Rig:
    """Interface of the instruments as the run logic sees them (see the module docstring).

    Attributes
    ----------
    fs_hz : float
        Sample rate.
    passband_hz : float
        The DAQ's alias-free band (its anti-alias filter's passband edge).
    names : list of str
        Channel names, in the order of the rows of :meth:`acquire`.
    clock : int
        Scans acquired since the rig was opened (the record's time base).
    """

    fs_hz: float
    passband_hz: float
    names: list[str]
    clock: int = 0

    def prepare(self) -> None:
        """Amplifier gains set and amplifiers enabled, generator outputs off."""
        raise NotImplementedError

    def sine(self, shaker: int, freq_hz: float, vpp: float) -> None:
        """Shaker ``shaker`` driven by a sine (output switched on and ramped, or re-levelled)."""
        raise NotImplementedError

    def noise(self, shaker: int, vpp: float, bandwidth_hz: float) -> None:
        """Continuous Gaussian noise on the shaker's generator output (NOIS, sigma = Vpp/6),
        flat up to ``bandwidth_hz``."""
        raise NotImplementedError

    def arb(self, shaker: int, samples: np.ndarray, vpp: float) -> float:
        """Play ``samples`` (one period, at the DAQ rate) repeatedly; returns volts per unit
        sample (the generator scales the waveform to its +-1 range)."""
        raise NotImplementedError

    def drive_off(self, shaker: int) -> None:
        """Ramp the shaker's drive down and switch its output off."""
        raise NotImplementedError

    def acquire(self, n: int) -> np.ndarray:
        """The next ``n`` scans (n_ch, n) in engineering units.

        Raises :class:`~drivers.errors.SensorOverload` (naming the channels) when a channel
        went over its input range: clipped samples are never returned as data. The clock
        counts the scans either way."""
        raise NotImplementedError

    def check(self) -> None:
        """Raise the fault an instrument reported (amplifier trip, lost heartbeat, ...)."""

    def line_check(self) -> None:
        """Thorough check before each line: read every amplifier's status now."""

    def identities(self) -> dict:
        return {}

    def status(self) -> dict:
        """The instruments' state as last read (for display): per amplifier ``enabled``,
        ``interlock_closed``, ``fault`` (``""`` when none)."""
        return {}

    def safe_state(self) -> list[str]:
        """Every output off, every amplifier disabled, acquisition stopped.

        Returns the safe state's problems, ``"<instrument>: <why>"``: a generator or an
        amplifier that did not confirm it is off. A DAQ that does not confirm its stop is
        logged, not returned: no drive reaches a shaker through it.
        """
        raise NotImplementedError

    def close(self) -> None:
        """Safe state, then release every instrument."""


class InstrumentRig(Rig):
    """The instruments of a setup, through the drivers.

    Parameters
    ----------
    setup : TestSetup
        Addresses, channels, shakers and limits.
    """

    def __init__(self, setup: TestSetup) -> None:
        self.setup = setup
        self.fs_hz = float(setup.daq.sample_rate_hz)
        self.passband_hz = setup.daq.passband_hz
        self.names = [c.name for c in setup.channels]
        self.clock = 0
        self.gens: dict[str, SignalGenerator] = {}
        self.amps: dict[str, SyncShakerAmplifier] = {}
        self.daq: CanFdDaq | None = None
        self._stack = contextlib.ExitStack()
        self._function: dict[int, str] = {}
        self._beats: dict[str, tuple[int, float]] = {}
        self._status: dict[str, dict] = {}
        # A safe state was attempted since the last command that drives or starts anything
        # (a shaker's instruments, the DAQ).
        self._safe_state_tried = False
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    def _open(self) -> None:
        s = self.setup
        max_vpp = s.limits.max_drive_vpp
        for g in s.generators:
            self.gens[g.name] = self._stack.enter_context(SignalGenerator(
                g.url, name=g.name, timeout_s=g.timeout_s, max_vpp=min(g.max_vpp, max_vpp),
                ramp_time_s=g.ramp_time_s, ramp_step_s=max(g.ramp_time_s / 10, 0.005)))
        for a in s.amplifiers:
            self.amps[a.name] = self._stack.enter_context(SyncShakerAmplifier(
                a.host, a.port, device_id=a.device_id, name=a.name, poll_interval_s=0.1))
        self.daq = self._stack.enter_context(CanFdDaq(
            interface=s.daq.interface, channel=s.daq.channel, nominal_bitrate=s.daq.nominal_bitrate,
            data_bitrate=s.daq.data_bitrate, timeout_s=1.0, stream_timeout_s=2.0))
        chans = [DaqChannel(c.name, c.input, "acceleration" if c.quantity == "acceleration" else "force",
                            c.sensitivity_mv_per_unit, c.range_volt, c.coupling) for c in s.channels]
        try:
            self.daq.configure(chans, s.daq.sample_rate_hz)
        except BusCapacityError as exc:
            raise InputError(f"{s.source}: [daq] sample_rate_hz: {exc}") from None

    def _shaker(self, j: int) -> tuple[SignalGenerator, int, SyncShakerAmplifier]:
        self._safe_state_tried = False
        sh = self.setup.shakers[j]
        return self.gens[sh.generator], sh.channel, self.amps[sh.amplifier]

    def prepare(self) -> None:
        for j, sh in enumerate(self.setup.shakers):
            gen, ch, amp = self._shaker(j)
            gen.output_off(ch, ramp_time_s=0.0)
            spec = next(a for a in self.setup.amplifiers if a.name == sh.amplifier)
            amp.set_gain(spec.gain_v_per_v)
            amp.enable()

    def _ensure(self, j: int, function: str) -> None:
        if self._function.get(j) != function:
            gen, ch, _ = self._shaker(j)
            if gen.is_on(ch):
                gen.output_off(ch)
            gen.set_function(ch, function)
            self._function[j] = function

    def sine(self, shaker: int, freq_hz: float, vpp: float) -> None:
        self._ensure(shaker, "SIN")
        gen, ch, _ = self._shaker(shaker)
        gen.set_frequency(ch, freq_hz)
        if gen.is_on(ch):
            gen.set_amplitude(ch, vpp)
        else:
            gen.output_on(ch, vpp)

    def noise(self, shaker: int, vpp: float, bandwidth_hz: float) -> None:
        self._ensure(shaker, "NOIS")
        gen, ch, _ = self._shaker(shaker)
        gen.set_noise_bandwidth(ch, bandwidth_hz)
        gen.output_on(ch, vpp)

    def arb(self, shaker: int, samples: np.ndarray, vpp: float) -> float:
        gen, ch, _ = self._shaker(shaker)
        if gen.is_on(ch):
            gen.output_off(ch)
        scale = gen.upload_arb(ch, samples, self.fs_hz, name=f"SSID{shaker}")
        self._function[shaker] = "ARB"
        gen.output_on(ch, vpp)
        return 0.5 * vpp * scale

    def drive_off(self, shaker: int) -> None:
        gen, ch, _ = self._shaker(shaker)
        gen.output_off(ch)

    def acquire(self, n: int) -> np.ndarray:
        self.check()
        self._safe_state_tried = False
        self.daq.start(n)
        try:
            blk = self.daq.read(n, timeout_s=n / self.fs_hz + 10.0)
        finally:
            self.clock += n  # an over-range raises after the scans were taken: they were test time
        self.check()
        return blk.data

    def check(self) -> None:
        for amp in self.amps.values():
            amp.check()

    def line_check(self) -> None:
        """Amplifier status read now (the monitor polls too, but a fast simulated run can
        finish a line between two polls): a trip or a stalled heartbeat stops the run."""
        import time

        for name, amp in self.amps.items():
            amp.check()
            st = amp.read_status()
            self._status[name] = {"enabled": st.enabled, "interlock_closed": st.interlock_closed,
                                  "fault": st.fault_name if st.fault_latched else ""}
            if not st.enabled or st.fault_latched:
                # The driver's monitor may have disabled it for a reason of its own (a stalled
                # heartbeat) between the check above and this read: that reason, not the
                # status's "tripped (none)" (a fault run under load said so).
                amp.check()
                if st.fault_code == 1 or not st.interlock_closed:
                    raise InterlockOpen(f"{name}: interlock open (door or E-stop): amplifier disabled")
                raise AmplifierFault(f"{name}: amplifier tripped ({st.fault_name})", st.fault_code)
            now = time.monotonic()
            last = self._beats.get(name)
            if last is None or st.heartbeat != last[0]:
                self._beats[name] = (st.heartbeat, now)
            elif now - last[1] > amp.amp.heartbeat_timeout_s:
                raise HeartbeatLost(f"{name}: heartbeat stopped at {st.heartbeat} for {now - last[1]:.1f} s")

    def identities(self) -> dict:
        out = {"generators": {k: g.idn for k, g in self.gens.items()},
               "amplifiers": {k: f"model 0x{MODEL_ID:04X} serial {a.amp.serial} at {a.amp.host}:{a.amp.port}"
                              for k, a in self.amps.items()},
               "daq": {k: (int(v) if isinstance(v, (int, np.integer)) else str(v))
                       for k, v in (self.daq.identity or {}).items()} if self.daq else {}}
        return out

    def status(self) -> dict:
        return {"amplifiers": {k: dict(v) for k, v in self._status.items()}}

    def safe_state(self) -> list[str]:
        """As :meth:`Rig.safe_state`, every instrument at once: one that does not answer
        holds up only its own attempt (its time-outs, a few seconds), so a frozen generator
        does not delay disabling the amplifiers, and a frozen lab's stop takes the slowest
        instrument's time instead of the sum of all (12-14 s seen)."""
        insts = [*self.gens.items(), *self.amps.items(), *([("daq", self.daq)] if self.daq else [])]
        with concurrent.futures.ThreadPoolExecutor(len(insts) or 1, thread_name_prefix="safe-state") as pool:
            tried = [(name, pool.submit(inst.safe_state)) for name, inst in insts]
        problems = []
        for name, done in tried:
            exc = done.exception()  # every instrument is tried whatever the others do
            if exc is None:
                continue
            if name == "daq":  # no drive reaches a shaker through it: logged, not returned
                log.error("acquisition stop not confirmed: %s", exc)
                continue
            msg = str(exc)  # the drivers' messages mostly name the instrument already
            problems.append(msg if msg.startswith(f"{name}:") else f"{name}: {msg}")
        self._function.clear()
        self._safe_state_tried = True
        for p in problems:
            log.error("safe state: %s", p)
        return problems

    def close(self) -> None:
        """Safe state, unless one was attempted since the last drive, then release every
        instrument without another: an instrument that did not answer that attempt would
        cost each further one its time-outs (with the drivers' own close trying again, a
        frozen lab took 30 s to let the command exit), and one that did confirm has been
        sent nothing since. That attempt's problems were reported by :meth:`safe_state`'s
        caller."""
        try:
            if not self._safe_state_tried:
                self.safe_state()
            for name, inst in [*self.gens.items(), *self.amps.items(), ("daq", self.daq)]:
                if inst is None:
                    continue
                try:
                    inst.release()
                except Exception as exc:  # every instrument is released whatever the others do
                    log.error("releasing %s: %s", name, exc)
        finally:
            try:
                self._stack.close()
            except InstrumentError as exc:
                log.error("closing instruments: %s", exc)
