"""Snapshot tests of the TUI's key screens at 80x24 (pytest-textual-snapshot): Setup with the
example loaded, Run with lines arriving, Results with modes, MAC, discrepancy and overlay.

The screens are built from deterministic input - the example setup, events made from the
simulated lab's exact FRF, and an FRF file with seeded noise - not from a live run, whose
timings differ from run to run. Regenerate after an intended change with
``pytest tests/test_tui_snapshots.py --snapshot-update`` and look at the SVGs before
committing them (the report of a failed comparison shows both).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pytest_textual_snapshot")

from textual.widgets import Input  # noqa: E402

from daq.setup import load_setup  # noqa: E402
from daq.simlab import build_world  # noqa: E402
from ssid.io import write_frf  # noqa: E402
from tui.app import LabApp  # noqa: E402
from tui.results import analyse_run  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SIZE = (80, 24)
EXAMPLE = "examples/setup_sim.toml"  # relative: the screen shows it, and must not show a checkout's path


def exact_frf(setup, n_lines: int = 60, spacing: str = "log"):
    """The simulated lab's own FRF (hidden effect included) on a grid over the setup's band."""
    s = setup.sine
    freq = (np.geomspace if spacing == "log" else np.linspace)(s.f_min_hz, s.f_max_hz, n_lines)
    return build_world(setup).frf(freq, outputs=setup.outputs, inputs=setup.inputs)


async def steady_cursors(pilot) -> None:
    """Stop the text cursors blinking: a focused Input shows its cursor for 0.5 s, then hides
    it for 0.5 s, so a screen taken more than half a second after mounting (a loaded CI machine,
    two test workers) would differ from one taken sooner. Stopped, the cursor stays shown."""
    await pilot.pause()
    for field in pilot.app.query(Input):
        field.cursor_blink = False


@pytest.fixture
def in_root(monkeypatch):
    monkeypatch.chdir(ROOT)


def test_setup_screen(snap_compare, in_root):
    assert snap_compare(LabApp(EXAMPLE, out="run.h5"), terminal_size=SIZE, run_before=steady_cursors)


def test_run_screen_with_lines_arriving(snap_compare, in_root):
    setup = load_setup(EXAMPLE)
    frf = exact_frf(setup)
    coh = np.full(frf.H.shape, 0.999)

    async def feed(pilot):
        from tui.session import LiveRun

        await steady_cursors(pilot)
        app = pilot.app
        app.live = LiveRun(setup.outputs, setup.inputs)
        app._event({"event": "instruments", "simulated": True,
                    "identities": {"generators": {"gen0": "ssidlab,SIM-33522,SN00000,1.0"},
                                   "amplifiers": {"amp0": "model 0x5A01", "amp1": "model 0x5A01"}, "daq": {}}})
        for k in range(40):  # two thirds of the band measured
            app._event({"event": "line", "grid_index": k, "freq_hz": float(frf.freq_hz[k]),
                        "H_abs": np.abs(frf.H[k]).tolist(), "coherence": coh[k].tolist()})
        app._event({"event": "sub_line", "shaker": 1, "grid_index": 39, "freq_hz": float(frf.freq_hz[39]),
                    "drive_vpp": 0.412, "ok": True, "reason": "", "force_n": 2.01, "thd_max": 0.0004,
                    "limit_use": {"drive": 0.0515, "acceleration": 0.21, "force": 0.0402, "reaction load": 0.013},
                    "instruments": {"amplifiers": {"amp0": {"enabled": True, "interlock_closed": True, "fault": ""},
                                                   "amp1": {"enabled": True, "interlock_closed": True, "fault": ""}}}})
        app._status("running: run.h5 (simulated lab)")
        await pilot.press("f2")
        app._redraw_live()
        await pilot.pause()

    assert snap_compare(LabApp(EXAMPLE, out="run.h5"), terminal_size=SIZE, run_before=feed)


def test_results_screen(snap_compare, in_root, tmp_path):
    """400 lines, noise model: complex Gaussian on every value, standard deviation 0.1 % of the
    FRF's RMS magnitude over the band per (output, input), seed 7; its variance in ``H_var``."""
    setup = load_setup(EXAMPLE)
    frf = exact_frf(setup, 400, "linear")
    rng = np.random.default_rng(7)
    sigma = 0.001 * np.sqrt(np.mean(np.abs(frf.H) ** 2, axis=0))
    frf.H = frf.H + sigma * (rng.standard_normal(frf.H.shape) + 1j * rng.standard_normal(frf.H.shape)) / np.sqrt(2)
    frf.H_var = np.broadcast_to(sigma**2, frf.H.shape).copy()
    path = tmp_path / "run.h5"
    write_frf(path, frf)
    results = analyse_run(path, setup, sim=True)
    assert results.discrepancy is not None and results.discrepancy["effect"] == "added_mass"

    async def show(pilot):
        await steady_cursors(pilot)
        app = pilot.app
        results.path = Path("run.h5")  # the name shown, not the temporary folder
        app._show_results(results, results.description.replace(str(tmp_path) + "/", ""))
        await pilot.press("f3")
        await pilot.pause()

    assert snap_compare(LabApp(EXAMPLE, out="run.h5"), terminal_size=SIZE, run_before=show)
