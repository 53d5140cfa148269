"""Connection check: is every instrument of a setup there, and who is it?

What an engineer does before a run: each generator, amplifier and the DAQ front end is
opened on its own (one dead instrument must not hide the state of the others), asked who it
is and - for an amplifier - for its interlock and fault state, then released in the safe
state. Nothing is driven. ``ssidlab tui`` shows the result on its Setup tab.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from drivers.amplifier import SyncShakerAmplifier
from drivers.daq import CanFdDaq
from drivers.errors import InstrumentError
from drivers.siggen import SignalGenerator

from .safety import describe_fault
from .setup import TestSetup

__all__ = ["InstrumentState", "check_instruments"]


@dataclass
class InstrumentState:
    """One instrument: ``kind`` generator / amplifier / daq; ``ok`` if it answered."""

    name: str
    kind: str
    address: str
    ok: bool
    identity: str = ""
    detail: str = ""  # amplifier: interlock and fault; a failure: why


def _generator(g, timeout_s: float) -> InstrumentState:
    with SignalGenerator(g.url, name=g.name, timeout_s=min(g.timeout_s, timeout_s)) as gen:
        on = [ch for ch in gen.channels if gen.is_on(ch)]
        detail = f"outputs on: {on}" if on else "outputs off"
        return InstrumentState(g.name, "generator", g.url, True, gen.idn, detail)


def _amplifier(a, timeout_s: float) -> InstrumentState:
    with SyncShakerAmplifier(a.host, a.port, device_id=a.device_id, name=a.name, timeout_s=timeout_s) as amp:
        st = amp.read_status()
        detail = (f"interlock {'closed' if st.interlock_closed else 'OPEN'}, "
                  f"{'enabled' if st.enabled else 'disabled'}, "
                  f"{'fault: ' + st.fault_name if st.fault_latched else 'no fault'}")
        return InstrumentState(a.name, "amplifier", f"{a.host}:{a.port}", True,
                               f"Modbus unit {a.device_id}, serial {amp.amp.serial}", detail)


def _daq(setup: TestSetup, timeout_s: float) -> InstrumentState:
    d = setup.daq
    with CanFdDaq(interface=d.interface, channel=d.channel, nominal_bitrate=d.nominal_bitrate,
                  data_bitrate=d.data_bitrate, timeout_s=timeout_s) as daq:
        ident = daq.identity
        text = f"serial {ident.get('serial', '?')}, firmware {ident.get('fw_version', '?')}"
        return InstrumentState("daq", "daq", f"{d.interface}:{d.channel}", True, text,
                               f"{ident.get('n_inputs', '?')} inputs")


def check_instruments(setup: TestSetup, timeout_s: float = 1.0) -> list[InstrumentState]:
    """Open, identify and release every instrument of ``setup``, each on its own.

    Returns one :class:`InstrumentState` per generator, amplifier and the DAQ, in that
    order; an instrument that does not answer has ``ok`` False and ``detail`` saying why
    (never raises for an instrument fault).
    """
    # The result says what failed; the Modbus library's own error log lines would only be
    # noise on a terminal (and garble a full-screen UI), so they are held back meanwhile.
    quiet = logging.getLogger("pymodbus")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL + 1)
    try:
        return _check_each(setup, timeout_s)
    finally:
        quiet.setLevel(level)


def _check_each(setup: TestSetup, timeout_s: float) -> list[InstrumentState]:
    out: list[InstrumentState] = []
    jobs = ([(g.name, "generator", g.url, lambda g=g: _generator(g, timeout_s)) for g in setup.generators]
            + [(a.name, "amplifier", f"{a.host}:{a.port}", lambda a=a: _amplifier(a, timeout_s))
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
