"""What the Setup tab and the instrument table show of a test setup, as plain text and rows.

Pure functions of a loaded ``daq.setup.TestSetup`` (and of the run's ``instruments`` event),
kept out of the app so that the widgets only place them.
"""

from __future__ import annotations

import math

__all__ = ["channel_options", "channel_rows", "checked_instrument_rows", "configured_instrument_rows",
           "describe_setup", "instruments_in_use_rows", "pair_options", "same_pair"]

#: One instrument table row: name, kind, address, state, identity.
InstrumentRow = tuple[str, str, str, str, str]


def describe_setup(setup) -> str:
    """Three lines: channels and shakers, the excitation, and the safety limits."""
    head = (f"{setup.name}: {len(setup.channels)} channels, {len(setup.shakers)} shakers "
            f"({', '.join(s.dof for s in setup.shakers)}), DAQ {setup.daq.sample_rate_hz} S/s")
    if setup.excitation == "stepped_sine":
        s = setup.sine
        exc = (f"stepped sine {s.f_min_hz:g}-{s.f_max_hz:g} Hz, {s.n_lines} lines {s.spacing} "
               f"x refine {s.refine}, force {s.force_n:g} N, accuracy {s.accuracy:g}")
    else:
        r = setup.random
        exc = (f"random ({r.kind}) {r.f_min_hz:g}-{r.f_max_hz:g} Hz, block {r.block_size}, "
               f"{r.averages} averages, {r.window}, {r.estimator}, drive {r.drive_vpp:g} Vpp")
    lim = setup.limits
    # RMS limits (random only) are shown when set: most setups have none, and "inf" thrice
    # more would crowd the line.
    rms = [f"{what} {v:g} {unit}" for what, v, unit in (
        ("accel", lim.max_accel_rms_m_per_s2, "m/s2"), ("force", lim.max_force_rms_n, "N"),
        ("reaction", lim.max_reaction_rms_n, "N")) if math.isfinite(v)]
    return (f"{head}\n{exc}\nlimits: drive {lim.max_drive_vpp:g} Vpp, force {lim.max_force_n:g} N, "
            f"accel {lim.max_accel_m_per_s2:g} m/s2, reaction {lim.max_reaction_n:g} N"
            + (f"; RMS {', '.join(rms)}" if rms else "") + f"; min coherence {setup.min_coherence:g}")


def channel_rows(setup) -> list[tuple[str, ...]]:
    """The channel table: name, input, DOF, quantity, sensitivity (mV/unit), range (V), coupling."""
    return [(c.name, str(c.input), c.dof, c.quantity, f"{c.sensitivity_mv_per_unit:g}",
             f"{c.range_volt:g}", c.coupling) for c in setup.channels]


def channel_options(setup) -> list[tuple[str, tuple[int, int]]]:
    """The (output, input) pairs a plot can show, as ``(label, (output index, input index))``."""
    return pair_options(setup.outputs, setup.inputs)


def pair_options(outputs: list[str], inputs: list[str]) -> list[tuple[str, tuple[int, int]]]:
    """The (output, input) pairs of FRFs with these DOFs, as ``(label, (output index, input
    index))``: a setup's (the live plot) or a measured FRF's own (the results)."""
    return [(f"{o} / {i}", (k, j)) for j, i in enumerate(inputs) for k, o in enumerate(outputs)]


def same_pair(channel: tuple[int, int], outputs: list[str], inputs: list[str], to_outputs: list[str],
              to_inputs: list[str]) -> tuple[int, int] | None:
    """The (output, input) indices in ``to_outputs`` / ``to_inputs`` of the DOFs that
    ``channel`` indexes in ``outputs`` / ``inputs``, or None where they are not all there.

    The live plot indexes the loaded setup's DOFs, the results the run's FRF: after another
    setup is loaded the same indices may name other DOFs, so a choice is passed on by name."""
    o, i = channel
    try:
        return list(to_outputs).index(outputs[o]), list(to_inputs).index(inputs[i])
    except (IndexError, ValueError):
        return None


def _instruments(setup) -> list[tuple[str, str, str]]:
    """The setup's instruments as (name, kind, address), generators, amplifiers, then the DAQ."""
    return ([(g.name, "generator", g.url) for g in setup.generators]
            + [(a.name, "amplifier", f"{a.host}:{a.port}") for a in setup.amplifiers]
            + [("daq", "daq", f"{setup.daq.interface}:{setup.daq.channel}")])


def configured_instrument_rows(setup) -> list[InstrumentRow]:
    """The setup's instruments before they are checked (F4) or used by a run."""
    return [(name, kind, address, "not checked (F4)", "") for name, kind, address in _instruments(setup)]


def checked_instrument_rows(states, sim: bool) -> tuple[list[InstrumentRow], str]:
    """Rows and a one-line verdict from ``daq.check.check_lab`` (F4).

    ``states`` are its per-instrument results (name, kind, address, ok, detail, identity,
    why not ready)."""
    from daq.check import check_verdict

    rows = [(s.name, s.kind, s.address, s.state, s.identity) for s in states]
    return rows, check_verdict(states) + (" (simulated lab)" if sim else "")


def instruments_in_use_rows(ev: dict, setup) -> list[InstrumentRow]:
    """Instrument table rows from the run's ``instruments`` event (identities as read).

    ``setup`` gives the addresses of real instruments; simulated ones are marked so."""
    from drivers.daq import firmware_text

    sim = bool(ev.get("simulated"))
    addr = {name: a for name, _, a in _instruments(setup)} if setup is not None and not sim else {}
    rows: list[InstrumentRow] = []
    for group, items in ev.get("identities", {}).items():
        if group == "daq":
            ident = ", ".join(f"{k} {firmware_text(v) if k == 'fw_version' else v}" for k, v in items.items()
                              if k in ("serial", "fw_version", "n_inputs"))
            rows.append(("daq", "daq", addr.get("daq", "simulated" if sim else ""), "in use by the run", ident))
        else:
            rows += [(name, group.rstrip("s"), addr.get(name, "simulated" if sim else ""), "in use by the run",
                      str(idn)) for name, idn in items.items()]
    return rows
