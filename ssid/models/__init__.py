"""Physical models: lumped systems for tests and examples (the payload simulator comes in issue 3)."""

from .lumped import chain_model, example_system, frf_on_test_stand

__all__ = ["chain_model", "example_system", "frf_on_test_stand"]
