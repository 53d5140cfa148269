"""FRFs with nothing to analyse are refused with the channel named, never analysed into garbage.

A dead accelerometer (zero at every line), a shaker that did not drive (no output responds to
its input), an all-zero or all-blanked file, or values no accelerance in SI units can take.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ssid.errors import InputError
from ssid.frf import require_response
from ssid.io import read_frf, write_frf, write_model
from conftest import chain_frf, chain_model
from test_cli_errors import assert_one_line_error, run_cli

def _with(**changes):
    return dataclasses.replace(chain_frf(), **changes)


def test_a_measured_record_passes():
    require_response(chain_frf())
    # a scale error of a few decades is not refused: it is data in other units, analysable
    frf = chain_frf()
    require_response(_with(H=frf.H * 1e-6))


@pytest.mark.parametrize("make,fragment", [
    (lambda f: _with(H=np.zeros_like(f.H)), "every H value is zero"),
    (lambda f: _with(valid=np.zeros(f.H.shape, bool)), "every H value is marked invalid"),
    (lambda f: _with(H=f.H * 1e120), "not an accelerance in SI units"),
    (lambda f: _with(H=f.H * 1e-120), "not an accelerance in SI units"),
])
def test_records_with_nothing_to_analyse_are_refused(make, fragment):
    with pytest.raises(InputError, match=fragment):
        require_response(make(chain_frf()), "run.h5")


def test_a_dead_output_and_a_dead_input_are_named():
    frf = chain_frf()
    H = frf.H.copy()
    H[:, 1, :] = 0.0
    with pytest.raises(InputError, match=r"run\.h5: output '2\+Z' is zero or marked invalid"):
        require_response(_with(H=H), "run.h5")
    valid = np.ones(frf.H.shape, bool)
    valid[:, 2, :] = False
    valid[:, 0, :] = False
    with pytest.raises(InputError, match=r"outputs '1\+Z', '3\+Z' are zero"):
        require_response(_with(valid=valid), "run.h5")
    H = frf.H.copy()
    H[:, :, 1] = 0.0
    with pytest.raises(InputError, match=r"input '3\+Z' is zero or marked invalid.*did not drive"):
        require_response(_with(H=H), "run.h5")


def test_a_dead_load_cell_is_named():
    """A reaction that reads zero at every line would make SSID identify a free
    substructure, silently; it is refused by name."""
    frf = chain_frf()
    rng = np.random.default_rng(3)
    R = rng.standard_normal((frf.n_freq, 2, frf.n_in)) + 1j * rng.standard_normal((frf.n_freq, 2, frf.n_in))
    require_response(_with(H_reaction=R, reactions=["1+Z", "3+Z"]))
    R[:, 1, :] = 0.0
    with pytest.raises(InputError, match=r"run\.h5: reaction '3\+Z' is zero at every line"):
        require_response(_with(H_reaction=R, reactions=["1+Z", "3+Z"]), "run.h5")


def test_every_analysis_command_refuses_a_dead_channel_and_convert_keeps_it(tmp_path):
    frf = chain_frf(n_freq=200)
    good = tmp_path / "good.h5"
    write_frf(good, frf)
    H = frf.H.copy()
    H[:, 1, :] = 0.0
    dead = tmp_path / "dead.h5"
    write_frf(dead, dataclasses.replace(frf, H=H))
    write_model(tmp_path / "model.h5", chain_model())
    commands = [
        ["identify", "dead.h5", "--out", "m.h5", "--json", "r.json"],
        ["bands", "dead.h5", "--json", "b.json"],
        ["pseudo-dof", "dead.h5", "--json", "p.json"],
        ["correlate", "--model", "model.h5", "--frf", "dead.h5", "--json", "c.json"],
        ["discrepancy", "--model", "model.h5", "--measured", "dead.h5", "--json", "d.json"],
        ["compare", "good.h5", "dead.h5"],
    ]
    for args in commands:
        assert_one_line_error(run_cli(*args, cwd=tmp_path),
                              f"ssidlab {args[0]}: error: dead.h5: output '2+Z' is zero")
    # conversion is not analysis: the file goes through as it is
    proc = run_cli("convert", "dead.h5", "dead.uff", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = run_cli("convert", "dead.uff", "back.h5", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert np.all(read_frf(tmp_path / "back.h5").H[:, 1, :] == 0)


def test_frf_data_built_from_lists_is_analysed_as_its_arrays():
    """FRFData is a plain dataclass: a caller may fill it with lists. require_response checked
    a normalised copy and the analyses went on with the lists ("'list' object has no attribute
    'shape'", QA); they now go on with the copy. Noise-free accelerances of the known chain:
    SSID gives its M, C, K back to round-off (1e-8: the chain's FRFs over 200 lines determine
    them to ~1e-14 here) and the other entry points give what they give for the arrays."""
    from ssid.frf_compare import compare_frfs
    from ssid.identify import identify_mck
    from ssid.pseudo_dof import identify_pseudo_dof

    frf = chain_frf(n_freq=200)
    listed = dataclasses.replace(frf, freq_hz=frf.freq_hz.tolist(), H=frf.H.tolist(), outputs=tuple(frf.outputs))
    truth = chain_model()
    r = identify_mck(listed)
    for name in ("M", "C", "K"):
        got, want = getattr(r, name), getattr(truth, name)
        assert np.linalg.norm(got - want) / np.linalg.norm(want) < 1e-8, name
    assert compare_frfs(listed, frf).disagreeing() == []
    np.testing.assert_array_equal(identify_pseudo_dof(listed).freq_hz, identify_pseudo_dof(frf).freq_hz)
