"""``ssidlab correlate`` through its ``run`` function and a local parser that behaves like
``ssidlab.cli.main`` (usage errors and InputError -> one line, status 2). The end-to-end
subprocess test comes with the wiring into ssidlab/cli.py."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
import scipy.io
from test_tam_models import beam_model, translations

from ssid.errors import InputError
from ssid.frf import accelerance_from_model
from ssid.io import Model, read_model, write_frf, write_model
from ssid.modal import modal_damping_matrix
from ssid.tam import guyan_reduce
from ssidlab.cli_correlate import add_correlate_subcommand, parse_mode_list


class _Usage(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # like ssidlab.cli._Parser: no exit, one line
        raise _Usage(f"{self.prog}: error: {message}")


def run(argv: list[str]) -> tuple[int, str]:
    parser = _Parser(prog="ssidlab")
    sub = parser.add_subparsers(dest="command", required=True)
    add_correlate_subcommand(sub)
    try:
        args = parser.parse_args(["correlate", *argv])
    except _Usage as exc:
        return 2, str(exc)
    try:
        return args.run(args), ""
    except InputError as exc:
        return 2, f"ssidlab correlate: error: {exc}"


NODES = [1, 3, 5, 7]
INTERFACE = "1+Z,7+Z"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("corr")
    M, K, dofs = beam_model(n_elem=6, length_m=1.0)
    C = modal_damping_matrix(M, K, np.full(M.shape[0], 0.02))
    write_model(d / "fem.h5", Model(M, K, C, dofs))
    a = translations(dofs, NODES)
    labels = [dofs[i] for i in a]
    # "Identified" model: the Guyan TAM of a structure 3 % heavier than the FEM.
    red = guyan_reduce(1.03 * M, K, a)
    write_model(d / "test.h5", Model(red.M, red.K, None, labels))
    write_model(d / "unstable.h5", Model(red.M, -red.K, None, labels))  # K negative definite
    massless = M.copy()
    massless[0, :] = massless[:, 0] = 0.0
    write_model(d / "massless.h5", Model(massless, K, None, dofs))
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(5.0, 900.0, 1200), labels, labels[:2])
    write_frf(d / "frf.h5", frf)
    blank = (frf.freq_hz > 100.0) & (frf.freq_hz < 200.0)  # a stretch of lines blanked
    frf.valid = np.broadcast_to(~blank[:, None, None], frf.H.shape).copy()
    frf.H[blank] = np.nan
    write_frf(d / "blanked.h5", frf)
    scipy.io.savemat(d / "fem.mat", {"M": M, "K": K, "dofs": np.array(dofs, dtype=object)})
    bad = M.copy()
    bad[0, 0] = np.nan
    with open(d / "nan.h5", "wb"):
        pass
    scipy.io.savemat(d / "nan.mat", {"M": bad, "K": K, "dofs": np.array(dofs, dtype=object)})
    return d


@pytest.mark.parametrize("tam", ["guyan", "irs", "serep", "hybrid", "cb"])
def test_model_against_model(files, tam):
    out = files / f"mm_{tam}.json"
    status, err = run(["--model", str(files / "test.h5"), "--model", str(files / "fem.mat"),
                       "--tam", tam, *(["--interface", INTERFACE] if tam == "cb" else []), "--json", str(out),
                       "--quiet"])
    assert (status, err) == (0, "")
    s = json.loads(out.read_text())
    for key in ("test_natural_freq_hz", "analysis_natural_freq_hz", "tam_natural_freq_hz", "mac",
                "paired_modes", "freq_error_percent", "orthogonality", "cross_orthogonality"):
        assert key in s
    assert s["tam"] == tam and s["mode"] == "model-model"
    assert len(s["paired_modes"]) == len(NODES)
    # 3 % more mass: every frequency 1.5 % low; Guyan adds up to ~1 % on the top mode here.
    assert all(-3.0 < e < 0.0 for e in s["freq_error_percent"])
    xo = s["cross_orthogonality"]
    assert xo["min_abs_diag"] > 0.99
    # The C-B TAM with only two fixed-interface modes is the least accurate mass here (its
    # 4th frequency is 2 % high): observed off-diagonal 0.11, the others 0.02.
    assert xo["max_abs_offdiag"] < (0.15 if tam == "cb" else 0.05)


def test_model_against_frf_with_plots(files):
    out = files / "mf.json"
    plots = files / "plots"
    status, err = run(["--model", str(files / "fem.h5"), "--frf", str(files / "frf.h5"),
                       "--tam", "cb", "--interface", INTERFACE, "--json", str(out),
                       "--plots", str(plots), "--quiet"])
    assert (status, err) == (0, "")
    s = json.loads(out.read_text())
    assert s["mode"] == "model-frf"
    assert s["frf_gap"] < 1e-9 and s["frf_gap_metric"] == "rms_log_ratio"
    assert min(map(min, s["frac"]["matrix"])) > 1 - 1e-9
    assert {p.split("/")[-1] for p in s["plots"]} >= {"mac.png", "freq_errors.png", "cmif.png",
                                                     "frf_1+Z_1+Z.png", "frf_3+Z_3+Z.png"}
    assert all((plots / p.split("/")[-1]).stat().st_size > 1000 for p in s["plots"])
    assert len(s["paired_modes"]) >= 3


def test_same_dofs_need_no_tam(files):
    out = files / "same.json"
    status, _ = run(["--model", str(files / "fem.h5"), "--model", str(files / "fem.mat"),
                     "--json", str(out), "--quiet"])
    s = json.loads(out.read_text())
    assert status == 0 and s["tam"] == "none"
    np.testing.assert_allclose(np.abs(np.array(s["cross_orthogonality"]["paired_matrix"])),
                               np.eye(len(s["paired_modes"])), atol=1e-8)


def test_mode_list():
    assert parse_mode_list("1-3,7, 5") == [1, 2, 3, 5, 7]
    with pytest.raises(argparse.ArgumentTypeError):
        parse_mode_list("0-2")
    # A mode twice was dropped without a word (--targets 1,1,2: two targets where the user
    # counted three, then "the TAM mass is singular"), while a label twice is refused.
    for text, mode in (("1,1,2", 1), ("1-3,2", 2), ("4,2-5", 4)):
        with pytest.raises(argparse.ArgumentTypeError, match=f"mode {mode} is repeated in '{text}'"):
            parse_mode_list(text)


@pytest.mark.parametrize(
    "argv, match",
    [
        (["--model", "{d}/test.h5", "--json", "{d}/o.json"], "second --model"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--frf", "{d}/frf.h5",
          "--json", "{d}/o.json"], "not both"),
        (["--model", "{d}/a", "--model", "{d}/b", "--model", "{d}/c", "--json", "{d}/o.json"],
         "more than twice"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--fmin", "3", "--json", "{d}/o.json"],
         "--frf only"),
        (["--model", "{d}/fem.h5", "--model", "{d}/test.h5", "--json", "{d}/o.json"],
         "fem.h5: DOF '[^']+' is not a DOF of the analysis model .*test.h5$"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--tam", "cb", "--json", "{d}/o.json"],
         "interface"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--tam", "cb", "--interface", "2+Z",
          "--json", "{d}/o.json"], "not among the test DOFs"),
        # options the TAM or the comparison does not use were ignored without a word (audit)
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--interface", "2+Z",
          "--json", "{d}/o.json"], "--interface applies to --tam cb only; --tam guyan has no interface DOFs"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--targets", "1-3",
          "--json", "{d}/o.json"], "--targets applies to --tam serep, hybrid or cb; --tam guyan uses no target"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--zeta", "0.03",
          "--json", "{d}/o.json"], "--zeta and --reactions apply to --frf only"),
        (["--model", "{d}/fem.h5", "--frf", "{d}/frf.h5", "--reactions", "apply",
          "--json", "{d}/o.json"], "frf.h5: --reactions apply needs measured interface reactions"),
        (["--model", "{d}/fem.h5", "--frf", "{d}/frf.h5", "--zeta", "0.03", "--json", "{d}/o.json"],
         "--zeta: .*fem.h5 has its own damping matrix C, which is used"),
        # Same DOFs, so no TAM is built: a mistyped interface is still refused.
        (["--model", "{d}/fem.h5", "--model", "{d}/fem.mat", "--tam", "cb", "--interface", "99+Z",
          "--json", "{d}/o.json"], "interface DOF '99\\+Z' is not among the test DOFs"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--tam", "serep", "--targets", "1-99",
          "--json", "{d}/o.json"], "--targets"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--targets", "x", "--json", "{d}/o.json"],
         "not a mode list"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--tam", "serep", "--targets", "1,1,2",
          "--json", "{d}/o.json"], "argument --targets: mode 1 is repeated in '1,1,2'"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--tam", "cb", "--interface", "1+Z,1+Z",
          "--json", "{d}/o.json"], "argument --interface: a DOF label is repeated in '1\\+Z,1\\+Z'"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--tam", "magic", "--json", "{d}/o.json"],
         "invalid choice"),
        (["--model", "{d}/fem.h5", "--frf", "{d}/frf.h5", "--zeta", "2", "--json", "{d}/o.json"],
         "damping ratio"),
        (["--model", "{d}/fem.h5", "--frf", "{d}/frf.h5", "--fmin", "2000", "--json", "{d}/o.json"],
         "fewer than 3 frequency lines between 2000 and 900 Hz \\(the FRFs cover 5 to 900 Hz\\)"),
        # a band whose every value is blanked: FRAC and gap came out NaN with exit 0 (QA)
        (["--model", "{d}/fem.h5", "--frf", "{d}/blanked.h5", "--fmin", "120", "--fmax", "180",
          "--json", "{d}/o.json"], "FRF data between 120 and 180 Hz: every H value is marked invalid"),
        (["--model", "{d}/test.h5", "--model", "{d}/missing.h5", "--json", "{d}/o.json"],
         "no such file"),
        # read as -200 % frequency errors and a passing orthogonality, exit 0 (QA)
        (["--model", "{d}/test.h5", "--model", "{d}/unstable.h5", "--json", "{d}/o.json"],
         "unstable.h5 \\(analysis model\\): K is not positive semi-definite"),
        # a DOF without mass and no C: scipy's LinAlgError as an internal error (QA)
        (["--model", "{d}/massless.h5", "--frf", "{d}/frf.h5", "--json", "{d}/o.json"],
         "massless.h5 \\(analysis model\\): M is not positive definite .* give the model its C"),
        (["--model", "{d}/test.h5", "--model", "{d}/nan.mat", "--json", "{d}/o.json"], "NaN"),
        (["--model", "{d}/test.h5", "--model", "{d}/nan.h5", "--json", "{d}/o.json"],
         "not an HDF5|recognised"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--json", "{d}/nodir/o.json"],
         "does not exist"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--json", "{d}/test.h5"],
         "overwrite an input"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5", "--json", "{d}/o.json",
          "--plots", "{d}/fem.h5"], "not a directory"),
        (["--model", "{d}/fem.h5", "--frf", "{d}/test.h5", "--json", "{d}/o.json"], "format"),
        (["--model", "{d}/test.h5", "--model", "{d}/fem.h5"], "required"),
    ],
)
def test_bad_input_is_one_line_and_status_2(files, argv, match):
    status, err = run([a.format(d=files) for a in argv])
    assert status == 2
    assert "\n" not in err and err.startswith("ssidlab correlate: error:")
    assert pytest.importorskip("re").search(match, err), err


def test_frf_outputs_missing_from_the_analysis_model_name_both_files(files):
    m = read_model(files / "test.h5")
    keep = m.dofs[:-1]
    write_model(files / "short.h5", Model(m.M[:-1, :-1], m.K[:-1, :-1], None, keep))
    status, err = run(["--model", str(files / "short.h5"), "--frf", str(files / "frf.h5"),
                       "--json", str(files / "o.json")])
    assert status == 2
    assert err.endswith(f"frf.h5: output {m.dofs[-1]!r} is not a DOF of the analysis model "
                        f"{files / 'short.h5'}"), err


def test_a_test_model_that_is_not_stable_is_correlated_with_a_warning(files):
    """An identified model need not be physical and is still worth correlating; its modes
    with omega^2 < 0 show as negative frequencies, and a warning says why."""
    out = files / "unstable.json"
    with pytest.warns(UserWarning, match=f"test model: {len(NODES)} mode\\(s\\) with omega\\^2 < 0"):
        status, _ = run(["--model", str(files / "unstable.h5"), "--model", str(files / "fem.h5"),
                         "--json", str(out), "--quiet"])
    assert status == 0
    assert all(f < 0 for f in json.loads(out.read_text())["test_natural_freq_hz"])


@pytest.mark.parametrize("tam", ["serep", "hybrid"])
def test_a_target_mode_the_test_dofs_do_not_see_is_refused(tmp_path, tam):
    """Fixed-fixed 7-mass chain measured at masses 2, 4 and 6, the nodes of its mode 4: with
    --targets 4 the SEREP and hybrid TAMs were ~1e16 and the run ended with status 0, an
    orthogonality matrix of +-1 and only a warning that the TAM mass is singular (QA)."""
    n = 7
    K = np.zeros((n, n))
    for i in range(n - 1):
        K[np.ix_([i, i + 1], [i, i + 1])] += 1e4 * np.array([[1.0, -1.0], [-1.0, 1.0]])
    K[0, 0] += 1e4
    K[-1, -1] += 1e4
    write_model(tmp_path / "an.h5", Model(np.eye(n), K, None, [f"{i}+Z" for i in range(1, n + 1)]))
    K_test = 1e4 * np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 2.0]])
    write_model(tmp_path / "test.h5", Model(np.diag([1.0, 1.1, 0.9]), K_test, None, ["2+Z", "4+Z", "6+Z"]))
    status, err = run(["--model", str(tmp_path / "test.h5"), "--model", str(tmp_path / "an.h5"),
                       "--tam", tam, "--targets", "4", "--json", str(tmp_path / "o.json")])
    assert status == 2 and "\n" not in err, err
    assert "target mode 4 is not observable at the retained DOFs" in err
    assert not (tmp_path / "o.json").exists()


@pytest.mark.parametrize("options", [["--tam", "cb"], ["--tam", "serep", "--targets", "1-3"],
                                     ["--tam", "cb", "--interface", "1+Z"]])
def test_tam_options_with_no_reduction_to_make_are_refused(files, options):
    """An analysis model over the test DOFs alone is compared with no TAM; a TAM option then
    was accepted and ignored (the docs' check: ``--tam serep --targets 1-3`` passed, and the
    JSON listed target modes no reduction had used). docs/correlation.md promises that an
    option the comparison does not use is refused."""
    out = files / f"no_tam_{len(options)}{options[-1]}.json"
    status, err = run(["--model", f"{files}/fem.h5", "--model", f"{files}/fem.mat", *options, "--json", str(out)])
    assert status == 2 and "has only the test DOFs: no TAM is made" in err and options[0] in err, err
    assert not out.exists()
    assert run(["--model", f"{files}/fem.h5", "--model", f"{files}/fem.mat", "--json", str(out)]) == (0, "")


def test_a_non_physical_mode_or_one_far_off_in_frequency_is_not_paired(tmp_path, capsys):
    """Three modes with the same shapes in both models (MAC 1 mode for mode). Of the test
    model's, one has omega^2 < 0, one is at ten times its counterpart's frequency (test mode 3,
    200 Hz against 20 Hz), one at 1.25 times (test mode 2). MAC alone paired all three (the
    QA's -12408.78 Hz with 2309.6 Hz, and 54.57 Hz with 1.29 Hz, 4140 % off); only test mode 2
    is a pair now, and the two the rule refuses are shown apart from the pairs, in the table
    and the JSON, with the reason."""
    phi = np.linalg.qr(np.random.default_rng(4).normal(size=(3, 3)))[0]
    dofs = ["1+Z", "2+Z", "3+Z"]

    def model(f_hz):  # M = I and the modes phi at these signed frequencies
        w2 = np.sign(f_hz) * (2 * np.pi * np.asarray(f_hz)) ** 2
        return Model(np.eye(3), phi @ np.diag(w2) @ phi.T, None, dofs)

    write_model(tmp_path / "test.h5", model([-10.0, 200.0, 50.0]))
    write_model(tmp_path / "fem.h5", model([10.0, 20.0, 40.0]))
    js = tmp_path / "c.json"
    with pytest.warns(UserWarning, match="omega\\^2 < 0"):
        status, err = run(["--model", str(tmp_path / "test.h5"), "--model", str(tmp_path / "fem.h5"),
                           "--json", str(js)])
    assert status == 0, err
    s = json.loads(js.read_text())
    assert [(p["test_mode"], p["analysis_mode"]) for p in s["paired_modes"]] == [(2, 3)]
    assert [(p["test_mode"], p["analysis_mode"]) for p in s["not_paired"]] == [(1, 1), (3, 2)]
    assert s["not_paired"][0]["reason"].startswith("the test mode has omega^2 < 0")
    assert s["not_paired"][1]["reason"].startswith("frequencies a factor 10 apart (a pair needs 2 or less)")
    assert s["pairing"] == {"min_mac": 0.5, "max_freq_ratio": 2.0}
    out = capsys.readouterr().out.splitlines()
    below = out[out.index("not paired (the best MAC of each, and why it is no pair):"):]
    assert below[1].split()[:7] == ["1", "omega^2", "<", "0", "1", "10.0000", "-"]
    assert below[2].split()[:6] == ["3", "200.0000", "2", "20.0000", "900.0", "1.000"]
    assert below[3].startswith("cross-orthogonality: min |diag| 1.000")


def test_a_free_free_models_rigid_body_mode_pairs_with_the_suspension_mode_measured(tmp_path):
    """A five-mass free-free chain (analysis: a rigid-body mode at 0 Hz) against the same chain
    on 60 N/m bungees at its ends, as a free-free test measures it (a 0.74 Hz suspension mode,
    MAC 1.000 with the rigid-body mode), and against one whose rigid-body mode an
    identification put at omega^2 = -0.04 (rad/s)^2. The frequency rule had left the rigid-body
    pair out (4 of 5 paired); it pairs by the MAC, as before the rule."""
    m = np.array([1.0, 1.5, 1.2, 0.8, 1.0])
    k = np.array([1e5, 1.2e5, 0.9e5, 1.1e5])
    K = np.zeros((5, 5))
    for i, ki in enumerate(k):
        K[i:i + 2, i:i + 2] += ki * np.array([[1.0, -1.0], [-1.0, 1.0]])
    dofs = [f"{i + 1}+Z" for i in range(5)]
    bungees = K.copy()
    bungees[0, 0] += 60.0
    bungees[-1, -1] += 60.0
    write_model(tmp_path / "fem.h5", Model(np.diag(m), K, None, dofs))
    for name, Kt in (("bungees", bungees), ("below_zero", K - 0.04 * np.diag(m))):
        write_model(tmp_path / f"{name}.h5", Model(np.diag(m), Kt, None, dofs))
        js = tmp_path / f"{name}.json"
        status, err = run(["--model", str(tmp_path / f"{name}.h5"), "--model", str(tmp_path / "fem.h5"),
                           "--json", str(js)])
        assert status == 0, err
        s = json.loads(js.read_text())
        assert [(p["test_mode"], p["analysis_mode"]) for p in s["paired_modes"]] == [(i, i) for i in range(1, 6)]
        assert s["not_paired"] == []
