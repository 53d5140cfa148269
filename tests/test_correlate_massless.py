"""Models with massless DOFs (M positive semi-definite: a lumped-mass model's rotations) have
their finite normal modes; ``ssidlab correlate`` refused them ("M is not positive definite, it
has no normal modes"), even with a Guyan TAM, which handles them exactly (QA)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import scipy.linalg as sla
from test_correlate_cli import run
from test_tam_models import beam_model, translations

from ssid.correlate_models import correlate_models
from ssid.errors import InputError
from ssid.io import Model, write_model
from ssid.tam import guyan_reduce


def _qa_chain():
    """The QA's 6-mass chain with the masses at DOFs 1, 3 and 4 (0-based 0, 2, 3) removed."""
    m = np.array([1.0, 2.0, 1.5, 1.0, 3.0, 2.0])
    m[[0, 2, 3]] = 0.0
    k = np.array([100.0, 200.0, 150.0, 300.0, 250.0, 120.0])
    K = np.diag(k + np.r_[k[1:], 0.0]) - np.diag(k[1:], 1) - np.diag(k[1:], -1)
    return np.diag(m), K


def _finite_eig(M, K):
    lam = sla.eig(K, M, right=False)
    return np.sort(np.real(lam[np.isfinite(lam)]))


def test_the_finite_modes_of_a_model_with_massless_dofs():
    from ssid.semidefinite_modes import normal_modes_semidefinite

    M, K = _qa_chain()
    lam, phi = normal_modes_semidefinite(M, K)
    np.testing.assert_allclose(lam, [5.939982, 66.666667, 120.250495], rtol=1e-6)  # the QA's numbers
    np.testing.assert_allclose(lam, _finite_eig(M, K), rtol=1e-10)
    np.testing.assert_allclose(phi.T @ M @ phi, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(K @ phi, M @ phi * lam, atol=1e-9 * np.abs(K).max())
    # A mass that is singular along no DOF (a consistent-mass-like null vector): the same.
    rng = np.random.default_rng(2)
    B = rng.normal(size=(7, 4))
    M2, K2 = B @ B.T, np.eye(7) * 50 + (lambda A: A @ A.T)(rng.normal(size=(7, 7)))
    lam2, phi2 = normal_modes_semidefinite(M2, K2)
    np.testing.assert_allclose(lam2, _finite_eig(M2, K2), rtol=1e-8)
    np.testing.assert_allclose(phi2.T @ M2 @ phi2, np.eye(4), atol=1e-10)


@pytest.mark.parametrize("M, K, message", [
    (np.diag([1.0, -1.0, 1.0]), np.diag([1.0, 2.0, 3.0]),
     "M is not positive semi-definite (an eigenvalue of -1, a negative mass)"),
    # the middle DOF has neither mass nor stiffness: nothing fixes its motion
    (np.diag([1.0, 0.0, 1.0]), np.diag([100.0, 0.0, 100.0]), "massless direction(s) that K does not hold"),
])
def test_an_indefinite_mass_or_a_massless_mechanism_is_refused(M, K, message):
    from ssid.semidefinite_modes import normal_modes_semidefinite

    with pytest.raises(InputError, match=re.escape(message)):
        normal_modes_semidefinite(M, K)
    with pytest.raises(InputError, match="NaN"):
        normal_modes_semidefinite(np.diag([1.0, np.nan, 1.0]), np.eye(3))


def test_a_lumped_beam_correlates_with_its_guyan_tam(tmp_path):
    """Lumped mass, no rotary inertia: every rotation is massless. Measured at every
    translation, the Guyan TAM omits the massless rotations only and is exact: its modes are
    the beam's, paired with MAC 1 and a cross-orthogonality of the identity."""
    M, K, dofs = beam_model(n_elem=6, lumped=True)
    a = translations(dofs, list(range(1, 8)))
    red = guyan_reduce(M, K, a)
    test = Model(red.M, red.K, None, [dofs[i] for i in a])
    s = correlate_models(test, Model(M, K, None, dofs), tam="guyan").summary
    assert len(s["paired_modes"]) == 7 and min(p["mac"] for p in s["paired_modes"]) > 1 - 1e-9
    assert s["cross_orthogonality"]["pass"] and s["cross_orthogonality"]["max_abs_offdiag"] < 1e-8
    assert max(abs(e) for e in s["freq_error_percent"]) < 1e-8
    assert any(w.startswith("analysis model: M is singular (7 massless direction(s)") for w in s["warnings"])
    # SEREP's target modes are the finite ones: exact as well.
    s = correlate_models(test, Model(M, K, None, dofs), tam="serep").summary
    assert min(p["mac"] for p in s["paired_modes"]) > 1 - 1e-9 and s["cross_orthogonality"]["pass"]
    write_model(tmp_path / "test.h5", test)
    write_model(tmp_path / "fem.h5", Model(M, K, None, dofs))
    status, err = run(["--model", str(tmp_path / "test.h5"), "--model", str(tmp_path / "fem.h5"), "--json",
                       str(tmp_path / "c.json"), "--quiet"])
    assert (status, err) == (0, "")
    assert len(json.loads((tmp_path / "c.json").read_text())["analysis_natural_freq_hz"]) == 7


def test_irs_with_a_singular_guyan_mass_says_what_is_singular(tmp_path):
    """The QA's chain with DOF index 2 massless, retained with both neighbours: its Guyan shape
    moves no mass, M_s is singular, and IRS (which needs the Guyan frequencies M_s^-1 K_s)
    ended in numpy's "A singular matrix detected: slice(s) [0] are singular"."""
    from ssid.tam import irs_reduce

    _, K = _qa_chain()
    M = np.diag([1.0, 2.0, 0.0, 1.0, 3.0, 2.0])
    with pytest.raises(InputError, match=re.escape("the Guyan mass M_s is singular: retained DOF no. 2 (model "
                                                   "index 2) moves no mass")) as info:
        irs_reduce(M, K, [1, 2, 3])
    assert "use Guyan" in str(info.value) and not isinstance(info.value, np.linalg.LinAlgError)
    dofs = [f"{i}+X" for i in range(1, 7)]
    write_model(tmp_path / "fem.h5", Model(M, K, None, dofs))
    write_model(tmp_path / "test.h5", Model(np.diag([2.0, 1.0, 1.0]), K[1:4, 1:4], None, dofs[1:4]))
    status, err = run(["--model", str(tmp_path / "test.h5"), "--model", str(tmp_path / "fem.h5"), "--tam", "irs",
                       "--json", str(tmp_path / "c.json")])
    assert status == 2 and "\n" not in err
    assert err.startswith(f"ssidlab correlate: error: {tmp_path / 'fem.h5'} (analysis model): the Guyan mass M_s "
                          "is singular: retained DOF no. 2 (model index 2)"), err


def test_lumped_masses_with_an_offset_have_their_finite_modes():
    """Point masses offset from the beam's axis (a CONM2 with an offset) couple each node's
    translation and rotation: M is singular with its null space off the coordinates, and
    round-off lets a Cholesky factor through. Trusted, eigh(K, M) gave -1853 and -1175 Hz
    for modes of 7.4 and 17.5 Hz. M's own eigenvalues decide now."""
    from ssid.semidefinite_modes import normal_modes_semidefinite

    Mb, K, dofs = beam_model(n_elem=8, length_m=1.0, lumped=True)
    M = np.zeros_like(Mb)
    for node in range(9):
        m = Mb[2 * node, 2 * node]
        M[2 * node:2 * node + 2, 2 * node:2 * node + 2] = m * np.array([[1.0, 0.37], [0.37, 0.37**2]])
    w = sla.eig(K, M, right=False)
    finite = np.sort(w[np.isfinite(w) & (np.abs(w) < 1e14)].real)
    lam, phi = normal_modes_semidefinite(M, K)
    np.testing.assert_allclose(lam, finite, rtol=1e-7)
    np.testing.assert_allclose(phi.T @ M @ phi, np.eye(lam.size), atol=1e-9)
