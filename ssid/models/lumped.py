"""Lumped spring-mass-damper systems with known M, C, K: the ground truth of the tests.

A chain is the simplest structure whose matrices are known exactly: masses ``m_i`` on a line,
springs ``k_i`` between neighbours, optional springs to ground, and dampers laid out
differently from the springs so that the damping is *not* proportional (complex modes).
"""

from __future__ import annotations

import numpy as np

__all__ = ["chain_model", "example_system", "frf_on_test_stand"]


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


def mount_on_test_stand(
    M: np.ndarray,
    C: np.ndarray,
    K: np.ndarray,
    dofs: list[str],
    reactions: list[str],
    stand_mass_kg: float = 20.0,
    stand_k_n_per_m: float = 2e6,
    stand_c_n_s_per_m: float = 40.0,
    ground_k_n_per_m: float = 5e6,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """A substructure bolted to a flexible test stand: the coupled M, C, K and DOF labels.

    Each reaction DOF ``r`` of the substructure is tied by a spring-damper (``stand_k``,
    ``stand_c``) to its own stand mass (DOF ``"stand@r"``, appended after the substructure's),
    which sits on a spring to ground: the stand has dynamics of its own, as in report
    section 6.6.
    """
    from ..frf import selection_matrix

    n = M.shape[0]
    nr = len(reactions)
    Mc = np.zeros((n + nr, n + nr))
    Cc = np.zeros_like(Mc)
    Kc = np.zeros_like(Mc)
    Mc[:n, :n], Cc[:n, :n], Kc[:n, :n] = M, C, K
    Mc[n:, n:] = stand_mass_kg * np.eye(nr)
    # Interface spring-dampers: element matrix [[1, -1], [-1, 1]] between x_r and x_stand.
    T = np.hstack([selection_matrix(dofs, reactions).T, -np.eye(nr)])  # (nr, n + nr): x_r - x_t
    Kc += stand_k_n_per_m * T.T @ T
    Cc += stand_c_n_s_per_m * T.T @ T
    Kc[n:, n:] += ground_k_n_per_m * np.eye(nr)
    return Mc, Cc, Kc, list(dofs) + [f"stand@{r}" for r in reactions]


def frf_on_test_stand(
    M: np.ndarray,
    C: np.ndarray,
    K: np.ndarray,
    dofs: list[str],
    inputs: list[str],
    reactions: list[str],
    freq_hz: np.ndarray,
    stand_mass_kg: float = 20.0,
    stand_k_n_per_m: float = 2e6,
    stand_c_n_s_per_m: float = 40.0,
    ground_k_n_per_m: float = 5e6,
):
    """Accelerances and interface reactions of a substructure bolted to a flexible test stand.

    The stand as in :func:`mount_on_test_stand`. The substructure's own M, C, K exclude the
    stand, so SSID with the measured reactions must recover them alone.

    Returns
    -------
    FRFData with ``H`` at every substructure DOF, ``H_reaction`` the force the stand exerts
    on the substructure at each reaction DOF per unit input force (contract sign convention).
    """
    from ..frf import FRFData, selection_matrix

    n = M.shape[0]
    nr = len(reactions)
    Mc, Cc, Kc, _ = mount_on_test_stand(M, C, K, dofs, reactions, stand_mass_kg, stand_k_n_per_m,
                                        stand_c_n_s_per_m, ground_k_n_per_m)
    T = np.hstack([selection_matrix(dofs, reactions).T, -np.eye(nr)])  # relative motion x_r - x_t
    freq_hz = np.asarray(freq_hz, dtype=float)
    w = 2 * np.pi * freq_hz
    D = np.vstack([selection_matrix(dofs, inputs), np.zeros((nr, len(inputs)))])
    Z = Kc[None] - (w**2)[:, None, None] * Mc[None] + 1j * w[:, None, None] * Cc[None]
    X = np.linalg.solve(Z, np.broadcast_to(D.astype(complex), (w.size,) + D.shape))
    rel = np.einsum("rq,kqj->krj", T, X)
    Hr = -(stand_k_n_per_m + 1j * w[:, None, None] * stand_c_n_s_per_m) * rel
    H = -(w**2)[:, None, None] * X[:, :n]
    return FRFData(
        freq_hz=freq_hz, H=H, outputs=list(dofs), inputs=list(inputs),
        H_reaction=Hr, reactions=list(reactions),
    )
