"""Lumped spring-mass-damper systems with known M, C, K: the ground truth of the tests.

A chain is the simplest structure whose matrices are known exactly: masses ``m_i`` on a line,
springs ``k_i`` between neighbours, optional springs to ground, and dampers laid out
differently from the springs so that the damping is *not* proportional (complex modes).
"""

from __future__ import annotations

import numpy as np

__all__ = ["chain_model", "example_system"]


def _chain_matrix(n: int, between: np.ndarray, to_ground: np.ndarray) -> np.ndarray:
    """Assemble a tridiagonal chain matrix from element values (springs or dampers)."""
    A = np.diag(np.asarray(to_ground, dtype=float)).copy()
    for e, v in enumerate(np.asarray(between, dtype=float)):
        i, j = e, e + 1
        A[i, i] += v
        A[j, j] += v
        A[i, j] -= v
        A[j, i] -= v
    return A


def chain_model(
    masses_kg: np.ndarray,
    k_between_n_per_m: np.ndarray,
    k_ground_n_per_m: np.ndarray,
    c_between_n_s_per_m: np.ndarray,
    c_ground_n_s_per_m: np.ndarray,
    extra_springs: list[tuple[int, int, float]] = (),
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """M, C, K of a chain of ``n`` masses, with optional extra springs ``(i, j, k)``.

    Returns
    -------
    (M, C, K, dofs) with M, C, K (n, n) and DOF labels ``"1+Z" ... "n+Z"``.
    """
    m = np.asarray(masses_kg, dtype=float)
    n = m.size
    M = np.diag(m)
    K = _chain_matrix(n, k_between_n_per_m, k_ground_n_per_m)
    C = _chain_matrix(n, c_between_n_s_per_m, c_ground_n_s_per_m)
    for i, j, k in extra_springs:
        K[i, i] += k
        K[j, j] += k
        K[i, j] -= k
        K[j, i] -= k
    return M, C, K, [f"{i + 1}+Z" for i in range(n)]


def example_system(n: int = 14, seed: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """A seeded, non-proportionally damped chain with modes spread over about two decades.

    Masses 0.5-2 kg, springs graded from stiff to soft along the chain so the modes spread
    from a few Hz to a few hundred Hz, two cross springs that break the pure chain pattern,
    and dampers placed unlike the springs (damping ratios of roughly 0.5-3 %).
    """
    rng = np.random.default_rng(seed)
    m = rng.uniform(0.5, 2.0, n)
    grade = np.geomspace(4e6, 4e4, n - 1)
    kb = grade * rng.uniform(0.7, 1.3, n - 1)
    kg = np.zeros(n)
    kg[0] = 6e4
    kg[-1] = 2e4
    cb = rng.uniform(0.2, 1.0, n - 1) * np.sqrt(kb * m[:-1]) * 0.06
    cg = np.zeros(n)
    cg[n // 2] = 20.0
    extra = [(1, n // 2, 3e4), (n // 3, n - 2, 1e4)]
    return chain_model(m, kb, kg, cb, cg, extra)
