"""``ssidlab discrepancy`` (ssidlab/cli_discrepancy.py): files in, contract JSON and model out,
one-line errors with status 2 through ``ssidlab.cli.main``'s rules."""

from __future__ import annotations

import argparse
import json
import re

import h5py
import numpy as np
import pytest

from ssid.discrepancy.cases import make_case
from ssid.errors import InputError
from ssid.io import read_model, write_frf, write_model
from ssidlab import cli
from ssidlab.cli_discrepancy import add_discrepancy_subcommand

CONTRACT_KEYS = ["effect", "dofs", "parameters", "gap_before", "gap_after", "gap_metric", "candidates"]


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="ssidlab")
    add_discrepancy_subcommand(parser.add_subparsers(dest="command"))
    return parser.parse_args(["discrepancy", *argv])


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("disc")
    case = make_case(1000, structure="chain", effect="added_mass")
    write_model(d / "nominal.h5", case.nominal)
    write_frf(d / "frf.h5", case.frf)
    return d, case


def test_run_writes_contract_json_updated_model_and_plots(files, capsys):
    d, case = files
    args = _parse(["--model", str(d / "nominal.h5"), "--measured", str(d / "frf.h5"),
                   "--json", str(d / "out.json"), "--out", str(d / "updated.h5"),
                   "--plots", str(d / "plots")])
    assert args.run(args) == 0
    data = json.loads((d / "out.json").read_text())
    assert list(data)[: len(CONTRACT_KEYS)] == CONTRACT_KEYS
    assert (data["effect"], set(data["dofs"])) == (case.truth.name, set(case.truth.dofs))
    assert data["parameters"]["mass_kg"] == pytest.approx(case.truth.parameters["mass_kg"], rel=0.2)
    assert data["gap_after"] <= 0.5 * data["gap_before"]
    updated = read_model(d / "updated.h5")
    i = updated.dofs.index(data["dofs"][0])
    assert updated.M[i, i] - case.nominal.M[i, i] == pytest.approx(data["parameters"]["mass_kg"])
    assert len(data["plots"]) >= 4 and all((d / "plots").joinpath(p.split("/")[-1]).exists()
                                           for p in data["plots"])
    assert "effect: added_mass" in capsys.readouterr().out


def test_the_negligible_floor_is_the_users_to_set(files):
    # The hidden mass changes FRF values by far more than 0.1 %; with the floor set above
    # any change it is seen, said to be negligible and not named.
    d, case = files
    args = _parse(["--model", str(d / "nominal.h5"), "--measured", str(d / "frf.h5"),
                   "--json", str(d / "floor.json"), "--negligible", "1e6", "--quiet"])
    assert args.run(args) == 0
    data = json.loads((d / "floor.json").read_text())
    seen = data["residual"]["negligible_effect"]
    assert data["effect"] == "none" and (seen["effect"], set(seen["dofs"])) == (case.truth.name, set(case.truth.dofs))
    assert 1e-3 < seen["frf_change"] < 1e4


@pytest.mark.parametrize("extra,message", [
    (["--fmin", "50", "--fmax", "10"], "must be below"),
    (["--fmin", "1e6"], "no frequency lines"),
])
def test_band_errors(files, extra, message):
    d, _ = files
    args = _parse(["--model", str(d / "nominal.h5"), "--measured", str(d / "frf.h5"),
                   "--json", str(d / "e.json"), *extra])
    with pytest.raises(InputError, match=message):
        args.run(args)


def test_output_must_not_overwrite_an_input(files):
    d, _ = files
    args = _parse(["--model", str(d / "nominal.h5"), "--measured", str(d / "frf.h5"),
                   "--json", str(d / "e.json"), "--out", str(d / "nominal.h5")])
    with pytest.raises(InputError, match="overwrite an input"):
        args.run(args)


def test_outputs_missing_from_the_model_are_refused(files, tmp_path):
    d, case = files
    small = case.nominal
    keep = [k for k, lbl in enumerate(small.dofs) if lbl != case.frf.outputs[0]]
    from ssid.io import Model

    write_model(tmp_path / "small.h5", Model(M=small.M[np.ix_(keep, keep)], K=small.K[np.ix_(keep, keep)],
                                             C=small.C[np.ix_(keep, keep)], dofs=[small.dofs[k] for k in keep]))
    args = _parse(["--model", str(tmp_path / "small.h5"), "--measured", str(d / "frf.h5"),
                   "--json", str(tmp_path / "e.json")])
    with pytest.raises(InputError, match="not a DOF of the model"):
        args.run(args)


def test_an_unstable_model_is_refused_naming_its_file(files, tmp_path):
    d, case = files
    from ssid.io import Model

    m = case.nominal
    path = tmp_path / "unstable.h5"
    write_model(path, Model(M=m.M, K=-m.K, C=m.C, dofs=m.dofs))
    args = _parse(["--model", str(path), "--measured", str(d / "frf.h5"), "--json", str(tmp_path / "e.json")])
    with pytest.raises(InputError, match=rf"^{re.escape(str(path))}: the model's K has the eigenvalue"):
        args.run(args)


# The overflow is the 1e-300 model's point, not a warning about the test.
@pytest.mark.filterwarnings("ignore:overflow:RuntimeWarning", "ignore:invalid value:RuntimeWarning")
@pytest.mark.parametrize("kind", ["massless DOF without C", "scaled beyond floating point"])
def test_a_model_the_analysis_cannot_compute_with_is_refused_naming_its_file(files, tmp_path, kind):
    """A DOF without mass and no C: the modal damping put in C's place needs a mass at every
    DOF, and scipy's LinAlgError was an internal error (QA). M and K times 1e-300: the model's
    response overflows: the gaps were NaN and the summary a TypeError, or, with reactions, no
    value kept a weight and a ZeroDivisionError was one."""
    d, case = files
    from ssid.io import Model

    m = case.nominal
    if kind.startswith("massless"):
        M = m.M.copy()
        M[0, :] = M[:, 0] = 0.0
        model, match = Model(M=M, K=m.K, C=None, dofs=m.dofs), "M is not positive definite .* give the model its C"
    else:
        model = Model(M=1e-300 * m.M, K=1e-300 * m.K, C=None, dofs=m.dofs)
        match = "the model's response at these lines is not a finite number"
    path = tmp_path / "model.h5"
    write_model(path, model)
    args = _parse(["--model", str(path), "--measured", str(d / "frf.h5"), "--json", str(tmp_path / "e.json")])
    with pytest.raises(InputError, match=match):
        args.run(args)


def test_main_gives_one_line_and_status_2_on_bad_input(files, tmp_path, capsys):
    """Through ssidlab.cli.main, as the console command runs it."""
    d, _ = files
    nan_file = tmp_path / "nan.h5"
    with h5py.File(d / "frf.h5", "r") as src, h5py.File(nan_file, "w") as dst:
        for k, v in src.attrs.items():
            dst.attrs[k] = v
        for name in src:
            data = src[name][()]
            if name == "H":
                data[2, 0, 0] = np.nan
            if name == "valid":
                data[:] = True
            dst.create_dataset(name, data=data)
    cases = [
        ["--model", str(tmp_path / "missing.h5"), "--measured", str(d / "frf.h5"), "--json", str(tmp_path / "o.json")],
        ["--model", str(d / "frf.h5"), "--measured", str(d / "frf.h5"), "--json", str(tmp_path / "o.json")],
        ["--model", str(d / "nominal.h5"), "--measured", str(nan_file), "--json", str(tmp_path / "o.json")],
        ["--model", str(d / "nominal.h5"), "--measured", str(d / "frf.h5"), "--json", str(tmp_path / "o.json"), "--bogus"],
        ["--model", str(d / "nominal.h5"), "--json", str(tmp_path / "o.json")],
        ["--model", str(d / "nominal.h5"), "--measured", str(d / "frf.h5"), "--json", str(tmp_path / "o.json"),
         "--negligible", "nan"],
        ["--model", str(d / "nominal.h5"), "--measured", str(d / "frf.h5"), "--json", str(tmp_path / "o.json"),
         "--negligible", "-1"],
    ]
    for argv in cases:
        assert cli.main(["discrepancy", *argv]) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("ssidlab discrepancy: error:"), err
        assert "Traceback" not in err


def _candidate(effect, dofs, criterion, best, rejected=None, **parameters):
    return {"effect": effect, "dofs": dofs, "parameters": parameters, "criterion": criterion,
            "delta_criterion": criterion - best, "rejected": rejected}


def test_candidates_turned_down_by_the_checks_are_said_rejected_not_tied_with_none():
    """The QA's record without a hidden effect: three leaders failed the cross-validation and
    every candidate above none was then moved to just below it (criterion none's + 1e-9); the
    table printed their delta as 0.0, a tie with none. Each now reads "rejected" with what it
    failed (the candidate's ``rejected``), or that it was never checked; a candidate ranked
    below none by its own criterion keeps its delta."""
    from ssidlab.cli_discrepancy import summary_text

    c0 = -6604.400441761534
    demoted = c0 + 1e-9
    unchecked = "not checked: ranked below none once the leaders checked had failed"
    data = {"effect": "none", "dofs": [], "parameters": {}, "gap_before": 0.888, "gap_after": 0.888,
            "gap_metric": "rms_noise_normalised_residual",
            "candidates": [_candidate("none", [], c0, c0),
                           _candidate("grounded_damper", ["stand@18+Z"], demoted, c0, unchecked,
                                      damping_n_s_per_m=0.0487),
                           _candidate("attached_oscillator", ["7+Z"], demoted, c0,
                                      "failed the cross-validation: it raised the held-out residual by 135",
                                      mass_kg=6.1e-6, stiffness_n_per_m=1.66, damping_n_s_per_m=1.4e-4),
                           _candidate("added_mass", ["16+Z"], demoted, c0,
                                      "negligible: it changes no model FRF value by more than 0.048 %",
                                      mass_kg=-1.0e-6),
                           _candidate("grounded_spring", ["stand@18+Z"], c0 + 3.787, c0, stiffness_n_per_m=-19.9)]}
    rows = summary_text(data).split("candidates (delta EBIC):\n")[1].splitlines()
    assert rows[0].split() == ["0.0", "none"]
    assert rows[1].split()[:3] == ["rejected", "grounded_damper", "stand@18+Z"]
    assert rows[1].endswith("(not checked: ranked below none once the leaders checked had failed)")
    assert rows[2].split()[0] == "rejected"
    assert rows[2].endswith("(failed the cross-validation: it raised the held-out residual by 135)")
    assert rows[3].split()[0] == "rejected"
    assert rows[3].endswith("(negligible: it changes no model FRF value by more than 0.048 %)")
    assert rows[4].split()[:2] == ["3.8", "grounded_spring"] and "(" not in rows[4]
