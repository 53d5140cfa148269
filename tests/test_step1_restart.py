"""The output-error refinement restarted from oscillatory roots (``ssid.step1_refine.oscillatory_start``).

A mode the lines barely resolve can leave the refinement in a basin where it is a pair of real
roots; the restart turns them into an oscillatory pair and the lower output error decides.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla

from ssid.frf import accelerance_from_model
from ssid.identify import identify_mck
from ssid.models.payload import INTERFACE_DOFS, modal_damping, payload_simulator, target_modes
from ssid.noise import report_noise_frf
from ssid.step1 import Step1Estimate
from ssid.step1_refine import oscillatory_start


def companion_roots(est: Step1Estimate) -> np.ndarray:
    n = est.C_hat.shape[0]
    return np.linalg.eigvals(np.block([[np.zeros((n, n)), np.eye(n)], [-est.K_hat, -est.C_hat]]))


def estimate_with_roots(lam: np.ndarray, seed: int = 0) -> Step1Estimate:
    """The step-1 matrices whose companion has the roots ``lam`` (closed under conjugation)
    on random shapes ``[phi; lambda phi]`` (a conjugate root on the conjugate shape)."""
    rng = np.random.default_rng(seed)
    n = lam.size // 2
    V = np.empty((2 * n, 2 * n), dtype=complex)
    done = set()
    for i, r in enumerate(lam):
        if i in done:
            continue
        phi = rng.standard_normal(n) + (1j * rng.standard_normal(n) if r.imag else 0)
        V[:, i] = np.concatenate([phi, r * phi])
        if r.imag:
            j = next(k for k in range(i + 1, lam.size) if k not in done and np.isclose(lam[k], np.conj(r)))
            V[:, j] = V[:, i].conj()
            done.add(j)
    comp = (V @ np.diag(lam) @ np.linalg.inv(V)).real
    return Step1Estimate(-comp[n:, n:], -comp[n:, :n], np.eye(n)[:, :1], np.zeros((n, 0)))


def test_real_pair_becomes_the_oscillatory_pair_of_its_stiffness():
    """Roots -10.9 and +10.4 rad/s (an unstable pair: stiffness l1 l2 < 0) become
    w (-zeta +- j sqrt(1 - zeta^2)) with w = sqrt(|l1 l2|), zeta = |l1 + l2| / (2 w); the
    two oscillatory modes are kept to rounding."""
    others = np.array([-3 + 400j, -3 - 400j, -20 + 2000j, -20 - 2000j])
    lam = np.concatenate([others, [-10.9, 10.4]])
    est = estimate_with_roots(lam)
    start = oscillatory_start(est)
    w = np.sqrt(10.9 * 10.4)
    zeta = 0.5 / (2 * w)
    want = np.concatenate([others, w * (-zeta + np.array([1j, -1j]) * np.sqrt(1 - zeta**2))])
    got = companion_roots(start)
    assert np.allclose(np.sort_complex(got), np.sort_complex(want), rtol=1e-9, atol=0)
    assert np.array_equal(start.Df_hat, est.Df_hat) and np.array_equal(start.Dr_hat, est.Dr_hat)


def test_no_real_roots_no_restart():
    est = estimate_with_roots(np.array([-3 + 400j, -3 - 400j, -20 + 2000j, -20 - 2000j]))
    assert oscillatory_start(est) is None


@pytest.mark.parametrize("seed", [2])
def test_suspension_mode_between_the_first_lines_is_found(seed):
    """The 10-DOF payload model (the EfI sensors of docs/replication.md), 1-551 Hz, 512
    lines, the report's noise, seed 2: the 1.29 Hz suspension mode lies between the first two
    lines (1.0 and 2.08 Hz). The refinement ends with real roots in its place; from the
    restart it reaches an output error 1.79 times lower and all ten target modes, measured
    within 0.51 % (seeds 1 and 3, no restart needed: 0.58, 0.63 %; the worst are the three
    suspension modes). The tolerance, 1.3 %, is twice the other seeds' worst; the cost must
    fall below 0.7 times.

    Measured with the flat noise levels taken from the data's differences where the
    residuals hold model error (``ssid.step1_ml``, step 4). With the residual levels alone
    the restart ended 2.7 times lower and the targets within 0.071 % (seeds 1, 3: 0.28,
    0.24 %): on this record that change costs the suspension modes accuracy
    (docs/replication.md, section 3's notes)."""
    p = payload_simulator()
    C = modal_damping(p.M, p.K, 0.02)
    sensors = ["1+Z", "2+Z", "3+Z", "4+Z", "5+Z", "6+Z", "7+Z", "8+Z", "17+Z", "18+Z"]
    frf = accelerance_from_model(p.M, C, p.K, p.dofs, np.linspace(1, 551, 512), sensors, INTERFACE_DOFS)
    r = identify_mck(report_noise_frf(frf, seed=seed))
    restart = r.info["real_root_restart"]
    assert restart["kept"] and restart["cost_restart"] < 0.7 * restart["cost"]
    assert r.real_roots.size == 0
    targets = np.sqrt(sla.eigh(p.K, p.M, eigvals_only=True)[target_modes(p, 10)]) / (2 * np.pi)
    assert r.natural_freq_hz.size == 10
    assert np.allclose(r.natural_freq_hz, targets, rtol=1.3e-2)
