"""Euler-Bernoulli beam/torsion elements for plane grillages (out-of-plane motion).

A grillage lies in the X-Y plane and moves out of it: each node has a Z translation and
rotations about X and Y (the payload simulator's DOF set). Each element combines
Euler-Bernoulli bending in its local x'-z plane with St-Venant torsion about its axis;
consistent mass for both. Written here rather than taken from a library because the
element is small and its sign conventions must match our DOF labels exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BeamSection", "box_section", "grillage_element", "assemble_grillage"]


@dataclass(frozen=True)
class BeamSection:
    """Section and material of a beam (SI units).

    Attributes
    ----------
    E_pa, G_pa : Young's and shear moduli, Pa.
    rho_kg_m3 : density, kg/m^3.
    A_m2 : area; I_m4 : second moment for out-of-plane bending; J_m4 : torsion constant;
    Ip_m4 : polar moment of area (torsional inertia per unit length is rho Ip).
    """

    E_pa: float
    G_pa: float
    rho_kg_m3: float
    A_m2: float
    I_m4: float
    J_m4: float
    Ip_m4: float


def box_section(width_m: float, height_m: float, wall_m: float, E_pa: float = 69e9,
                G_pa: float = 26e9, rho_kg_m3: float = 2700.0) -> BeamSection:
    """Thin-walled rectangular box (default aluminium): bending about the width axis.

    ``J`` from Bredt's formula for a closed thin-walled section, ``4 A_m^2 t / perimeter``.
    """
    b, h, t = width_m, height_m, wall_m
    A = b * h - (b - 2 * t) * (h - 2 * t)
    I_y = (b * h**3 - (b - 2 * t) * (h - 2 * t) ** 3) / 12  # out-of-plane bending
    I_z = (h * b**3 - (h - 2 * t) * (b - 2 * t) ** 3) / 12
    Am = (b - t) * (h - t)
    J = 4 * Am**2 * t / (2 * (b - t) + 2 * (h - t))
    return BeamSection(E_pa, G_pa, rho_kg_m3, A, I_y, J, I_y + I_z)


def grillage_element(xy1: np.ndarray, xy2: np.ndarray, sec: BeamSection) -> tuple[np.ndarray, np.ndarray]:
    """Stiffness and mass (6 x 6) of a grillage element in global DOFs.

    Global DOFs per node: ``[w, theta_x, theta_y]`` (Z translation, rotations about X, Y).
    Local DOFs per node: ``[w, phi, psi]``: ``phi = dw/dx'`` (bending slope along the element)
    and ``psi`` the twist about the element axis. With ``(c, s)`` the axis direction,
    a rotation vector ``(theta_x, theta_y)`` has component ``psi = c theta_x + s theta_y``
    along the axis and ``theta_y' = -s theta_x + c theta_y`` about the in-plane normal; the
    right-hand rule gives ``phi = dw/dx' = -theta_y'``.
    """
    d = np.asarray(xy2, float) - np.asarray(xy1, float)
    L = float(np.hypot(*d))
    c, s = d / L
    EI, GJ = sec.E_pa * sec.I_m4, sec.G_pa * sec.J_m4
    kb = EI / L**3 * np.array([
        [12, 6 * L, -12, 6 * L],
        [6 * L, 4 * L**2, -6 * L, 2 * L**2],
        [-12, -6 * L, 12, -6 * L],
        [6 * L, 2 * L**2, -6 * L, 4 * L**2],
    ])
    mb = sec.rho_kg_m3 * sec.A_m2 * L / 420 * np.array([
        [156, 22 * L, 54, -13 * L],
        [22 * L, 4 * L**2, 13 * L, -3 * L**2],
        [54, 13 * L, 156, -22 * L],
        [-13 * L, -3 * L**2, -22 * L, 4 * L**2],
    ])
    kt = GJ / L * np.array([[1, -1], [-1, 1]])
    mt = sec.rho_kg_m3 * sec.Ip_m4 * L / 6 * np.array([[2, 1], [1, 2]])
    # Local order [w1, phi1, psi1, w2, phi2, psi2].
    Kl = np.zeros((6, 6))
    Ml = np.zeros((6, 6))
    b_idx = [0, 1, 3, 4]
    t_idx = [2, 5]
    Kl[np.ix_(b_idx, b_idx)] = kb
    Ml[np.ix_(b_idx, b_idx)] = mb
    Kl[np.ix_(t_idx, t_idx)] = kt
    Ml[np.ix_(t_idx, t_idx)] = mt
    Tn = np.array([[1, 0, 0], [0, s, -c], [0, c, s]])  # global [w, tx, ty] -> local [w, phi, psi]
    T = np.zeros((6, 6))
    T[:3, :3] = Tn
    T[3:, 3:] = Tn
    return T.T @ Kl @ T, T.T @ Ml @ T


def assemble_grillage(
    node_xy: dict[int, tuple[float, float]],
    elements: list[tuple[int, int, BeamSection]],
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Assemble K and M of a grillage, DOFs ordered node by node as ``n+Z, n+RX, n+RY``.

    Parameters
    ----------
    node_xy : node id -> (x, y) in metres.
    elements : (node a, node b, section) per element.

    Returns
    -------
    (K, M, labels) with K, M (3 n_nodes, 3 n_nodes).
    """
    nodes = sorted(node_xy)
    pos = {nd: i for i, nd in enumerate(nodes)}
    n = 3 * len(nodes)
    K = np.zeros((n, n))
    M = np.zeros((n, n))
    for a, b, sec in elements:
        ke, me = grillage_element(node_xy[a], node_xy[b], sec)
        idx = np.r_[3 * pos[a] : 3 * pos[a] + 3, 3 * pos[b] : 3 * pos[b] + 3]
        K[np.ix_(idx, idx)] += ke
        M[np.ix_(idx, idx)] += me
    labels = [f"{nd}+{c}" for nd in nodes for c in ("Z", "RX", "RY")]
    return K, M, labels
