"""The "payload simulator" of the report (chapter 6): a 52-DOF aluminium grillage.

Two 60-in box-beam rails (nodes 1-4 and 5-8) joined at each end by a pair of stacked 20-in
cross-beams, both spanning the rail ends: one through nodes 11, 9, 13 (x = 0) or 14, 10, 16
(x = 60 in), the other through nodes 12, 18 or 15, 17; 18 nodes and 20 elements. The
report's "very short rods" between the two cross-beams of a pair join nodes at the same
plan position: the multi-point constraints Z9 = Z18 and Z10 = Z17. Each node has Z, RX, RY (X/Y translations
and Z rotation constrained); 54 - 2 = 52 DOFs. Soft springs at nodes 11, 13, 14, 16 model the
bungee suspension; the interface DOFs are 4+Z, 8+Z and 18+Z.

The report's figure and section properties are not in its text: node positions are inferred
from its mode-shape tables (Table 6.19: nodes 1-4 and 5-8 are the two rails, 17 and 18 lie on
the centre line at the rail ends), and the sections are chosen so that the
three lowest modes are suspension modes below 20 Hz and the flexible modes start near
100 Hz with close pairs, as in Table 6.1. Results resemble the report's; they do not equal it:
the frame's twist, the report's 4th mode at 18.1 Hz (its Table 6.19), is at 78.9 Hz here, since
closed box rails resist it in torsion (docs/replication.md, "Why our modes sit elsewhere").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .beams import BeamSection, assemble_grillage, box_section

__all__ = [
    "PayloadModel",
    "RAIL_BOX",
    "CROSS_BOX",
    "payload_simulator",
    "INTERFACE_DOFS",
    "Z_DOFS",
    "modal_damping",
    "rayleigh_damping",
    "attach_test_stand",
    "target_modes",
    "z_energy_fraction",
]

IN = 0.0254  # metres per inch

#: Interface DOFs of the payload (report section 6.1).
INTERFACE_DOFS = ["4+Z", "8+Z", "18+Z"]
#: The 16 independent Z DOFs (nodes 9 and 10 are constrained to 18 and 17).
Z_DOFS = [f"{n}+Z" for n in (1, 2, 3, 4, 5, 6, 7, 8, 11, 12, 13, 14, 15, 16, 17, 18)]

_NODES_IN = {
    1: (0, 0), 2: (20, 0), 3: (40, 0), 4: (60, 0),
    5: (0, 20), 6: (20, 20), 7: (40, 20), 8: (60, 20),
    11: (0, 5), 9: (0, 10), 13: (0, 15), 12: (0, 4), 18: (0, 10),
    14: (60, 5), 10: (60, 10), 16: (60, 15), 15: (60, 4), 17: (60, 10),
}
_RAILS = [(1, 2), (2, 3), (3, 4), (5, 6), (6, 7), (7, 8)]
_INNER = [(1, 11), (11, 9), (9, 13), (13, 5), (4, 14), (14, 10), (10, 16), (16, 8)]
_OUTER = [(1, 12), (12, 18), (18, 5), (4, 15), (15, 17), (17, 8)]
#: Multi-point constraints: Z of the first node equals Z of the second.
_MPC = [(9, 18), (10, 17)]
_BUNGEE_NODES = (11, 13, 14, 16)
#: Default sections, aluminium boxes: 2 x 2 x 0.125 in rails, 1 x 1 x 0.0625 in cross-beams.
RAIL_BOX = box_section(2.0 * IN, 2.0 * IN, 0.125 * IN)
CROSS_BOX = box_section(1.0 * IN, 1.0 * IN, 0.0625 * IN)


@dataclass
class PayloadModel:
    """Undamped FE model: M, K (n, n) over ``dofs`` (labels like ``"4+Z"``)."""

    M: np.ndarray
    K: np.ndarray
    dofs: list[str]

    @property
    def n(self) -> int:
        return len(self.dofs)

    def index(self, labels: list[str]) -> np.ndarray:
        """Positions of ``labels`` in ``dofs``."""
        pos = {lbl: i for i, lbl in enumerate(self.dofs)}
        return np.array([pos[lbl] for lbl in labels], dtype=int)


def payload_simulator(
    bungee_z_n_per_m: float = 95.0,
    bungee_rot_n_m_per_rad: tuple[float, float] = (130.0, 60.0),
    *,
    rail: BeamSection = RAIL_BOX,
    inner_cross: BeamSection = CROSS_BOX,
    outer_cross: BeamSection | None = None,
) -> PayloadModel:
    """The 52-DOF payload simulator (see the module docstring).

    Parameters
    ----------
    bungee_z_n_per_m : vertical stiffness of each of the four bungee springs.
    bungee_rot_n_m_per_rad : (about X, about Y) rotational stiffness of each bungee attachment;
        with the vertical springs they set the three suspension modes (heave, pitch, roll).
    rail, inner_cross, outer_cross : sections of the two rails, of the cross-beams through the
        bungee nodes and of those through nodes 17 and 18 (default ``inner_cross``).

    Returns
    -------
    PayloadModel with 52 DOFs, ordered node by node (Z, RX, RY), slaves' Z removed.
    """
    if outer_cross is None:
        outer_cross = inner_cross
    xy = {nd: (x * IN, y * IN) for nd, (x, y) in _NODES_IN.items()}
    elements = ([(a, b, rail) for a, b in _RAILS] + [(a, b, inner_cross) for a, b in _INNER]
                + [(a, b, outer_cross) for a, b in _OUTER])
    K, M, labels = assemble_grillage(xy, elements)
    pos = {lbl: i for i, lbl in enumerate(labels)}
    for nd in _BUNGEE_NODES:
        K[pos[f"{nd}+Z"], pos[f"{nd}+Z"]] += bungee_z_n_per_m
        K[pos[f"{nd}+RX"], pos[f"{nd}+RX"]] += bungee_rot_n_m_per_rad[0]
        K[pos[f"{nd}+RY"], pos[f"{nd}+RY"]] += bungee_rot_n_m_per_rad[1]
    # MPCs by transformation x = T q: each slave Z follows its master's Z.
    slaves = [pos[f"{s}+Z"] for s, _ in _MPC]
    keep = [i for i in range(len(labels)) if i not in slaves]
    T = np.zeros((len(labels), len(keep)))
    T[keep, np.arange(len(keep))] = 1.0
    col = {full: j for j, full in enumerate(keep)}
    for s, m in _MPC:
        T[pos[f"{s}+Z"], col[pos[f"{m}+Z"]]] = 1.0
    Kr = T.T @ K @ T
    Mr = T.T @ M @ T
    return PayloadModel(M=(Mr + Mr.T) / 2, K=(Kr + Kr.T) / 2, dofs=[labels[i] for i in keep])


def modal_damping(M: np.ndarray, K: np.ndarray, zeta: float | np.ndarray = 0.02) -> np.ndarray:
    """Viscous damping giving every mode the damping ratio ``zeta`` (report: 2 %).

    ``C = M Phi diag(2 zeta_r omega_r) Phi^T M`` with mass-normalised modes ``Phi``.
    """
    import scipy.linalg as sla

    lam, phi = sla.eigh(K, M)
    z = np.broadcast_to(np.asarray(zeta, dtype=float), lam.shape)
    Mphi = M @ phi
    C = Mphi @ np.diag(2 * z * np.sqrt(np.abs(lam))) @ Mphi.T
    return (C + C.T) / 2


def rayleigh_damping(M: np.ndarray, K: np.ndarray, f1_hz: float, f2_hz: float,
                     zeta: float = 0.02) -> np.ndarray:
    """``C = a M + b K`` with damping ratio ``zeta`` at ``f1_hz`` and ``f2_hz``.

    Used with a test stand (report section 6.6): unlike modal damping, it couples nothing
    between substructure and stand that the physical joints do not.
    """
    w1, w2 = 2 * np.pi * f1_hz, 2 * np.pi * f2_hz
    a = 2 * zeta * w1 * w2 / (w1 + w2)
    b = 2 * zeta / (w1 + w2)
    return a * M + b * K


def attach_test_stand(
    model: PayloadModel,
    interface_dofs: list[str] = INTERFACE_DOFS,
    stand_mass_kg: tuple[float, float, float] = (6.0, 10.0, 14.0),
    stand_k_n_per_m: tuple[float, float, float] = (3e6, 5e6, 8e6),
    arm_m: float = 0.15,
    coupling_k_n_per_m: float = 2e6,
) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:
    """Couple a 9-DOF test-stand column to each interface DOF (report section 6.6).

    Each column has three bodies (Z, RX, RY each: 9 DOFs) stacked on springs to ground; each
    level's spring is split into two at +-``arm_m`` with unequal stiffness (60/40), which
    couples bounce and rocking as in a real stand. The top body's Z is tied to the interface
    DOF by a load-cell spring ``coupling_k``: the load cell's force is the measured reaction.

    Returns
    -------
    (M, K, dofs, T_rel): coupled matrices over ``model.dofs + stand dofs`` and ``T_rel``
    (n_interface, n_total) giving ``x_stand_top - x_interface`` for each interface, so that
    the reaction on the substructure is ``coupling_k * T_rel @ x``.
    """
    n0 = model.n
    ni = len(interface_dofs)
    n = n0 + 9 * ni
    M = np.zeros((n, n))
    K = np.zeros((n, n))
    M[:n0, :n0] = model.M
    K[:n0, :n0] = model.K
    dofs = list(model.dofs)
    T_rel = np.zeros((ni, n))
    iface = model.index(interface_dofs)
    for c, label in enumerate(interface_dofs):
        base = n0 + 9 * c
        for lvl in range(3):
            z, rx, ry = base + 3 * lvl, base + 3 * lvl + 1, base + 3 * lvl + 2
            m = stand_mass_kg[lvl]
            M[z, z] += m
            M[rx, rx] += m * arm_m**2 / 3
            M[ry, ry] += m * arm_m**2 / 3
            dofs += [f"stand{c + 1}.{lvl + 1}+Z", f"stand{c + 1}.{lvl + 1}+RX",
                     f"stand{c + 1}.{lvl + 1}+RY"]
            below = None if lvl == 0 else base + 3 * (lvl - 1)
            k = stand_k_n_per_m[lvl]
            # Two springs per rotation axis at +-arm with 60/40 split: couples Z and rotation.
            for rot in (rx, ry):
                for sign, frac in ((+1, 0.6), (-1, 0.4)):
                    e = np.zeros(n)
                    e[z] = 1.0
                    e[rot] = sign * arm_m
                    if below is not None:
                        e[below] = -1.0
                        e[below + (rot - z)] = -sign * arm_m
                    K += (k / 2) * frac * 2 * np.outer(e, e)
        top = base + 6
        e = np.zeros(n)
        e[top] = 1.0
        e[iface[c]] = -1.0
        K += coupling_k_n_per_m * np.outer(e, e)
        T_rel[c] = e
    return (M + M.T) / 2, (K + K.T) / 2, dofs, T_rel


def z_energy_fraction(model: PayloadModel) -> tuple[np.ndarray, np.ndarray]:
    """Natural frequencies (Hz, ascending) and the share of each mode's kinetic energy in Z
    translations (``phi_i (M phi)_i`` summed over the Z DOFs, mass-normalised modes): (n,), (n,)."""
    import scipy.linalg as sla

    lam, phi = sla.eigh(model.K, model.M)
    iz = model.index(Z_DOFS)
    return np.sqrt(np.abs(lam)) / (2 * np.pi), (phi * (model.M @ phi))[iz].sum(axis=0)


def target_modes(model: PayloadModel, n_modes: int, z_fraction_min: float = 0.3) -> np.ndarray:
    """Indices (ascending frequency) of the first ``n_modes`` modes dominated by Z motion.

    The report's "target modes" are global modes dominated by Z translations (Table 6.1,
    asterisks). A mode qualifies when at least ``z_fraction_min`` of its kinetic energy is in
    Z translations (:func:`z_energy_fraction`).
    """
    idx = np.flatnonzero(z_energy_fraction(model)[1] >= z_fraction_min)
    if idx.size < n_modes:
        raise ValueError(f"only {idx.size} Z-dominated modes, {n_modes} asked")
    return idx[:n_modes]
