"""Mass-weighted checks that cannot be met are "not applicable", not "fail" or "pass" (QA):
more test shapes than DOFs, and shapes outside the range of a singular TAM mass (a SEREP TAM of
fewer target modes than DOFs)."""

from __future__ import annotations

import numpy as np
from test_correlate_cli import run

from ssid.correlate_models import correlate_models, correlate_with_frf
from ssid.frf import accelerance_from_model
from ssid.io import Model, write_model
from ssid.modal import modal_damping_matrix
from ssid.tam import reduce_to_tam

DOFS = [f"{i}+X" for i in range(1, 7)]


def _chain():
    """The QA's grounded 6-mass chain (0.34 ... 4.2 Hz)."""
    m = np.array([1.0, 2.0, 1.5, 1.0, 3.0, 2.0])
    k = np.array([100.0, 200.0, 150.0, 300.0, 250.0, 120.0])
    K = np.diag(k + np.r_[k[1:], 0.0]) - np.diag(k[1:], 1) - np.diag(k[1:], -1)
    return np.diag(m), K


def test_more_test_shapes_than_dofs_cannot_be_mass_orthogonal():
    """The chain's own FRFs at 3 outputs: 5 CMIF peaks, FRAC 1 and a gap of 1e-16, and the
    orthogonality and cross-orthogonality "fail" with off-diagonal terms of 0.76."""
    M, K = _chain()
    C = modal_damping_matrix(M, K, np.full(6, 0.02))
    frf = accelerance_from_model(M, C, K, DOFS, np.linspace(0.05, 3.5, 1400), ["5+X", "2+X", "6+X"], ["5+X", "2+X"])
    s = correlate_with_frf(frf, Model(M, K, C, DOFS)).summary
    assert len(s["test_natural_freq_hz"]) == 5 and s["frac"]["min"] > 1 - 1e-9
    for key in ("orthogonality", "cross_orthogonality"):
        assert s[key]["status"] == "not applicable" and s[key]["pass"] is None
        assert s[key]["max_abs_offdiag"] > 0.5  # the numbers are kept
    assert "5 test modes at 3 DOFs: more shapes than DOFs cannot be mass-orthogonal, so the orthogonality " \
           "check is not applicable (its numbers are kept)" in s["warnings"]
    assert any(w.startswith("5 paired modes at 3 DOFs") for w in s["warnings"])
    assert not any(p["cross_orthogonality_applicable"] for p in s["paired_modes"])


def test_modes_outside_a_singular_tam_mass_are_not_judged_by_it():
    """SEREP TAM with targets 1 and 2 at 3 DOFs: its mass has rank 2. Test mode 3 (the chain's
    mode 3, exact) lies 10 % inside its range, and its cross-orthogonality of 1.000 with
    analysis mode 3 was counted: it says nothing."""
    M, K = _chain()
    a = [4, 1, 5]
    red = reduce_to_tam("serep", M, K, a)
    test = Model(red.M, red.K, None, [DOFS[i] for i in a])
    s = correlate_models(test, Model(M, K, None, DOFS), tam="serep", targets=[1, 2]).summary
    assert [p["cross_orthogonality_applicable"] for p in s["paired_modes"]] == [True, True, False]
    for key in ("orthogonality", "cross_orthogonality"):
        assert s[key]["status"] == "pass" and s[key]["pass"] is True and s[key]["not_applicable"] == [3]
    assert ("the TAM mass has rank 2 of 3 (a SEREP TAM of fewer target modes than DOFs, or a massless retained "
            "DOF?): test mode 3 and paired analysis mode 3 lie mostly outside its range") in " ".join(s["warnings"])


def test_the_table_brackets_what_does_not_apply(tmp_path, capsys):
    M, K = _chain()
    a = [4, 1, 5]
    red = reduce_to_tam("serep", M, K, a)
    write_model(tmp_path / "test.h5", Model(red.M, red.K, None, [DOFS[i] for i in a]))
    write_model(tmp_path / "fem.h5", Model(M, K, None, DOFS))
    status, err = run(["--model", str(tmp_path / "test.h5"), "--model", str(tmp_path / "fem.h5"), "--tam", "serep",
                       "--targets", "1,2", "--json", str(tmp_path / "c.json")])
    assert status == 0, err
    out = capsys.readouterr().out.splitlines()
    assert out[4].split()[-1] == "(1.000)" and out[3].split()[-1] == "1.000"
    assert "(XOR): not applicable (the warnings say why), not counted in the verdict" in out
    assert "orthogonality of the test modes: max |off-diag| 0.000 -> pass" in out
