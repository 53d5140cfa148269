"""Physical models: lumped systems, beam grillages and the report's payload simulator."""

from .lumped import chain_model, example_system, frf_on_test_stand, mount_on_test_stand
from .payload import PayloadModel, payload_simulator

__all__ = ["chain_model", "example_system", "frf_on_test_stand", "mount_on_test_stand", "PayloadModel", "payload_simulator"]
