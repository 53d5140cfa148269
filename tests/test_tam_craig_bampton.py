"""Craig-Bampton: generalised and physical-coordinate TAMs, the scale-free mode selection,
and the Craig-Bampton form of a model (fixed-interface eigenvalues, boundary stiffness).

Beam of tests/test_tam_models.py; boundary (interface) = the translations at both ends,
measured interior = translations at nodes 3, 5, 7, 9. Tolerances as in test_tam.py: 1e-9
relative for results that are exact in theory.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_tam_models import beam_model, translations

from ssid.craig_bampton import (
    craig_bampton_form,
    craig_bampton_physical,
    craig_bampton_reduce,
    fixed_interface_modes,
)
from ssid.craig_bampton_tam import (
    craig_bampton_tam,
    fixed_interface_contributions,
    pivoted_selection_report,
    select_fixed_interface_modes,
)
from ssid.errors import InputError
from ssid.tam import guyan_reduce, natural_frequencies_hz, normal_modes, reduce_to_tam

EXACT = 1e-9


@pytest.fixture(scope="module")
def setup():
    M, K, dofs = beam_model()
    b = translations(dofs, [1, 11])
    r = translations(dofs, [3, 5, 7, 9])
    return M, K, dofs, b, r


def _target_errors(red, f_targets):
    f = natural_frequencies_hz(red.M, red.K)
    return np.array([np.min(np.abs(f - x)) / x for x in f_targets])


def test_generalised_cb_with_all_fixed_interface_modes_is_exact(setup):
    M, K, _, b, _ = setup
    red = craig_bampton_reduce(M, K, b)
    f = natural_frequencies_hz(M, K)
    assert np.max(np.abs(natural_frequencies_hz(red.M, red.K) - f) / f) < EXACT
    # K_cb = diag(Lambda, K_bb_hat): no stiffness coupling between modes and boundary.
    n_i = K.shape[0] - len(b)
    np.testing.assert_allclose(red.K[:n_i, n_i:], 0, atol=1e-6 * np.abs(red.K).max())


def test_physical_cb_with_every_interior_dof_measured_is_exact(setup):
    M, K, _, b, _ = setup
    a = list(range(M.shape[0]))
    n_i = M.shape[0] - len(b)
    red = craig_bampton_physical(M, K, a, b, np.arange(n_i))
    f = natural_frequencies_hz(M, K)
    assert np.max(np.abs(natural_frequencies_hz(red.M, red.K) - f) / f) < EXACT


def test_physical_cb_is_a_change_of_coordinates_of_the_generalised_one(setup):
    # T_CB2 is invertible: same Ritz space [Phi_n(selected), Psi_c], same frequencies.
    M, K, _, b, r = setup
    modes = [0, 1, 3, 6]
    phys = craig_bampton_physical(M, K, r + b, b, modes)
    gen = craig_bampton_reduce(M, K, b, modes)
    fp = natural_frequencies_hz(phys.M, phys.K)
    fg = natural_frequencies_hz(gen.M, gen.K)
    assert np.max(np.abs(fp - fg) / fg) < EXACT
    np.testing.assert_allclose(phys.T[r + b], np.eye(len(r) + len(b)), atol=1e-9)


def test_contributions_are_scale_free_and_sum_to_one(setup):
    M, K, _, b, _ = setup
    _, phi = normal_modes(M, K)
    _, phi_fi, _ = fixed_interface_modes(M, K, b)
    t = [0, 2, 3, 5, 7]
    c = fixed_interface_contributions(M, K, b, phi[:, t], phi_fi)
    rng = np.random.default_rng(7)
    s_fi = rng.choice([-1, 1], phi_fi.shape[1]) * 10 ** rng.uniform(-6, 6, phi_fi.shape[1])
    s_t = rng.choice([-1, 1], len(t)) * 10 ** rng.uniform(-6, 6, len(t))
    c2 = fixed_interface_contributions(M, K, b, phi[:, t] * s_t, phi_fi * s_fi)
    np.testing.assert_allclose(c2, c, atol=1e-12)
    # Fixed-interface modes are a complete M_ii-orthogonal basis of the interior.
    moving = c.sum(axis=0) > 0
    np.testing.assert_allclose(c.sum(axis=0)[moving], 1.0, atol=1e-9)


def test_rigid_body_target_needs_no_fixed_interface_mode(setup):
    # A rigid-body motion of a free beam is pure constraint-mode motion: zero contribution.
    _, _, _, b, _ = setup
    M0, K0, _ = beam_model(k_ground_n_per_m=(0.0, 0.0))
    lam, phi = normal_modes(M0, K0)
    assert abs(lam[0]) < 1e-6 * lam[2]  # the first two modes are rigid
    c = fixed_interface_contributions(M0, K0, b, phi[:, :2])
    assert np.all(c == 0)


@pytest.mark.parametrize("targets", [[0, 1, 2, 4, 6, 8], [2, 3, 6, 7, 8, 9], [0, 1, 5, 6, 7, 8]])
def test_selection_does_not_change_when_modes_are_rescaled(setup, targets):
    """The report's open issue: the selection must not depend on mode scaling."""
    M, K, _, b, r = setup
    _, phi = normal_modes(M, K)
    _, phi_fi, _ = fixed_interface_modes(M, K, b)
    ref = select_fixed_interface_modes(M, K, r, b, phi[:, targets], phi_fi)
    rng = np.random.default_rng(11)
    for _ in range(5):
        s_fi = rng.choice([-1, 1], phi_fi.shape[1]) * 10 ** rng.uniform(-8, 8, phi_fi.shape[1])
        s_t = rng.choice([-1, 1], len(targets)) * 10 ** rng.uniform(-8, 8, len(targets))
        sel = select_fixed_interface_modes(M, K, r, b, phi[:, targets] * s_t, phi_fi * s_fi)
        np.testing.assert_array_equal(sel.modes, ref.modes)
        np.testing.assert_array_equal(sel.order, ref.order)


def test_report_pivoting_does_depend_on_scaling(setup):
    # The motivation: full pivoting on Phi_nr takes the largest entry first, so a scaled-up
    # mode wins the first pivot whatever its contribution to the targets.
    M, K, _, b, r = setup
    _, phi_fi, i = fixed_interface_modes(M, K, b)
    phi_nr = phi_fi[np.searchsorted(i, r)]
    s = np.ones(phi_fi.shape[1])
    s[11] = 1e6
    assert pivoted_selection_report(phi_nr * s, 4)[0] == 11
    assert pivoted_selection_report(phi_nr, 4)[0] != 11


def test_selection_finds_the_exact_modes_when_targets_lie_in_their_span(setup):
    # Targets built from fixed-interface modes 2, 5, 7 (interior only, boundary at rest) are
    # carried entirely by those modes: the selection must pick them (plus one more).
    M, K, _, b, r = setup
    _, phi_fi, i = fixed_interface_modes(M, K, b)
    phi_t = np.zeros((M.shape[0], 3))
    phi_t[i] = phi_fi[:, [2, 5, 7]] @ np.array([[1.0, 0.3, 0.0], [0.0, 1.0, 0.5], [0.2, 0.0, 1.0]])
    sel = select_fixed_interface_modes(M, K, r, b, phi_t, phi_fi)
    assert {2, 5, 7} <= set(sel.modes.tolist())
    np.testing.assert_allclose(sel.captured, 1.0, atol=1e-9)


def test_selected_modes_represent_high_targets_better_than_the_lowest_modes(setup):
    M, K, _, b, r = setup
    f = natural_frequencies_hz(M, K)
    targets = [2, 3, 6, 7, 8, 9]
    tam = craig_bampton_tam(M, K, r + b, b, targets)
    lowest = craig_bampton_physical(M, K, r + b, b, [0, 1, 2, 3])
    e_sel = _target_errors(tam.reduced, f[targets])
    e_low = _target_errors(lowest, f[targets])
    assert e_sel.mean() < 0.5 * e_low.mean()  # observed 0.13 vs 0.49


def test_cb_form_of_the_cb_tam_returns_the_selected_modes_and_boundary_stiffness(setup):
    # Section 6.5: a model over the measured DOFs (SSID or TAM) in Craig-Bampton form. For
    # the C-B TAM its fixed-interface eigenvalues are exactly the selected ones, and its
    # boundary stiffness is the full model's static stiffness at the interface.
    M, K, _, b, r = setup
    tam = craig_bampton_tam(M, K, r + b, b, [0, 1, 2, 3, 4, 5])
    nb = np.arange(len(r), len(r) + len(b))  # positions of b within the TAM's DOFs
    form = craig_bampton_form(tam.reduced.M, tam.reduced.K, nb)
    lam_sel = tam.fixed_interface_eigenvalues[tam.selection.modes]
    np.testing.assert_allclose(form.eigenvalues, lam_sel, rtol=EXACT)
    full = craig_bampton_form(M, K, b)
    K_static_b = guyan_reduce(M, K, b).K
    np.testing.assert_allclose(full.boundary_stiffness, K_static_b, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(form.boundary_stiffness, K_static_b, rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(full.frequencies_hz, np.sqrt(full.eigenvalues) / (2 * np.pi))


def test_cb_tam_errors(setup):
    M, K, _, b, r = setup
    with pytest.raises(InputError, match="boundary"):
        craig_bampton_physical(M, K, r, b, [0, 1, 2, 3])
    with pytest.raises(InputError, match="one fixed-interface mode per"):
        craig_bampton_physical(M, K, r + b, b, [0, 1])
    with pytest.raises(InputError, match="interface"):
        reduce_to_tam("cb", M, K, r + b)


def test_a_boundary_of_every_dof_or_of_none_is_an_input_error(setup):
    """Every DOF on the boundary leaves no interior: numpy's "attempt to get argmax of an empty
    sequence" from craig_bampton_reduce and craig_bampton_tam. No boundary DOF was a plain
    ValueError naming "retained" (QA)."""
    M, K, dofs, b, r = setup
    every = list(range(len(dofs)))
    with pytest.raises(InputError, match=f"every one of the {len(dofs)} DOFs is a boundary"):
        craig_bampton_reduce(M, K, every)
    with pytest.raises(InputError, match=f"every one of the {len(dofs)} DOFs is a boundary"):
        craig_bampton_tam(M, K, every, every)
    with pytest.raises(InputError, match="boundary must be a non-empty 1-D sequence of DOF indices"):
        craig_bampton_reduce(M, K, [])
    for boundary in ([], None):
        with pytest.raises(InputError, match="the Craig-Bampton TAM needs the interface"):
            craig_bampton_tam(M, K, list(b) + list(r), boundary)
    with pytest.raises(InputError, match="boundary DOF index 99 is outside"):
        craig_bampton_tam(M, K, list(b) + list(r), [b[0], 99])
    # One interior DOF left: a valid model, all of whose fixed-interface modes (one) keep the
    # full model's frequencies exactly (a change of coordinates).
    red = craig_bampton_reduce(M, K, every[1:])
    assert np.max(np.abs(natural_frequencies_hz(red.M, red.K) / natural_frequencies_hz(M, K) - 1)) < EXACT
