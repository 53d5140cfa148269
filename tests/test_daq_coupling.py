"""Mixed coupling: a DC force gauge against AC/IEPE accelerometers and load cells. The front
end's coupling high-pass (first-order, ``[daq] ac_corner_hz``, 0.5 Hz on the simulated DAQ)
is in the IEPE channels only, so it does not cancel in the FRF; the estimates divide it out
(``daq.coupling``) and the run file says so."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from test_daq_helpers import frf_error, random_setup, run_on_sim, sine_setup

from daq.coupling import coupling_response, undo_coupling
from daq.run import run_test
from daq.setup import parse_setup
from daq.simlab import WorldRig, build_world
from ssid.errors import InputError
from ssid.io import read_frf


def _iepe(text: str, quantities=("acceleration", "reaction")) -> str:
    """``text`` with every channel of ``quantities`` IEPE-coupled (the force gauges stay DC)."""
    for q in quantities:
        text = text.replace(f'quantity = "{q}"\n', f'quantity = "{q}"\ncoupling = "IEPE"\n')
    return text


def test_stepped_sine_with_iepe_accelerometers_and_a_dc_force_gauge(tmp_path):
    """20-40 Hz, where the 0.5 Hz high-pass leads by atan(0.5/f) = 1.4-0.7 deg (2.5e-2 to
    1.25e-2 of |H|): uncorrected, the lines were up to 2.5e-2 off, 12 times the accuracy
    asked (2e-3) and 20 times the stated uncertainty. Noise off: the stated uncertainty is
    the transient the settling left, and the simulated DAQ's bilinear filter departs from the
    analog high-pass the correction divides out by 2e-6 here; corrected, the run is as an
    all-DC one (largest line error 1.0e-3, error over stated deviation 1.0 at the 95th
    percentile). The load cell is IEPE too, so H_reaction is corrected the same way (1.5e-3,
    as all-DC; bounded as the noise-free stepped-sine test bounds reactions, 5e-3)."""
    text = _iepe(sine_setup(f_min=20.0, f_max=40.0, n_lines=3, refine=2, reaction=True))
    setup = parse_setup(text, str(tmp_path / "s.toml"))
    summary, _ = run_on_sim(setup, tmp_path / "run.h5")
    assert summary["state"] == "complete"
    frf = read_frf(tmp_path / "run.h5")
    ref = build_world(setup).frf(frf.freq_hz, outputs=frf.outputs, inputs=frf.inputs)
    assert frf.valid_mask().all()
    err = frf_error(frf, build_world(setup))
    assert np.max(err) < setup.sine.accuracy, np.max(err)
    z = np.abs(frf.H - ref.H) / np.sqrt(frf.H_var)
    assert np.percentile(z, 95) < 3, np.percentile(z, 95)
    er = np.linalg.norm(frf.H_reaction - ref.H_reaction, axis=1) / np.linalg.norm(ref.H_reaction, axis=1)
    assert np.max(er) < 5e-3, np.max(er)
    with h5py.File(tmp_path / "run.h5") as f:  # the run file says what was divided out
        assert f.attrs["ac_corner_hz"] == 0.5
        said = f.attrs["coupling_correction"]
    assert "0.5 Hz" in said and "'acc 1+Z'" in said and "'load 14+Z'" in said and "force" not in said


@pytest.mark.parametrize("rig", ["lab", "world"])
def test_periodic_random_with_iepe_accelerometers_and_a_dc_force_gauge(tmp_path, rig):
    """One shaker, 40-200 Hz, noise off, two averages: uncorrected, the lowest line was
    1.25e-2 off (the high-pass's lead at 40 Hz); corrected, 5e-5 (all-DC: 3e-5), bounded by
    the accuracy the periodic averages settle to, 1e-3. The same on the world driven
    directly (``WorldRig``, the benchmarks' rig), whose AC/IEPE channels pass the simulated
    DAQ's high-pass too (2e-5)."""
    setup = parse_setup(_iepe(random_setup(averages=2, two=False)), str(tmp_path / "s.toml"))
    if rig == "lab":
        run_on_sim(setup, tmp_path / "run.h5")
    else:
        world = build_world(setup)
        run_test(setup, out=str(tmp_path / "run.h5"), rig_factory=lambda s: WorldRig(s, world), echo=lambda m: None)
    frf = read_frf(tmp_path / "run.h5")
    assert frf.valid_mask().all()
    err = frf_error(frf, build_world(setup))
    assert np.max(err) < 1e-3, np.max(err)


def test_the_correction_is_the_ratio_of_the_channels_responses():
    """Both channels IEPE: nothing changes (the high-pass cancels); only the response IEPE:
    H is divided by its first-order high-pass, iw / (iw + w_c), and the variance by its
    square magnitude."""
    setup = parse_setup(_iepe(random_setup(two=False)), "s.toml")
    f = np.array([0.5, 20.0])
    c = coupling_response(setup, f)
    force, acc = setup.channel_index("force 1+Z"), setup.channel_index("acc 1+Z")
    hp = 1j * f / (1j * f + 0.5)
    np.testing.assert_allclose(c[:, acc], hp, rtol=1e-12)
    np.testing.assert_array_equal(c[:, force], 1.0)
    H, var = np.full((2, 1, 1), 2.0 + 1j), np.full((2, 1, 1), 1e-4)
    H2, var2 = undo_coupling(H, var, c[:, [acc]], c[:, [force]])
    np.testing.assert_allclose(H2[:, 0, 0], H[:, 0, 0] / hp, rtol=1e-12)
    np.testing.assert_allclose(var2[:, 0, 0], 1e-4 / np.abs(hp) ** 2, rtol=1e-12)
    H3, _ = undo_coupling(H, var, c[:, [acc]], c[:, [acc]])
    np.testing.assert_array_equal(H3, H)
    assert abs(abs(hp[0]) - np.sqrt(0.5)) < 1e-12  # -3 dB at the corner


def test_the_corner_is_a_setup_value():
    text = random_setup(two=False)
    assert parse_setup(text, "s.toml").daq.ac_corner_hz == 0.5
    assert parse_setup(text.replace("[daq]\n", "[daq]\nac_corner_hz = 0.16\n"), "s.toml").daq.ac_corner_hz == 0.16
    with pytest.raises(InputError, match=r"\[daq\] ac_corner_hz: must be in \(0, 100\]"):
        parse_setup(text.replace("[daq]\n", "[daq]\nac_corner_hz = 0\n"), "s.toml")
