"""Connection check: is every instrument of a setup there, and who is it?

What an engineer does before a run: each generator, amplifier and the DAQ front end is
opened on its own (one dead instrument must not hide the state of the others), asked who it
is and - for an amplifier - for its interlock and fault state, then released in the safe
state. Nothing is driven. Beyond "it answered", each is judged ready or not for the run the
setup describes: an amplifier with its interlock open or a fault latched refuses to enable,
and a DAQ with fewer inputs than the setup's channels use refuses to configure, so the run
would stop at its start. ``ssidlab check`` prints the result; ``ssidlab tui`` shows it on its
Setup tab (F4).
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.amplifier import modbus_log_held_back
from drivers.amplifier_sync import SyncShakerAmplifier
from drivers.daq import CanFdDaq, firmware_text
from drivers.errors import AmplifierFault, InstrumentError
from drivers.siggen import SignalGenerator

from .safety import describe_fault
from .setup import TestSetup

__all__ = ["InstrumentState", "check_instruments", "check_lab", "check_verdict"]


@dataclass
class InstrumentState:
    """One instrument: ``kind`` generator / amplifier / daq; ``ok`` if it answered.

    ``not_ready`` says why a run could not start from the state it answered in (empty when
    it could)."""

    name: str
    kind: str
    address: str
    ok: bool
    identity: str = ""
    detail: str = ""  # amplifier: interlock and fault; a failure: why
    not_ready: str = ""

    @property
    def ready(self) -> bool:
        return self.ok and not self.not_ready

    @property
    def state(self) -> str:
        """``ok: <detail>``, ``NOT READY: <why>`` or ``NO ANSWER: <why>``."""
        if not self.ok:
            return f"NO ANSWER: {self.detail}"
        return f"NOT READY: {self.not_ready}" if self.not_ready else f"ok: {self.detail}"


def _generator(g, timeout_s: float) -> InstrumentState:
    with SignalGenerator(g.url, name=g.name, timeout_s=min(g.timeout_s, timeout_s)) as gen:
        on = [ch for ch in gen.channels if gen.is_on(ch)]
        detail = f"outputs on: {on}" if on else "outputs off"
        return InstrumentState(g.name, "generator", g.url, True, gen.idn, detail)


def _amplifier(a, timeout_s: float, reset_faults: bool = False) -> InstrumentState:
    with SyncShakerAmplifier(a.host, a.port, device_id=a.device_id, name=a.name, timeout_s=timeout_s) as amp:
        st = amp.read_status()
        reset = refused = ""
        if reset_faults and st.fault_latched:
            # Clearing a latch switches nothing on (the output stays disabled); the amplifier
            # itself refuses while the cause is present (interlock open, coil still hot).
            try:
                amp.reset_fault()
                reset = f"latched fault ({st.fault_name}) reset, "
            except AmplifierFault:
                refused = f"latched fault ({st.fault_name}) not reset: its cause is still present"
            st = amp.read_status()
        detail = (f"{reset}interlock {'closed' if st.interlock_closed else 'OPEN'}, "
                  f"{'enabled' if st.enabled else 'disabled'}, "
                  f"{'fault: ' + st.fault_name if st.fault_latched else 'no fault'}")
        # What ShakerAmplifier.enable refuses: the run would stop before its first line. An
        # open interlock latches its own fault, which needs a reset once it is closed again.
        if not st.interlock_closed:
            why = "interlock open (door or E-stop)"
        elif st.fault_latched:
            why = f"fault latched since a trip ({st.fault_name}): reset it once its cause is gone"
        else:
            why = ""
        why = "; ".join(w for w in (why, refused) if w)
        return InstrumentState(a.name, "amplifier", f"{a.host}:{a.port}", True,
                               f"Modbus unit {a.device_id}, serial {amp.amp.serial}", detail, why)


def _daq(setup: TestSetup, timeout_s: float) -> InstrumentState:
    d = setup.daq
    with CanFdDaq(interface=d.interface, channel=d.channel, nominal_bitrate=d.nominal_bitrate,
                  data_bitrate=d.data_bitrate, timeout_s=timeout_s) as daq:
        ident = daq.identity
        text = f"serial {ident.get('serial', '?')}, firmware {firmware_text(ident.get('fw_version', '?'))}"
        beyond = [c for c in setup.channels if c.input >= daq.n_inputs]
        why = (f"{daq.n_inputs} inputs (0..{daq.n_inputs - 1}), the setup uses "
               + ", ".join(f"{c.input} ({c.name!r})" for c in beyond)) if beyond else ""
        return InstrumentState("daq", "daq", f"{d.interface}:{d.channel}", True, text,
                               f"{ident.get('n_inputs', '?')} inputs", why)


def check_instruments(setup: TestSetup, timeout_s: float = 1.0, reset_faults: bool = False) -> list[InstrumentState]:
    """Open, identify and release every instrument of ``setup``, each on its own.

    Returns one :class:`InstrumentState` per generator, amplifier and the DAQ, in that
    order; an instrument that does not answer has ``ok`` False and ``detail`` saying why
    (never raises for an instrument fault). With ``reset_faults``, an amplifier's latched
    fault is reset first (a deliberate act of the engineer: only once its cause is gone,
    which the amplifier checks itself); the state is read after it.
    """
    with modbus_log_held_back():  # the result says what failed
        return _check_each(setup, timeout_s, reset_faults)


def _check_each(setup: TestSetup, timeout_s: float, reset_faults: bool) -> list[InstrumentState]:
    out: list[InstrumentState] = []
    jobs = ([(g.name, "generator", g.url, lambda g=g: _generator(g, timeout_s)) for g in setup.generators]
            + [(a.name, "amplifier", f"{a.host}:{a.port}", lambda a=a: _amplifier(a, timeout_s, reset_faults))
               for a in setup.amplifiers]
            + [("daq", "daq", f"{setup.daq.interface}:{setup.daq.channel}", lambda: _daq(setup, timeout_s))])
    for name, kind, address, job in jobs:
        try:
            out.append(job())
        except (InstrumentError, OSError, ValueError) as exc:
            # pyserial, sockets and python-can raise their own types for a missing port or
            # interface; every one of them means "not there", said in one line.
            out.append(InstrumentState(name, kind, address, False, "", describe_fault(exc)))
        except Exception as exc:  # noqa: BLE001 -- e.g. can.CanError: same meaning, one line
            out.append(InstrumentState(name, kind, address, False, "", f"{type(exc).__name__}: {exc}"))
    return out


def check_lab(setup: TestSetup, sim: bool = False, timeout_s: float = 1.0,
              reset_faults: bool = False) -> list[InstrumentState]:
    """:func:`check_instruments` on the lab of ``setup``; with ``sim``, on the simulated lab,
    started on loopback for the check and stopped after it (a check never leaves devices
    running)."""
    if not sim:
        return check_instruments(setup, timeout_s, reset_faults)
    from .simlab import start_sim_lab

    handle, inst = start_sim_lab(setup)
    try:
        return check_instruments(inst, timeout_s, reset_faults)
    finally:
        handle.stop()


def check_verdict(states: list[InstrumentState]) -> str:
    """One line: whether every instrument answered and is ready for the run, and if not,
    which are not and why."""
    silent = [s.name for s in states if not s.ok]
    waiting = [f"{s.name}: {s.not_ready}" for s in states if s.ok and s.not_ready]
    if not silent and not waiting:
        return f"instruments: all {len(states)} answered and ready"
    said = [f"{len(silent)} of {len(states)} did not answer ({', '.join(silent)})"] if silent else []
    if waiting:
        said.append(f"not ready: {'; '.join(waiting)}")
    return "instruments: " + "; ".join(said)
