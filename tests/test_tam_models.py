"""Small FE models with known answers for the TAM and correlation tests (no tests here).

An Euler-Bernoulli beam in the x-z plane: each node has a translation ``"<node>+Z"`` and a
rotation ``"<node>+RY"``. With a lumped mass matrix the rotations carry no mass, so Guyan
reduction to the translations is exact -- the classical check of a static TAM.
"""

from __future__ import annotations

import numpy as np


def beam_model(
    n_elem: int = 10,
    length_m: float = 1.5,
    ei_n_m2: float = 2.0e3,
    rho_a_kg_per_m: float = 2.7,
    lumped: bool = False,
    k_ground_n_per_m: tuple[float, float] = (5.0e3, 5.0e3),
    extra_mass: dict[int, float] | None = None,
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """M, K (2 (n_elem + 1) square) and labels of a beam on springs to ground at both ends.

    Parameters
    ----------
    lumped : bool
        Lumped translational mass, no rotary inertia (True), or consistent mass (False).
    k_ground_n_per_m : (first node, last node)
        Translational springs to ground; with both positive the beam is statically stable.
    extra_mass : {node: kg}, optional
        Point masses on translations.
    """
    n_node = n_elem + 1
    h = length_m / n_elem
    ke = ei_n_m2 / h**3 * np.array(
        [[12, 6 * h, -12, 6 * h], [6 * h, 4 * h * h, -6 * h, 2 * h * h],
         [-12, -6 * h, 12, -6 * h], [6 * h, 2 * h * h, -6 * h, 4 * h * h]]
    )
    if lumped:
        me = rho_a_kg_per_m * h / 2 * np.diag([1.0, 0.0, 1.0, 0.0])
    else:
        me = rho_a_kg_per_m * h / 420 * np.array(
            [[156, 22 * h, 54, -13 * h], [22 * h, 4 * h * h, 13 * h, -3 * h * h],
             [54, 13 * h, 156, -22 * h], [-13 * h, -3 * h * h, -22 * h, 4 * h * h]]
        )
    n = 2 * n_node
    M = np.zeros((n, n))
    K = np.zeros((n, n))
    for e in range(n_elem):
        idx = np.arange(2 * e, 2 * e + 4)
        M[np.ix_(idx, idx)] += me
        K[np.ix_(idx, idx)] += ke
    K[0, 0] += k_ground_n_per_m[0]
    K[2 * n_elem, 2 * n_elem] += k_ground_n_per_m[1]
    for node, m in (extra_mass or {}).items():
        M[2 * node, 2 * node] += m
    dofs = [f"{k}+{c}" for k in range(1, n_node + 1) for c in ("Z", "RY")]
    return M, K, dofs


def translations(dofs: list[str], nodes: list[int]) -> list[int]:
    """Indices of the ``+Z`` DOFs of 1-based ``nodes``."""
    return [dofs.index(f"{k}+Z") for k in nodes]
