"""Hidden effects: what the simulated hardware has and the nominal analysis model lacks.

Each effect is a change to a structure's M, C, K at labelled DOFs. The class names follow
the contract's discrepancy-workflow effect names (``docs/formats.md``) so that a test can
plant an effect in the world and check that the discrepancy workflow finds the same one:

================================  =========================================================
class (``effect`` name)            physical meaning in the lab
================================  =========================================================
:class:`AddedMass`                 accelerometer or cable mass (``added_mass``)
:class:`GroundedSpring`            boundary / support stiffness (``grounded_spring``)
:class:`CouplingSpring`            joint stiffness change, may be negative (``coupling_spring``)
:class:`GroundedDamper`            local damping to ground (``grounded_damper``)
:class:`AttachedOscillator`        fixture resonance, a spring-mass hanging from a DOF
                                   (``attached_oscillator``)
================================  =========================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Union

import numpy as np

from ssid.models.effects import add_effect

__all__ = [
    "AddedMass",
    "AttachedOscillator",
    "CouplingSpring",
    "Effect",
    "GroundedDamper",
    "GroundedSpring",
    "apply_effects",
]


@dataclass(frozen=True)
class AddedMass:
    """A point mass the model lacks (sensor, cable, fixture part) at ``dof``."""

    dof: str
    mass_kg: float
    effect = "added_mass"


@dataclass(frozen=True)
class GroundedSpring:
    """A spring from ``dof`` to ground (boundary condition the model lacks)."""

    dof: str
    stiffness_n_per_m: float
    effect = "grounded_spring"


@dataclass(frozen=True)
class CouplingSpring:
    """A spring between two DOFs; negative stiffness models a joint that lost stiffness."""

    dof_a: str
    dof_b: str
    stiffness_n_per_m: float
    effect = "coupling_spring"


@dataclass(frozen=True)
class GroundedDamper:
    """Localised viscous damping from ``dof`` to ground."""

    dof: str
    damping_n_s_per_m: float
    effect = "grounded_damper"


@dataclass(frozen=True)
class AttachedOscillator:
    """A spring-mass-damper hanging from ``dof`` (e.g. a fixture resonance).

    It adds one DOF to the structure, labelled ``"<dof>~osc<k>"``; no sensor sees it unless
    one is wired to that label on purpose.
    """

    dof: str
    mass_kg: float
    stiffness_n_per_m: float
    damping_n_s_per_m: float = 0.0
    effect = "attached_oscillator"


Effect = Union[AddedMass, GroundedSpring, CouplingSpring, GroundedDamper, AttachedOscillator]


def apply_effects(
    M: np.ndarray,
    C: np.ndarray | None,
    K: np.ndarray,
    dofs: list[str],
    effects: list[Effect] | tuple[Effect, ...] = (),
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """M, C, K and DOF labels of a structure with hidden effects added.

    Parameters
    ----------
    M, C, K : (n, n)
        Nominal matrices (``C`` None: undamped).
    dofs : list of str
        Labels of the ``n`` DOFs.
    effects : sequence of effects
        Applied in order; attached oscillators append one DOF each.

    Returns
    -------
    (M, C, K, dofs) as new arrays; the first ``n`` labels are unchanged.
    """
    M = np.array(M, dtype=float)
    K = np.array(K, dtype=float)
    C = np.zeros_like(M) if C is None else np.array(C, dtype=float)
    dofs = list(dofs)
    for eff in effects:
        if isinstance(eff, CouplingSpring):
            at, params = (eff.dof_a, eff.dof_b), {"stiffness_n_per_m": eff.stiffness_n_per_m}
        elif isinstance(eff, (AddedMass, GroundedSpring, GroundedDamper, AttachedOscillator)):
            at = (eff.dof,)
            params = {k: v for k, v in vars(eff).items() if k != "dof"}
        else:
            raise TypeError(f"unknown hidden effect {eff!r}")
        M, C, K, dofs = add_effect(M, C, K, dofs, eff.effect, at, params)
    return M, C, K, dofs
