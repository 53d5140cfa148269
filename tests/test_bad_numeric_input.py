"""Data the readers accept but the numerics cannot use: a clear error, never an internal error,
a NaN verdict or an arbitrary answer.

A. FRFs whose lines lie outside any vibration test's frequencies (a unit or scale error) and
   FRFs that are the same at every line (no resonance: the response does not determine a
   model) were internal errors (LinAlgError, "cannot reshape array of size 0") in identify,
   bands and pseudo-dof.
B. ``ssidlab compare`` agreed over one common line, matched only a few of the lines of a file
   holding its frequencies in float32, and called a file and itself different at |H| ~ 1e90
   (FRAC NaN); the reciprocity check in ``identify`` did the same.
C. ``place`` and ``correlate`` worked on a model with K zero (every mode at 0 Hz, any shapes),
   and ``correlate`` printed placeholder numbers (1.000, 0.000) when no mode was paired.

Each test builds its input in ``tmp_path`` and failed before the fix it guards.
"""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest
from conftest import DOFS, chain_frf, chain_model, one_error_line

from ssid.correlate import check_orthogonality
from ssid.errors import IdentificationError, InputError
from ssid.frf import FRFData, accelerance_from_model, require_frequency_dependence, require_response
from ssid.frf_compare import MIN_COMMON_LINES, compare_curves, compare_frfs
from ssid.identify import identify_mck
from ssid.io import Model, write_frf, write_model
from ssid.noise import difference_flat_levels, fit_additive_proportional
from ssid.reciprocity import reciprocity_check


def _write(tmp_path, frf: FRFData, name: str = "frf.h5") -> str:
    path = tmp_path / name
    write_frf(path, frf)
    return str(path)


def _analyses(src: str, tmp_path) -> list[tuple[str, list[str]]]:
    """The commands that identify from an FRF file, with their arguments."""
    out, js = str(tmp_path / "m.h5"), str(tmp_path / "r.json")
    return [("identify", [src, "--out", out, "--json", js]),
            ("identify", [src, "--out", out, "--json", js, "--select-band"]),
            ("pseudo-dof", [src, "--json", js]),
            ("bands", [src, "--json", js])]


# ----------------------------------------------------------------------------------------------
# A. Frequencies outside a vibration test's; FRFs that do not change with frequency
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("scale", [1e-200, 1e200, 1e-9, 1e12])
def test_frequencies_no_vibration_test_has_are_refused_where_the_file_is_read(tmp_path, ssidlab, scale):
    """Lines at 2e-200 Hz were "array must not contain infs or NaNs", at 2e200 Hz "SVD did not
    converge" or "cannot reshape" (exit 1), or a band processing of garbage (exit 0)."""
    frf = chain_frf()
    frf = dataclasses.replace(frf, freq_hz=frf.freq_hz * scale)
    with pytest.raises(InputError, match=r"run\.h5: the frequency lines run from .* outside 1e-06 to 1e\+09 Hz"):
        require_response(frf, "run.h5")
    src = _write(tmp_path, frf)
    for command, args in _analyses(src, tmp_path):
        status, _, err = ssidlab(command, *args)
        line = one_error_line(err, command)
        assert status == 2 and f"{src}: the frequency lines run from" in line and "scale or unit" in line, line
    # Lines from 1e-6 Hz to 1e9 Hz pass (a long-period structure, an ultrasonic test).
    require_response(dataclasses.replace(frf, freq_hz=np.linspace(1e-6, 1e-4, frf.n_freq)))
    require_response(dataclasses.replace(frf, freq_hz=np.linspace(1e8, 1e9, frf.n_freq)))


@pytest.mark.parametrize("constant", ["ones", "random"])
def test_an_frf_the_same_at_every_line_is_refused_as_no_model(tmp_path, ssidlab, constant):
    """H overwritten with 1 + 0j was "LinAlgError: Singular matrix" (identify, bands) or
    "cannot reshape array of size 0" (--select-band, pseudo-dof), exit 1; a random constant
    of rank 2 for 3 outputs gave models (exit 0) that the data do not determine."""
    frf = chain_frf()
    rng = np.random.default_rng(1)
    value = (np.ones(frf.H.shape[1:]) if constant == "ones"
             else rng.standard_normal(frf.H.shape[1:]) + 1j * rng.standard_normal(frf.H.shape[1:]))
    frf = dataclasses.replace(frf, H=np.broadcast_to(value, frf.H.shape).astype(complex))
    with pytest.raises(IdentificationError, match="the response does not determine a model"):
        require_frequency_dependence(frf)
    with pytest.raises(IdentificationError, match="the response does not determine a model"):
        identify_mck(frf)
    src = _write(tmp_path, frf)
    rank = 1 if constant == "ones" else 2
    for command, args in _analyses(src, tmp_path):
        status, _, err = ssidlab(command, *args)
        line = one_error_line(err, command)
        assert status == 2 and "H is the same at every frequency line" in line, line
        assert f"of rank {rank} for 3 outputs" in line and "does not determine a model" in line, line


def test_a_rigid_body_driven_at_every_dof_is_identified_from_its_mass_line(tmp_path, ssidlab):
    """A constant H of full rank is a free rigid body's mass line, H = M^-1: it determines
    M (and K = C = 0) and is identified so. Every root became a rigid-body mode and step 2
    failed: "ValueError: cannot reshape array of size 0 into shape (0)", exit 1."""
    M = np.array([[2.0, 0.3, 0.0], [0.3, 1.0, 0.1], [0.0, 0.1, 1.5]])
    freq = np.linspace(1.0, 100.0, 120)
    H = np.broadcast_to(np.linalg.inv(M), (freq.size, 3, 3)).astype(complex)
    frf = FRFData(freq_hz=freq, H=H, outputs=list(DOFS), inputs=list(DOFS))
    require_frequency_dependence(frf)  # full rank: no refusal
    res = identify_mck(frf)
    assert res.n_rigid_body_modes == 3
    np.testing.assert_allclose(res.M, M, rtol=1e-8, atol=1e-8)
    assert np.abs(res.K).max() <= 1e-8 * np.abs(M).max() * (2 * np.pi * freq[0]) ** 2
    src = _write(tmp_path, frf)
    status, _, err = ssidlab("identify", src, "--out", tmp_path / "m.h5", "--json", tmp_path / "r.json",
                             "--quiet")
    assert status == 0 and "error" not in err, err


def test_a_singular_fit_is_an_identification_error(monkeypatch):
    """A linear-algebra failure inside an identification (data that pass the entry checks
    and still leave a fit without a solution) is bad data, status 2, not a bug."""
    import ssid.identify

    def singular(*args, **kwargs):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setattr(ssid.identify, "identify_step1", singular)
    with pytest.raises(IdentificationError, match=r"no unique solution .*Singular matrix.*does not determine a model"):
        identify_mck(chain_frf())


# ----------------------------------------------------------------------------------------------
# B. compare and the reciprocity check
# ----------------------------------------------------------------------------------------------


def _shifted_after(frf: FRFData, k: int) -> FRFData:
    """``frf`` with every line from ``k`` on moved by half a spacing: ``k`` lines in common."""
    f = frf.freq_hz.copy()
    f[k:] += 0.5 * (f[1] - f[0])
    return dataclasses.replace(frf, freq_hz=f)


@pytest.mark.parametrize("n_common", [1, MIN_COMMON_LINES - 1])
def test_compare_refuses_too_few_common_lines(tmp_path, ssidlab, n_common):
    """One common line gave "1 common lines ... all 4 FRFs agree", exit 0: over one line the
    gain fits exactly and FRAC is 1, whatever the curves."""
    a = chain_frf()
    src_a, src_b = _write(tmp_path, a, "a.h5"), _write(tmp_path, _shifted_after(a, n_common), "b.h5")
    status, _, err = ssidlab("compare", src_a, src_b)
    line = one_error_line(err, "compare")
    assert status == 2 and f"only {n_common} frequency line(s) in common" in line, line
    assert f"at least {MIN_COMMON_LINES} are needed" in line, line


def test_compare_over_the_minimum_of_lines_says_how_many(tmp_path, ssidlab):
    a = chain_frf()
    src_a = _write(tmp_path, a, "a.h5")
    src_b = _write(tmp_path, _shifted_after(a, MIN_COMMON_LINES), "b.h5")
    status, out, err = ssidlab("compare", src_a, src_b, "--quiet")
    assert status == 0 and out.strip().endswith(f"over {MIN_COMMON_LINES} common lines"), out
    # The other lines of the band both cover have no partner: said, with the count.
    assert err.startswith(f"warning: {a.n_freq - MIN_COMMON_LINES} lines of the band both files cover"), err


def test_compare_says_which_frfs_it_left_out(tmp_path, ssidlab):
    """An FRF with fewer than MIN_COMMON_LINES valid values in common is not compared; the
    verdict "all 5 FRFs agree" of 6 must not read as all of them."""
    a = chain_frf()
    valid = np.ones(a.H.shape, dtype=bool)
    valid[MIN_COMMON_LINES - 1:, 1, 0] = False  # 2+Z / 1+Z: one value short
    b = dataclasses.replace(a, H=np.where(valid, a.H, np.nan), valid=valid)
    src_a, src_b = _write(tmp_path, a, "a.h5"), _write(tmp_path, b, "b.h5")
    status, out, err = ssidlab("compare", src_a, src_b, "--quiet")
    assert status == 0 and out.startswith("all 5 FRFs agree"), out
    assert err == (f"warning: 1 FRF(s) have fewer than {MIN_COMMON_LINES} valid values in common and are "
                   "not compared\n"), err


def test_compare_names_the_channels_one_file_lacks(tmp_path, ssidlab):
    """An output renamed in one file was left out of the comparison without a word: "all 4
    FRFs agree" of the 6 the first file holds (QA)."""
    a = chain_frf()
    b = dataclasses.replace(a, outputs=["1+Z", "2+Zx", "3+Z"])
    src_a, src_b = _write(tmp_path, a, "a.h5"), _write(tmp_path, b, "b.h5")
    status, out, err = ssidlab("compare", src_a, src_b, "--quiet", "--json", tmp_path / "c.json")
    assert status == 0 and out.startswith("all 4 FRFs agree"), out
    assert err == (f"warning: outputs only in {src_a}, not compared: 2+Z\n"
                   f"warning: outputs only in {src_b}, not compared: 2+Zx\n"), err
    assert json.loads((tmp_path / "c.json").read_text())["not_compared"] == {
        f"outputs only in {src_a}": ["2+Z"], f"outputs only in {src_b}": ["2+Zx"]}


def test_an_empty_dof_label_is_refused(tmp_path):
    """A blank label was read as a DOF (QA: compare matched the others and said nothing)."""
    with pytest.raises(InputError, match=re.escape("outputs[1] is an empty label")):
        write_frf(tmp_path / "f.h5", dataclasses.replace(chain_frf(), outputs=["1+Z", " ", "3+Z"]))


def test_compare_matches_lines_stored_in_float32(tmp_path, ssidlab):
    """freq_hz written as float32 in one file: only the lines float32 holds exactly matched a
    1e-9 relative tolerance (25 of 1024 on the demo record), with "agree" and no warning."""
    a = chain_frf()
    b = dataclasses.replace(a, freq_hz=a.freq_hz.astype(np.float32).astype(float))
    assert np.count_nonzero(b.freq_hz != a.freq_hz) > a.n_freq // 2  # the rounding is there
    cmp = compare_frfs(a, b)
    assert cmp.freq_hz.size == a.n_freq and cmp.n_unmatched == 0 and not cmp.disagreeing()
    src_a, src_b = _write(tmp_path, a, "a.h5"), _write(tmp_path, b, "b.h5")
    status, out, err = ssidlab("compare", src_a, src_b, "--json", tmp_path / "c.json")
    assert status == 0 and err == "" and out.splitlines()[-1].endswith(f"over {a.n_freq} common lines"), out
    assert json.loads((tmp_path / "c.json").read_text())["n_lines"] == a.n_freq


@pytest.mark.parametrize("scale", [1e90, 1e-90])
def test_gain_and_frac_hold_at_the_ends_of_the_accepted_magnitudes(tmp_path, ssidlab, scale):
    """A file compared with itself at |H| ~ 1e90 or 1e-90 (the reader accepts 1e-100 to 1e100):
    "4 of 4 FRFs differ ... FRAC nan" (the fourth powers of FRAC left float64)."""
    a = chain_frf()
    h = a.H[:, 0, 0]
    var = (1e-3 * np.abs(h)) ** 2
    ref = compare_curves(h, 1.01 * h, var, var)
    c = compare_curves(scale * h, 1.01 * scale * h, scale**2 * var, scale**2 * var)
    assert c.frac == pytest.approx(1.0, abs=1e-12) and c.gain == pytest.approx(1 / 1.01, rel=1e-12)
    for name in ("gain_std", "residual_ratio", "relative_residual"):
        assert getattr(c, name) == pytest.approx(getattr(ref, name), rel=1e-9, abs=1e-15), name
    scaled = dataclasses.replace(a, H=a.H * scale)
    assert compare_frfs(scaled, scaled).disagreeing() == []
    src = _write(tmp_path, scaled, "s.h5")
    status, out, _ = ssidlab("compare", src, src, "--quiet")
    assert status == 0 and out.startswith(f"all {a.n_out * a.n_in} FRFs agree"), out
    # A gain of decades reads as one, not as ninety digits.
    status, out, _ = ssidlab("compare", src, _write(tmp_path, a, "a.h5"))
    assert status == 0 and f"gain {scale:.4g} at" in out, out


@pytest.mark.parametrize("scale", [1e90, 1e-90])
def test_reciprocity_and_identify_hold_at_the_ends_of_the_accepted_magnitudes(scale):
    """``identify`` on H scaled by 1e90 warned "NOT RECIPROCAL ... FRAC nan", and its noise
    levels (fourth powers of |H|) overflowed; the scaled record identifies as the original."""
    a = chain_frf()
    scaled = dataclasses.replace(a, H=a.H * scale)
    pairs = reciprocity_check(scaled)
    assert pairs and all(p.reciprocal and p.curves.frac == pytest.approx(1.0) for p in pairs)
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        res = identify_mck(scaled)
    assert not any("RECIPROCAL" in w for w in res.warnings), res.warnings
    np.testing.assert_allclose(res.natural_freq_hz, identify_mck(a).natural_freq_hz, rtol=1e-6)


@pytest.mark.parametrize("scale", [2.0**600, 2.0**-600])
def test_noise_levels_scale_with_the_data_exactly(scale):
    """The noise-model fits at |H|^2 scaled by 2^+-600 (|H| ~ 1e90 or 1e-90): the flat levels
    scale exactly, the proportional level and the correlation do not change (1/var^2 left
    float64: inf and NaN levels)."""
    a = chain_frf()
    rng = np.random.default_rng(2)
    noisy = a.H * (1 + 1e-3 * rng.standard_normal(a.H.shape)) + 1e-4 * rng.standard_normal(a.H.shape)
    ok = np.ones(a.H.shape, dtype=bool)
    r2, h2 = np.abs(noisy - a.H) ** 2, np.abs(a.H) ** 2
    a2, b2 = fit_additive_proportional(r2, h2, ok)
    a2s, b2s = fit_additive_proportional(r2 * scale, h2 * scale, ok)
    np.testing.assert_array_equal(a2s, a2 * scale)
    np.testing.assert_array_equal(b2s, b2)
    root = np.sqrt(scale)
    f2, rho = difference_flat_levels(noisy, ok, b2)
    f2s, rhos = difference_flat_levels(noisy * root, ok, b2)
    np.testing.assert_allclose(f2s, f2 * scale, rtol=1e-12)
    np.testing.assert_allclose(rhos, rho, rtol=1e-12)


# ----------------------------------------------------------------------------------------------
# C. Models with no elastic mode; a correlation with nothing paired
# ----------------------------------------------------------------------------------------------


def _zero_k_model(tmp_path) -> str:
    m = chain_model()
    path = tmp_path / "zero_k.h5"
    write_model(path, Model(M=m.M, K=np.zeros_like(m.K), C=None, dofs=m.dofs))
    return str(path)


def test_place_refuses_a_model_without_elastic_modes(tmp_path, ssidlab):
    """Was exit 0: "2 of 3 candidate DOFs for 2 target modes (0-0 Hz)", a choice among modes
    whose shapes are any basis."""
    src = _zero_k_model(tmp_path)
    status, _, err = ssidlab("place", src, "--sensors", "2", "--json", tmp_path / "p.json")
    line = one_error_line(err, "place")
    assert status == 2 and f"{src}: K is zero: the model has no elastic modes" in line, line
    assert not (tmp_path / "p.json").exists()


def test_correlate_refuses_a_model_without_elastic_modes(tmp_path, ssidlab):
    """Was exit 0 with "paired modes: 0" against either model."""
    zero = _zero_k_model(tmp_path)
    m = chain_model()
    good = str(tmp_path / "good.h5")
    write_model(good, m)
    frf = _write(tmp_path, chain_frf())
    for args, who in (([good, zero], "analysis model"), ([zero, good], "test model")):
        status, _, err = ssidlab("correlate", "--model", args[0], "--model", args[1], "--json", tmp_path / "c.json")
        line = one_error_line(err, "correlate")
        assert status == 2 and f"{zero} ({who}): K is zero: the model has no elastic modes" in line, line
    status, _, err = ssidlab("correlate", "--model", zero, "--frf", frf, "--json", tmp_path / "c.json")
    assert status == 2 and "(analysis model): K is zero" in one_error_line(err, "correlate")
    assert not (tmp_path / "c.json").exists()


def test_a_correlation_with_no_pair_says_so_and_writes_no_placeholders(tmp_path, ssidlab):
    """Test modes at single DOFs, analysis modes spread evenly over four (a Hadamard basis):
    every MAC is 0.25, nothing is paired. The summary read "min |diag| 1.000, max |off-diag|
    0.000 -> fail" and the JSON held 1.0 and 0.0, numbers of no matrix."""
    hadamard = np.array([[1, 1, 1, 1], [1, -1, 1, -1], [1, 1, -1, -1], [1, -1, -1, 1]]) / 2.0
    w2 = (2 * np.pi * 10.0 * np.arange(1, 5)) ** 2
    dofs = ["1+Z", "2+Z", "3+Z", "4+Z"]
    test, analysis = str(tmp_path / "test.h5"), str(tmp_path / "fe.h5")
    write_model(test, Model(M=np.eye(4), K=np.diag(1.01 * w2), C=None, dofs=dofs))
    write_model(analysis, Model(M=np.eye(4), K=hadamard @ np.diag(w2) @ hadamard.T, C=None, dofs=dofs))
    status, out, err = ssidlab("correlate", "--model", test, "--model", analysis, "--json", tmp_path / "c.json")
    assert status == 0, err
    assert "no modes were paired" in out and "1.000" not in out and "-> fail" in out, out
    xo = json.loads((tmp_path / "c.json").read_text())["cross_orthogonality"]
    assert xo["pass"] is False and xo["paired_matrix"] == []
    assert xo["min_abs_diag"] is None and xo["max_abs_offdiag"] is None and xo["worst_offdiag"] is None, xo
    empty = check_orthogonality(np.zeros((0, 0)))
    assert not empty.passed and np.isnan(empty.min_diag) and empty.worst_offdiag is None


@pytest.mark.parametrize("case, message", [
    ("input not measured", "inputs label '1+Z' is not among outputs"),
    ("NaN not blanked", "H holds NaN or Inf in 1 value(s)"),
    ("descending lines", "freq_hz must be strictly increasing"),
])
def test_frf_data_built_in_python_gets_the_readers_checks(case, message):
    """FRFData built in Python (not read from a file) reached the fits unchecked: an input DOF
    not among the outputs raised "ValueError: '1+Z' is not in list", a NaN without a
    ``valid`` mask scipy's "array must not contain infs or NaNs", and descending lines "no
    frequency lines between 60 and 2 Hz"."""
    a = chain_frf()
    if case == "input not measured":
        model = chain_model()
        bad = accelerance_from_model(model.M, model.C, model.K, model.dofs, a.freq_hz, DOFS[1:], ["1+Z"])
    elif case == "NaN not blanked":
        H = a.H.copy()
        H[10, 1, 0] = np.nan
        bad = dataclasses.replace(a, H=H)
    else:
        bad = dataclasses.replace(a, freq_hz=a.freq_hz[::-1].copy(), H=a.H[::-1].copy())
    with pytest.raises(InputError, match=re.escape(message)):
        identify_mck(bad)


@pytest.mark.parametrize("kwargs, message", [
    ({"solver": "xx"}, "unknown solver 'xx'; choose one of ml, ls, tls, stls"),
    ({"damping": "xx"}, "unknown damping option 'xx'"),
    ({"f_max_hz": "abc"}, "f_max_hz must be a frequency in Hz, got 'abc'"),
    ({"f_min_hz": float("nan")}, "f_min_hz must be a finite frequency in Hz, got nan"),
])
def test_identify_options_no_run_can_use_are_input_errors(kwargs, message):
    """A mistyped option was a plain ValueError (float's "could not convert string to float:
    'abc'", not naming the argument): bad input as any other, an InputError."""
    with pytest.raises(InputError, match=re.escape(message)):
        identify_mck(chain_frf(), **kwargs)


def test_band_limits_that_are_not_numbers_are_input_errors_everywhere():
    """correlate_with_frf and find_discrepancy took the band limits as given: "abc" ended in
    numpy's comparison of an array with a string."""
    from ssid.correlate_models import correlate_with_frf
    from ssid.discrepancy import find_discrepancy

    for run in (lambda **kw: correlate_with_frf(chain_frf(), chain_model(), **kw),
                lambda **kw: find_discrepancy(chain_model(), chain_frf(), **kw)):
        with pytest.raises(InputError, match="f_max_hz must be a frequency in Hz, got 'abc'"):
            run(f_max_hz="abc")
