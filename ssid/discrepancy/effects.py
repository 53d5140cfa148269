"""The library of candidate effects: parametrised changes to a model's M, C, K.

Names and parameter keys are the contract's (``../shared/contract.md``, "Effect names of the
discrepancy workflow"); ``sim_devices.effects`` plants the same effects in the simulated
world, so a test can hide one there and check that the workflow names it.

Every effect except ``none`` changes the dynamic stiffness ``Z(omega) = K - omega^2 M +
j omega C`` by a rank-one term ``delta(omega) u u^T``:

==========================  =======================  =============================================
effect                      ``u``                    ``delta(omega)``
==========================  =======================  =============================================
``added_mass``              ``e_p``                  ``-omega^2 m``
``grounded_spring``         ``e_p``                  ``k``
``grounded_damper``         ``e_p``                  ``j omega c``
``coupling_spring``         ``e_p - e_q``            ``k``
``attached_oscillator``     ``e_p``                  ``-omega^2 m (k + j omega c) / (k + j omega c - omega^2 m)``
==========================  =======================  =============================================

The oscillator's ``delta`` is its extra DOF condensed out exactly (the force a spring-damper
hanging a mass ``m`` from DOF ``p`` exerts on ``p``). That is what makes every candidate a
rank-one update of the nominal receptance (``ssid.discrepancy.localise``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ssid.models.effects import add_effect

from ..io import Model

__all__ = [
    "EFFECT_NAMES",
    "ONE_DOF_EFFECTS",
    "PARAMETER_KEYS",
    "Effect",
    "apply_effect",
    "apply_effect_to_model",
    "effect_dynamic_stiffness",
    "oscillator_shape",
    "unit_shape",
]

#: The contract's effect names, ``none`` last.
EFFECT_NAMES = (
    "added_mass",
    "grounded_spring",
    "coupling_spring",
    "grounded_damper",
    "attached_oscillator",
    "none",
)

#: Parameter keys of each effect, in the order the fit uses them.
PARAMETER_KEYS: dict[str, tuple[str, ...]] = {
    "added_mass": ("mass_kg",),
    "grounded_spring": ("stiffness_n_per_m",),
    "coupling_spring": ("stiffness_n_per_m",),
    "grounded_damper": ("damping_n_s_per_m",),
    "attached_oscillator": ("mass_kg", "stiffness_n_per_m", "damping_n_s_per_m"),
    "none": (),
}

#: Effects acting at one DOF with one parameter that enters ``delta`` linearly.
ONE_DOF_EFFECTS = ("added_mass", "grounded_spring", "grounded_damper")


@dataclass(frozen=True)
class Effect:
    """One effect of the library at named DOFs.

    Attributes
    ----------
    name : str
        One of :data:`EFFECT_NAMES`.
    dofs : tuple of str
        One label, two for ``coupling_spring``, none for ``none``.
    parameters : dict
        Values under the keys of :data:`PARAMETER_KEYS` (SI units).
    """

    name: str
    dofs: tuple[str, ...] = ()
    parameters: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.name not in EFFECT_NAMES:
            raise ValueError(f"unknown effect {self.name!r}; choose one of {EFFECT_NAMES}")
        n_dofs = {"none": 0, "coupling_spring": 2}.get(self.name, 1)
        if len(self.dofs) != n_dofs:
            raise ValueError(f"{self.name} acts at {n_dofs} DOF(s), got {list(self.dofs)}")
        if set(self.parameters) != set(PARAMETER_KEYS[self.name]):
            raise ValueError(
                f"{self.name} takes parameters {PARAMETER_KEYS[self.name]}, got {sorted(self.parameters)}"
            )

    @property
    def n_parameters(self) -> int:
        return len(PARAMETER_KEYS[self.name])

    def values(self) -> np.ndarray:
        """Parameter values in :data:`PARAMETER_KEYS` order, (n_parameters,)."""
        return np.array([float(self.parameters[k]) for k in PARAMETER_KEYS[self.name]])

    def describe(self) -> str:
        """One line, e.g. ``added_mass at 3+Z: mass_kg=0.0512``."""
        if self.name == "none":
            return "none"
        pars = ", ".join(f"{k}={v:.4g}" for k, v in self.parameters.items())
        return f"{self.name} at {'-'.join(self.dofs)}: {pars}"


def unit_shape(name: str, omega: np.ndarray) -> np.ndarray:
    """``delta(omega)`` of a one-parameter effect per unit parameter, (n_freq,) complex.

    ``added_mass``: ``-omega^2``; springs: 1; ``grounded_damper``: ``j omega``.
    """
    w = np.asarray(omega, dtype=float)
    if name == "added_mass":
        return (-(w**2)).astype(complex)
    if name in ("grounded_spring", "coupling_spring"):
        return np.ones(w.shape, dtype=complex)
    if name == "grounded_damper":
        return 1j * w
    raise ValueError(f"{name} is not a one-parameter effect")


def oscillator_shape(omega: np.ndarray, omega_o: np.ndarray, zeta_o: np.ndarray) -> np.ndarray:
    """``delta(omega)`` of an attached oscillator per kg of oscillator mass.

    With ``k = m omega_o^2`` and ``c = 2 zeta_o m omega_o``, ``delta = m s(omega)`` and
    ``s = -omega^2 (1 + 2 j zeta_o r) / (1 + 2 j zeta_o r - r^2)``, ``r = omega / omega_o``:
    for a given tuning the oscillator is linear in its mass.

    Parameters
    ----------
    omega : (n_freq,)
        rad/s.
    omega_o, zeta_o : broadcastable arrays
        Oscillator natural frequency (rad/s) and damping ratio; the result has shape
        ``broadcast(omega_o, zeta_o).shape + (n_freq,)``.
    """
    w = np.asarray(omega, dtype=float)
    wo = np.asarray(omega_o, dtype=float)[..., None]
    zo = np.asarray(zeta_o, dtype=float)[..., None]
    r = w / wo
    num = 1 + 2j * zo * r
    return -(w**2) * num / (num - r**2)


def effect_dynamic_stiffness(effect: Effect, omega: np.ndarray) -> np.ndarray:
    """``delta(omega)`` of ``effect`` (see the module table), (n_freq,) complex, N/m."""
    w = np.asarray(omega, dtype=float)
    p = effect.parameters
    if effect.name == "none":
        return np.zeros(w.shape, dtype=complex)
    if effect.name == "attached_oscillator":
        m, k, c = p["mass_kg"], p["stiffness_n_per_m"], p["damping_n_s_per_m"]
        kc = k + 1j * w * c
        return -(w**2) * m * kc / (kc - w**2 * m)
    return float(effect.values()[0]) * unit_shape(effect.name, w)


def apply_effect(
    M: np.ndarray,
    C: np.ndarray | None,
    K: np.ndarray,
    dofs: list[str],
    effect: Effect,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, list[str]]:
    """M, C, K and labels with ``effect`` added (new arrays; the inputs are not changed).

    ``C`` stays None when it was None and the effect adds no damping. An attached
    oscillator appends one DOF (labelled ``"<dof>~osc<k>"``) to the end.
    """
    return add_effect(M, C, K, dofs, effect.name, effect.dofs, effect.parameters)


def apply_effect_to_model(model: Model, effect: Effect, C: np.ndarray | None = None) -> Model:
    """``model`` with ``effect`` added; ``C`` overrides the model's damping when given."""
    M, C2, K, dofs = apply_effect(model.M, model.C if C is None else C, model.K, model.dofs, effect)
    attrs = dict(model.attrs)
    return Model(M=M, K=K, C=C2, dofs=dofs, attrs=attrs)
