"""What a resumed run may change in its setup, and the setup a resume runs with.

A run file's lines belong to the setup they were measured with, so a resume normally runs
with the stored setup. A few keys say nothing about what a measured line means, and a
resume is often the very moment they have to change:

* how the instruments are reached: the restart that a resume usually follows can renumber a
  USB serial port (``/dev/ttyUSB0`` -> ``/dev/ttyUSB1``), reassign an amplifier's address, or
  bring the CAN adapter up under another name; a generator that was slow to answer may need
  a longer ``timeout_s``;
* the DAQ input ranges: a range too small for the level stops a run (three over-ranges in a
  row), and a resume with the same range would meet the overload again; a range is no part of
  a channel's calibration, so the lines measured before stay good;
* the operator (a shift change) and where the files go (``[output]`` ``file``, ``uff``).

Addresses may change, but the instruments may not: after a restart two generators' serial
ports can swap, and the setup unchanged then drives one shaker with the other's signal (two
amplifiers' addresses likewise). :func:`instruments_not_the_same` compares who answers with
who answered in the run's last session.

Anything else - a calibration, the wiring, the excitation, the limits, the simulated world -
is refused: the lines on file and the schedule's decisions belong to the stored setup.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any, NamedTuple

from ssid.errors import InputError

from .setup import TestSetup, load_setup, parse_setup
from .storage import RunFile

__all__ = ["RESUMABLE_KEYS", "SetupChange", "instruments_not_the_same", "load_resume_setup", "range_changes",
           "setup_changes_on_resume", "setup_in_effect"]

#: The keys a resumed session may change, by table (see the module docstring).
RESUMABLE_KEYS: dict[str, tuple[str, ...]] = {
    "channels": ("range_volt",),
    "generators": ("url", "timeout_s"),
    "amplifiers": ("host", "port", "device_id"),
    "daq": ("interface", "channel"),
    "test": ("operator",),
    "output": ("file", "uff"),
}


class SetupChange(NamedTuple):
    """One key a resumed session changed. ``table`` is the TOML table (``"channels"``,
    ``"test"``), ``item`` the name of the array-of-tables entry (None for a plain table);
    ``old`` / ``new`` are the values in effect (defaults filled in; None for an optional key
    not set)."""

    table: str
    item: str | None
    key: str
    old: Any
    new: Any

    @property
    def where(self) -> str:
        return f"[{self.table}]" if self.item is None else f"[[{self.table}]] {self.item!r}"

    def __str__(self) -> str:
        return f"{self.where} {self.key} {self.old!r} -> {self.new!r}"


def setup_in_effect(rf: RunFile) -> TestSetup:
    """The setup the run's last session ran with: the one it was started with, or the one
    recorded by a session resumed with a changed setup. Each is checked against its hash."""
    for session in reversed(rf.meta.get("sessions", [])):
        if "setup_toml" in session:
            text, sha, where = session["setup_toml"], session.get("setup_sha256"), f"{rf.path}:/acq/meta_json"
            break
    else:
        text, sha, where = rf.setup_text, rf.setup_sha256, f"{rf.path}:/acq/setup_toml"
    setup = parse_setup(text, where)
    if setup.sha256 != sha:
        raise InputError(f"{where}: the stored setup does not match its SHA-256 (damaged run file)")
    return setup


def _without_resumable(doc: dict) -> dict:
    out = dict(doc)
    for table, keys in RESUMABLE_KEYS.items():
        if isinstance(doc.get(table), list):
            out[table] = [{k: v for k, v in t.items() if k not in keys} for t in doc[table]]
        elif isinstance(doc.get(table), dict):
            out[table] = {k: v for k, v in doc[table].items() if k not in keys}
    return out


def _first_difference(a: dict, b: dict) -> str:
    """The table where two parsed setups first differ, as a reader would find it."""
    where = next(k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k))
    x, y = a.get(where), b.get(where)
    if isinstance(x, list) and isinstance(y, list) and len(x) == len(y):
        i = next(i for i, (p, q) in enumerate(zip(x, y)) if p != q)
        name = x[i].get("name", i) if isinstance(x[i], dict) else i
        return f"[[{where}]] {name!r}"
    return f"[[{where}]]" if isinstance(x, list) or isinstance(y, list) else f"[{where}]"


def _values(setup: TestSetup, doc: dict, table: str) -> list[tuple[str | None, Any]]:
    """The items of ``table`` (name, values in effect): the parsed specs where the setup
    keeps them (their defaults filled in), else the TOML table itself."""
    specs = {"channels": setup.channels, "generators": setup.generators, "amplifiers": setup.amplifiers}
    if table in specs:
        return [(s.name, s) for s in specs[table]]
    return [(None, setup.daq if table == "daq" else doc.get(table, {}))]


def _value(item: Any, key: str) -> Any:
    return item.get(key) if isinstance(item, dict) else getattr(item, key)


def setup_changes_on_resume(stored: TestSetup, new: TestSetup, run: str | Path) -> list[SetupChange]:
    """What ``new`` changes from ``stored`` (the setup of the run file ``run``); empty when
    only comments or layout differ.

    Raises
    ------
    InputError
        ``new`` differs in a key outside :data:`RESUMABLE_KEYS`, naming the table.
    """
    if new.sha256 == stored.sha256:
        return []
    a, b = (tomllib.loads(s.text) for s in (stored, new))
    if _without_resumable(a) != _without_resumable(b):
        raise InputError(f"{new.source}: differs from the setup of the run {run} in "
                         f"{_first_difference(_without_resumable(a), _without_resumable(b))}; a resume may "
                         "change only the channels' range_volt, the instruments' addresses, the operator "
                         "and the output file names (daq.resume)")
    changes = []
    for table, keys in RESUMABLE_KEYS.items():
        # Every other key agrees, so the items pair up in order, names and all.
        for (item, old), (_, now) in zip(_values(stored, a, table), _values(new, b, table)):
            changes += [SetupChange(table, item, k, _value(old, k), _value(now, k))
                        for k in keys if _value(old, k) != _value(now, k)]
    return changes


def range_changes(changes: list[SetupChange]) -> dict[str, tuple[float, float]]:
    """The DAQ input ranges among ``changes``: ``{channel name: (old, new range_volt)}``."""
    return {c.item: (c.old, c.new) for c in changes if c.table == "channels" and c.key == "range_volt"}


def load_resume_setup(path: str | Path, setup_path: str | None = None) -> TestSetup:
    """The setup to resume the unfinished run file ``path`` with: ``setup_path`` when given
    (it may change only :data:`RESUMABLE_KEYS`), else the setup the run's last session ran
    with."""
    rf = RunFile.open(path)
    try:
        stored = setup_in_effect(rf)
    finally:
        rf.close()
    if setup_path is None:
        return stored
    setup = load_setup(setup_path)
    setup_changes_on_resume(stored, setup, path)
    return setup


def _maker_model_serial(idn: str) -> str:
    # *IDN? is "maker,model,serial,firmware": a firmware update is the same instrument.
    return ",".join(part.strip() for part in str(idn).split(",")[:3])


def _amplifier_serial(identity: str) -> str | None:
    # "model 0x5A01 serial 52001 at host:port"; the address may change, the serial not. Run
    # files from before the amplifiers reported a serial hold none: nothing to compare.
    found = re.search(r"\bserial (\S+)", str(identity))
    return found.group(1) if found else None


def instruments_not_the_same(before: dict, now: dict) -> list[str]:
    """The instruments that answer as others than in the run's last session, one line each.

    ``before`` / ``now``: identities as :meth:`daq.rig.Rig.identities` gives them (what
    ``meta_json`` records per session). Compared: each generator's maker, model and serial
    (``*IDN?``), each amplifier's serial and the DAQ front end's serial.
    """
    out = []
    old_gens = before.get("generators") or {}
    for name, idn in (now.get("generators") or {}).items():
        old = old_gens.get(name)
        if old is not None and _maker_model_serial(old) != _maker_model_serial(idn):
            out.append(f"{name} answers as {idn!r}, in the last session as {old!r}")
    old_amps = before.get("amplifiers") or {}
    for name, identity in (now.get("amplifiers") or {}).items():
        old_sn, new_sn = _amplifier_serial(old_amps.get(name, "")), _amplifier_serial(identity)
        if old_sn is not None and new_sn is not None and old_sn != new_sn:
            out.append(f"{name} answers with serial {new_sn}, in the last session with {old_sn}")
    old_sn, new_sn = ((d.get("daq") or {}).get("serial") for d in (before, now))
    if old_sn is not None and new_sn is not None and old_sn != new_sn:
        out.append(f"the DAQ answers with serial {new_sn}, in the last session with {old_sn}")
    return out
