"""The structured (memory-saving) normal equations equal their explicit definitions.

Step 1's ``sum kron(W, G)`` and step 2's Hadamard form of Eq. 3.23 never build the tall
matrices; these tests build them on a small case and compare.
"""

from __future__ import annotations

import numpy as np
import pytest

import ssid.step1 as s1
import ssid.step1_refine as s1r
from ssid.models import example_system, frf_on_test_stand
from ssid.solvers import solve_ls, solve_tls
import ssid.step2 as step2
from ssid.step2 import modal_scale_factors, state_space_modes


@pytest.fixture(scope="module")
def small():
    M, C, K, dofs = example_system(4, seed=5)
    frf = frf_on_test_stand(M, C, K, dofs, [dofs[1]], [dofs[3]], np.linspace(5, 400, 37))
    return M, C, K, dofs, frf


def test_solve_tls_exact_data():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((50, 5))
    X = rng.standard_normal((5, 3))
    assert np.allclose(solve_tls(A, A @ X), X, atol=1e-10)
    assert np.allclose(solve_tls(A, A @ X, n_exact=2), X, atol=1e-10)
    assert np.allclose(solve_ls(A, A @ X), X, atol=1e-10)


def test_mixed_tls_keeps_exact_columns_exact():
    """Noise only in the non-exact columns: mixed LS-TLS beats plain TLS on average."""
    rng = np.random.default_rng(1)
    errs_plain, errs_mixed = [], []
    for _ in range(40):
        A0 = rng.standard_normal((200, 4))
        X = rng.standard_normal((4, 1))
        B = A0 @ X + 0.05 * rng.standard_normal((200, 1))
        A = A0.copy()
        A[:, 2:] += 0.05 * rng.standard_normal((200, 2))
        errs_plain.append(np.linalg.norm(solve_tls(A, B) - X))
        errs_mixed.append(np.linalg.norm(solve_tls(A, B, n_exact=2) - X))
    assert np.mean(errs_mixed) < np.mean(errs_plain)


def test_step1_normal_equations_equal_explicit_jacobian(small):
    *_, frf = small
    rng = np.random.default_rng(2)
    d = s1.step1_data(frf, weight=rng.uniform(0.5, 2.0, frf.H.shape))
    est = s1.estimate_equation_error(d, "ls")
    est = s1.Step1Estimate.from_x(est.to_x() * (1 + 0.01 * rng.standard_normal(est.to_x().shape)),
                                  d.n, d.n_in)
    Hm = s1.predict_accelerance(d, est)
    Ainv = np.linalg.inv(s1._dynamic_matrix(d, est))
    Z = s1.step1_regressors(d, Hm)
    w2 = d.weight**2
    W = np.einsum("kia,kij,kic->kjac", Ainv.conj(), w2, Ainv)
    V = np.einsum("kia,kij->kja", Ainv.conj(), w2 * (d.H - Hm))
    ne = s1r._NormalEquations(d.n, d.p)
    for sl in (slice(0, 7), slice(7, None)):  # accumulated over two blocks of lines
        ne.add(Z[sl], W[sl], V[sl])
    N, g = ne.matrix()
    # Explicit Jacobian of r + A^-1 dX z, rows (k, i, j), columns vec(dX) row-major.
    n, p = d.n, d.p
    L = d.omega.size
    J = np.einsum("kia,kjb->kijab", Ainv, Z).reshape(L * n * d.n_in, n * p)
    w = np.sqrt(w2).reshape(-1)
    Jw = J * w[:, None]
    rw = (d.H - Hm).reshape(-1) * w
    assert np.allclose(N, (Jw.conj().T @ Jw).real, rtol=1e-9, atol=1e-12 * np.abs(N).max())
    assert np.allclose(g, (Jw.conj().T @ rw).real, rtol=1e-9, atol=1e-12 * np.abs(g).max())


@pytest.mark.parametrize("weights", ["uniform", "per_value", "chunked"])
def test_step2_structured_normal_equations(small, weights, monkeypatch):
    """Eq. 3.23 solved through its Hadamard structure (or in chunks, for weights that do not
    factor) equals the explicit weighted LS."""
    M, C, K, dofs, frf = small
    if weights == "chunked":
        monkeypatch.setattr(step2, "_factor_weights", lambda w2, max_terms=4: None)
    rng = np.random.default_rng(3)
    wt = None if weights == "uniform" else rng.uniform(0.5, 2.0, frf.H.shape)
    d = s1.step1_data(frf, weight=wt)
    est = s1.estimate_equation_error(d, "ls")
    modes = state_space_modes(est.C_hat, est.K_hat)
    u = modal_scale_factors(d, modes)
    # Explicit E of Eq. 3.23/3.24 with conjugate-pair parametrisation, solved by lstsq.
    th = modes.theta_x
    w = d.omega[:, None]
    R = -(w**2) / (1j * w - modes.lam[None, :])
    q = th[d.in_idx][None] + np.einsum("mr,kmj->kjr", th[d.r_idx], d.Hr)
    E = np.einsum("kr,ir,kjr->kijr", R, th, q).reshape(-1, th.shape[1])
    y = d.H.reshape(-1)
    sw = d.weight.reshape(-1)
    m = modes.n_pairs
    T = np.zeros((2 * m, 2 * m), dtype=complex)
    T[:m, :m] = np.eye(m)
    T[:m, m:] = 1j * np.eye(m)
    T[m:, :m] = np.eye(m)
    T[m:, m:] = -1j * np.eye(m)
    ET = (E @ T) * sw[:, None]
    A = np.vstack([ET.real, ET.imag])
    b = np.concatenate([(y * sw).real, (y * sw).imag])
    v = np.linalg.lstsq(A, b, rcond=None)[0]
    assert np.allclose(u, T @ v, rtol=1e-7)
    assert np.allclose(u[m:], u[:m].conj())


def test_accelerance_under_test_loads_reproduces_the_stand_frf():
    """The free substructure's model loaded by the measured reactions gives back what was
    measured on the stand (coupled model, exact), and without reactions the free FRF."""
    from ssid.frf import accelerance_from_model, accelerance_under_test_loads

    M, C, K, dofs = example_system(5, seed=3)
    f = np.linspace(5, 400, 41)
    on_stand = frf_on_test_stand(M, C, K, dofs, [dofs[1], dofs[4]], [dofs[0], dofs[3]], f)
    H = accelerance_under_test_loads(M, C, K, dofs, on_stand)
    assert H.shape == on_stand.H.shape
    assert np.max(np.abs(H - on_stand.H)) < 1e-9 * np.max(np.abs(on_stand.H))
    free = accelerance_from_model(M, C, K, dofs, f, dofs, [dofs[1], dofs[4]])
    assert np.allclose(accelerance_under_test_loads(M, C, K, dofs, free), free.H, rtol=1e-10, atol=0)
    # and the stand matters: the free FRF is far from the measured one
    assert np.max(np.abs(free.H - on_stand.H)) > 0.1 * np.max(np.abs(on_stand.H))
