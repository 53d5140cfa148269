"""Why a :class:`sim_devices.world.World` cannot be built: the structure, the hardware, or one
hidden effect, named so that a setup's error can point at its ``[[sim.effects]]`` entry."""

from __future__ import annotations

from .effects import Effect, describe, parameters

__all__ = ["EffectError", "UnstableError", "WorldError"]


class WorldError(ValueError):
    """The world cannot be built from the structure and hardware given."""


class UnstableError(WorldError):
    """The assembled system (structure, effects, stand, shakers) is unstable or its mass
    matrix singular: no time response exists to simulate."""


class EffectError(WorldError):
    """One hidden effect the world cannot be built with.

    Attributes
    ----------
    index : int
        Its place (0-based) in the effects given: the ``[[sim.effects]]`` entry, 1-based, is
        ``index + 1``.
    effect : Effect
        The effect itself.
    parameter : str
        The key of its value at fault (``mass_kg``, ``stiffness_n_per_m``, ...).
    problem : str
        What is wrong with it.
    """

    def __init__(self, index: int, effect: Effect, parameter: str, problem: str) -> None:
        self.index, self.effect, self.parameter, self.problem = index, effect, parameter, problem
        super().__init__(f"hidden effect #{index + 1} {self.entry}")

    @property
    def entry(self) -> str:
        """``"(added_mass at 6+Z) mass_kg = -0.9: <problem>"``: the text after the entry's name."""
        value = parameters(self.effect)[self.parameter]
        return f"({describe(self.effect)}) {self.parameter} = {value:g}: {self.problem}"
