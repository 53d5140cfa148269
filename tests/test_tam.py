"""Guyan, IRS, SEREP and hybrid TAMs: each is exact in the limit where theory says it must be.

Models are Euler-Bernoulli beams (tests/test_tam_models.py): 11 nodes, translation and
rotation at each, on soft springs at both ends, first modes from ~7 Hz. Frequencies are
compared relatively; "exact" means 1e-9 (eigensolutions of 22x22 matrices with condition
numbers ~1e8 keep ~7-8 digits in the worst mode, far better in the rest: 1e-9 on the modes
checked leaves a margin of 100 over what we observe while any formula error shows at 1e-3).
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from test_tam_models import beam_model, translations

from ssid.errors import InputError
from ssid.tam import (
    guyan_reduce,
    guyan_transform,
    hybrid_tam,
    irs_reduce,
    natural_frequencies_hz,
    normal_modes,
    reduce_to_tam,
    serep_reduce,
)

EXACT = 1e-9


def _rel(a, b):
    return np.max(np.abs(np.asarray(a) - np.asarray(b)) / np.abs(np.asarray(b)))


def _finite_frequencies_hz(M, K):
    """Finite natural frequencies of (K, M) with a singular M (massless DOFs), ascending."""
    import scipy.linalg as sla

    lam = sla.eig(K, M, right=False)
    lam = lam[np.isfinite(lam)].real
    return np.sort(np.sqrt(lam)) / (2 * np.pi)


@pytest.fixture(scope="module")
def beam():
    return beam_model()


@pytest.mark.parametrize("method", ["guyan", "irs", "serep", "hybrid"])
def test_transform_is_identity_at_retained_rows(beam, method):
    M, K, dofs = beam
    a = translations(dofs, [11, 1, 6, 3, 8, 9])  # deliberately not in DOF order
    T = reduce_to_tam(method, M, K, a).T
    np.testing.assert_allclose(T[a], np.eye(len(a)), atol=1e-9)


def test_guyan_exact_when_omitted_dofs_are_massless():
    # Lumped mass: the rotations carry no inertia, so condensing them out is exact (Guyan's
    # assumption holds exactly); the full model has only as many finite modes as translations.
    M, K, dofs = beam_model(lumped=True)
    a = translations(dofs, range(1, 12))
    red = guyan_reduce(M, K, a)
    f_full = _finite_frequencies_hz(M, K)
    assert f_full.size == len(a)
    assert _rel(natural_frequencies_hz(red.M, red.K), f_full) < EXACT


def test_irs_equals_guyan_when_omitted_dofs_are_massless():
    M, K, dofs = beam_model(lumped=True)
    a = translations(dofs, range(1, 12))
    np.testing.assert_allclose(irs_reduce(M, K, a).T, guyan_transform(K, a), atol=1e-12)


def test_guyan_and_irs_are_upper_bounds_and_irs_is_closer(beam):
    M, K, dofs = beam
    a = translations(dofs, [1, 3, 5, 7, 9, 11])
    f = natural_frequencies_hz(M, K)[: len(a)]
    fg = natural_frequencies_hz(*guyan_reduce(M, K, a)[:2])
    fi = natural_frequencies_hz(*irs_reduce(M, K, a)[:2])
    # Rayleigh-Ritz: a reduced model never lies below the full one (1e-9: the eigensolver's
    # round-off on these ill-conditioned pencils is ~1e-10, as observed).
    assert np.all(fg >= f * (1 - EXACT)) and np.all(fi >= f * (1 - EXACT))
    # IRS corrects the omitted inertia: closer on every one of the six modes.
    assert np.all(np.abs(fi - f) <= np.abs(fg - f))
    assert np.abs(fi - f)[:3].max() / f[2] < 1e-6  # the lowest modes nearly exact


def test_serep_exact_for_target_modes_even_non_consecutive(beam):
    M, K, dofs = beam
    a = translations(dofs, [1, 2, 4, 6, 8, 11])
    f = natural_frequencies_hz(M, K)
    targets = [0, 1, 2, 4, 6, 9]  # skips modes, as the report's target modes do
    red = serep_reduce(M, K, a, targets)
    assert _rel(natural_frequencies_hz(red.M, red.K), f[targets]) < EXACT
    # The TAM's modes are the target modes' retained partitions.
    _, phi = normal_modes(M, K)
    _, phi_tam = normal_modes(red.M, red.K)
    for k, t in enumerate(targets):
        c = phi_tam[:, k] @ phi[a, t] / (np.linalg.norm(phi_tam[:, k]) * np.linalg.norm(phi[a, t]))
        assert abs(c) > 1 - 1e-9


def test_hybrid_keeps_fewer_target_modes_exact_and_stays_full_rank(beam):
    M, K, dofs = beam
    a = translations(dofs, [1, 3, 5, 7, 9, 11])
    f = natural_frequencies_hz(M, K)
    targets = [0, 1, 3]
    red = hybrid_tam(M, K, a, targets)
    f_h = natural_frequencies_hz(red.M, red.K)  # would fail if M_a were singular
    for t in targets:
        assert np.min(np.abs(f_h - f[t])) / f[t] < EXACT
    # Its transformation reproduces every target mode from the mode's retained partition.
    _, phi = normal_modes(M, K)
    np.testing.assert_allclose(red.T @ phi[a][:, targets], phi[:, targets], atol=1e-8)


def test_hybrid_with_all_targets_is_serep(beam):
    M, K, dofs = beam
    a = translations(dofs, [1, 3, 5, 7, 9, 11])
    np.testing.assert_allclose(hybrid_tam(M, K, a).T, serep_reduce(M, K, a).T, atol=1e-8)


def test_omitted_free_part_is_a_clear_error():
    # Springs to ground only at node 1: omitting node 1 and keeping none of the beam's
    # translations leaves K_oo singular (a free beam) -> one-line InputError.
    M, K, dofs = beam_model(k_ground_n_per_m=(0.0, 0.0))
    a = [dofs.index("1+RY")]
    with pytest.raises(InputError, match="K_oo is singular"):
        guyan_reduce(M, K, a)


def test_serep_refuses_dependent_targets(beam):
    M, K, dofs = beam
    a = translations(dofs, [6])
    # At mid-span the symmetric modes 1 and 3 have no slope: at (6+Z, 6+RY) both read
    # (x, 0), so they cannot be told apart.
    with pytest.raises(InputError, match="not linearly independent"):
        serep_reduce(M, K, a + [dofs.index("6+RY")], [0, 2])
    with pytest.raises(InputError, match="at most as many"):
        serep_reduce(M, K, a, [0, 1])


def _chain(n, fixed_ends):
    """``n`` unit masses joined by 1e4 N/m springs, with a spring to ground at each end when
    ``fixed_ends`` (fixed-fixed) or none (free-free)."""
    K = np.zeros((n, n))
    for i in range(n - 1):
        K[np.ix_([i, i + 1], [i, i + 1])] += 1e4 * np.array([[1.0, -1.0], [-1.0, 1.0]])
    if fixed_ends:
        K[0, 0] += 1e4
        K[-1, -1] += 1e4
    return np.eye(n), K


@pytest.mark.parametrize("reduce", [serep_reduce, hybrid_tam])
def test_a_target_mode_with_a_node_at_every_retained_dof_is_refused(reduce):
    """Free-free 3-mass chain: mode 2 is (1, 0, -1), at rest at the middle mass. Fixed-fixed
    7-mass chain: mode 4 is sin(4 pi j / 8), at rest at masses 2, 4 and 6. Retained there, the
    mode's partition is round-off (~1e-16 of the mode): SEREP's T was ~1e16 and the TAM mass
    ~1e32 instead of an error, as the singular values were only compared with each other."""
    M, K = _chain(3, fixed_ends=False)
    with pytest.raises(InputError, match="target mode 2 is not observable at the retained DOFs"):
        reduce(M, K, [1], [1])
    M, K = _chain(7, fixed_ends=True)
    _, phi = normal_modes(M, K)
    assert np.abs(phi[[1, 3, 5], 3]).max() < 1e-14 * np.abs(phi[:, 3]).max()  # the nodes
    with pytest.raises(InputError, match="target mode 4 is not observable"):
        reduce(M, K, [1, 3, 5], [3])
    with pytest.raises(InputError, match="target mode 4 is not observable"):
        reduce(M, K, [1, 3, 5], [0, 3])  # named among targets the DOFs see
    # Modes 1-3 move there: the TAM holds them exactly (T rebuilds each from its partition).
    red = reduce(M, K, [1, 3, 5], [0, 1, 2])
    np.testing.assert_allclose(red.T @ phi[[1, 3, 5]][:, :3], phi[:, :3], atol=1e-12)


_BAD_INPUT = [
    # (what is wrong, M and K of a 6-mass chain -> the bad ones, retained, message)
    ("NaN in K", lambda M, K: (M, K * np.nan), [0, 2], "model: K holds NaN or Inf in 36 value(s)"),
    ("M not square", lambda M, K: (np.ones((6, 5)), K), [0, 2], "model: M must be a square matrix, got shape (6, 5)"),
    ("K of another size", lambda M, K: (M, K[:5, :5]), [0, 2], "model: K is 5 x 5 but there are 6 dofs"),
    ("K not symmetric", lambda M, K: (M, K + np.triu(np.ones((6, 6)))), [0, 2], "model: K is not symmetric"),
    ("a fractional index", lambda M, K: (M, K), [0.5, 2], "retained DOF indices must be whole numbers, got 0.5"),
    ("an index past the end", lambda M, K: (M, K), [0, 7], "retained DOF index 7 is outside 0..5"),
    ("a negative index", lambda M, K: (M, K), [-1, 2], "retained DOF index -1 is outside 0..5"),
    ("an index twice", lambda M, K: (M, K), [2, 2], "retained DOF index 2 is given twice"),
    ("no index", lambda M, K: (M, K), [], "retained must be a non-empty 1-D sequence of DOF indices"),
]


@pytest.mark.parametrize("method", ["guyan", "irs", "serep", "hybrid"])
@pytest.mark.parametrize("case, bad, retained, message", _BAD_INPUT, ids=[c[0] for c in _BAD_INPUT])
def test_bad_matrices_and_dof_indices_are_input_errors(method, case, bad, retained, message):
    """Each was a raw numpy/scipy error (NaN: "SVD did not converge"; M not square: matmul's
    core-dimension mismatch), a plain ValueError, or worse an answer: 0.5 was truncated to DOF 0
    and an asymmetric K was reduced as given (QA)."""
    M, K = bad(*_chain(6, fixed_ends=True))
    with pytest.raises(InputError, match=re.escape(message)):
        reduce_to_tam(method, M, K, retained)


def test_normal_modes_of_a_mass_that_is_not_positive_definite_are_an_input_error():
    """scipy's "The leading minor of order 1 of B is not positive definite" reached a caller of
    normal_modes as a LinAlgError (QA). It is an InputError now, and still a LinAlgError: the
    callers that name the model in their own message (correlate, place, discrepancy) catch it."""
    M, K = _chain(6, fixed_ends=True)
    for bad in (-M, np.diag([1.0, 1.0, 0.0, 1.0, 1.0, 1.0])):  # negative definite; a massless DOF
        with pytest.raises(InputError, match="M is not positive definite") as info:
            normal_modes(bad, K)
        assert isinstance(info.value, np.linalg.LinAlgError)
    with pytest.raises(InputError, match="no normal modes of these M, K: array must not contain infs or NaNs"):
        normal_modes(M, K * np.nan)
    lam, _ = normal_modes(M, K)  # and a good model still has its modes: 4 k sin^2(j pi / 14) / m
    np.testing.assert_allclose(lam, 4e4 * np.sin(np.arange(1, 7) * np.pi / 14) ** 2, rtol=1e-12)


def test_unknown_tam_name(beam):
    M, K, _ = beam
    with pytest.raises(ValueError, match="unknown TAM"):
        reduce_to_tam("magic", M, K, [0, 2])
