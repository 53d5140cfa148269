"""Local physical effects added to a model's M, C, K (the contract's effect table).

One implementation serves both the simulated lab's hidden effects (``sim_devices``) and the
discrepancy workflow's candidates (``ssid.discrepancy``), so that what the lab hides and what
the workflow fits are the same physics.
"""

from __future__ import annotations

import numpy as np

__all__ = ["add_effect"]


def _index(dofs: list[str], label: str) -> int:
    try:
        return dofs.index(label)
    except ValueError:
        raise ValueError(f"effect at unknown DOF {label!r}") from None


def _add_element(A: np.ndarray, i: int, j: int, value: float) -> None:
    """Add a two-node element ``value * [[1, -1], [-1, 1]]`` between DOFs ``i`` and ``j``."""
    A[i, i] += value
    A[j, j] += value
    A[i, j] -= value
    A[j, i] -= value


def _oscillator_label(dofs: list[str], base: str) -> str:
    """A unique label for an oscillator's own DOF: ``"<dof>~osc<k>"``."""
    k = 1
    while f"{base}~osc{k}" in dofs:
        k += 1
    return f"{base}~osc{k}"


def add_effect(
    M: np.ndarray,
    C: np.ndarray | None,
    K: np.ndarray,
    dofs: list[str],
    name: str,
    at: tuple[str, ...] | list[str],
    parameters: dict,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, list[str]]:
    """M, C, K and labels with one effect added (new arrays; the inputs are not changed).

    Parameters
    ----------
    name : str
        ``added_mass``, ``grounded_spring``, ``coupling_spring``, ``grounded_damper``,
        ``attached_oscillator`` or ``none``.
    at : labels of the DOF(s) it acts at (two for ``coupling_spring``).
    parameters : dict
        ``mass_kg``, ``stiffness_n_per_m``, ``damping_n_s_per_m`` as the effect takes them.

    ``C`` stays None when it was None and the effect adds no damping. An attached oscillator
    appends one DOF (labelled ``"<dof>~osc<k>"``) to the end.
    """
    M = np.array(M, dtype=float)
    K = np.array(K, dtype=float)
    C = None if C is None else np.array(C, dtype=float)
    dofs = list(dofs)
    p = parameters
    if name == "none":
        return M, C, K, dofs
    i = _index(dofs, at[0])
    if name == "added_mass":
        M[i, i] += p["mass_kg"]
    elif name == "grounded_spring":
        K[i, i] += p["stiffness_n_per_m"]
    elif name == "grounded_damper":
        C = np.zeros_like(M) if C is None else C
        C[i, i] += p["damping_n_s_per_m"]
    elif name == "coupling_spring":
        _add_element(K, i, _index(dofs, at[1]), p["stiffness_n_per_m"])
    elif name == "attached_oscillator":
        n = M.shape[0]
        C = np.zeros_like(M) if C is None else C
        M, C, K = (np.pad(A, ((0, 1), (0, 1))) for A in (M, C, K))
        M[n, n] = p["mass_kg"]
        _add_element(K, i, n, p["stiffness_n_per_m"])
        _add_element(C, i, n, p.get("damping_n_s_per_m", 0.0))
        dofs.append(_oscillator_label(dofs, at[0]))
    else:
        raise ValueError(f"unknown effect {name!r}")
    return M, C, K, dofs
