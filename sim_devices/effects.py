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
    "describe",
    "invalid_parameter",
    "parameters",
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


def parameters(eff: Effect) -> dict[str, float]:
    """The effect's numbers by key (``mass_kg``, ``stiffness_n_per_m``, ``damping_n_s_per_m``),
    as a setup file's ``[[sim.effects]]`` entry names them."""
    return {k: v for k, v in vars(eff).items() if not k.startswith("dof")}


def describe(eff: Effect) -> str:
    """``"added_mass at 6+Z"``, ``"coupling_spring between 7+Z and 8+Z"``: which entry."""
    if isinstance(eff, CouplingSpring):
        return f"{eff.effect} between {eff.dof_a} and {eff.dof_b}"
    return f"{eff.effect} at {eff.dof}"


def invalid_parameter(eff: Effect) -> tuple[str, str] | None:
    """The parameter no structure can take, whatever it is added to, and why; None if none.

    A damper with negative damping feeds energy in, and a hanging spring-mass with a mass or
    a spring <= 0 is no oscillator (it diverges, or has no resonance). A negative added mass
    or spring is not refused here: it may stand for mass or stiffness the model has and the
    hardware lacks (a coupling spring's stiffness lost, ``docs/formats.md``), and whether the
    structure stays stable with it depends on the structure (:class:`sim_devices.world.World`
    names the effect when it does not).
    """
    if isinstance(eff, GroundedDamper) and eff.damping_n_s_per_m < 0:
        return "damping_n_s_per_m", "a damper's damping must be >= 0 (a negative one feeds energy in)"
    if isinstance(eff, AttachedOscillator):
        if eff.mass_kg <= 0:
            return "mass_kg", "an attached oscillator's mass must be > 0"
        if eff.stiffness_n_per_m <= 0:
            return "stiffness_n_per_m", ("an attached oscillator's spring must be > 0 (with none it has no "
                                         "resonance, with a negative one it diverges)")
        if eff.damping_n_s_per_m < 0:
            return "damping_n_s_per_m", "an attached oscillator's damping must be >= 0 (a negative one feeds energy in)"
    return None


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
            at, params = (eff.dof,), parameters(eff)
        else:
            raise TypeError(f"unknown hidden effect {eff!r}")
        M, C, K, dofs = add_effect(M, C, K, dofs, eff.effect, at, params)
    return M, C, K, dofs


def instability_reason(eff: Effect, M: np.ndarray, C: np.ndarray, K: np.ndarray) -> tuple[str, str]:
    """Which of ``eff``'s parameters made the structure unstable, and how.

    ``M``, ``C``, ``K`` are the structure's (on its stand, if it has one) once ``eff`` and the
    effects before it are added. The first of them that lost its definiteness, among those
    the effect changes, names the parameter: a mass that makes M indefinite, a spring that
    gives K a negative eigenvalue (a static divergence), a damper that gives C one.
    """
    params = parameters(eff)
    for A, key, what in ((M, "mass_kg", "the mass matrix is no longer positive definite"),
                         (K, "stiffness_n_per_m", "the stiffness matrix gets a negative eigenvalue (a motion "
                          "with negative stiffness, which diverges)"),
                         (C, "damping_n_s_per_m", "the damping matrix gets a negative eigenvalue (a motion "
                          "that gains energy)")):
        lam = np.linalg.eigvalsh((A + A.T) / 2)
        # M must be definite; K and C may be singular (a free structure, an undamped one),
        # so only an eigenvalue clearly below zero, not round-off, counts for them.
        floor = 0.0 if key == "mass_kg" else -1e-9 * np.max(np.abs(lam))
        if key in params and lam[0] <= floor:
            return key, f"makes the assembled system unstable: {what}"
    return next(iter(params)), "makes the assembled system unstable"
