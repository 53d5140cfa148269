"""Read and write the ssidlab HDF5 files: measured FRFs and M, C, K models.

The two layouts (``format = "ssidlab-frf"`` and ``"ssidlab-model"``) are fixed by the interface
contract and described in ``docs/formats.md``. Files are small, so whole datasets are read
into numpy arrays and the files are closed again at once.

Every problem found in a file raises :class:`ssid.errors.InputError` with a one-line message
``"<file>: <problem>"``; the command line prints it and exits with status 2. The writers run
the same checks before they write, so we never produce a file that we would refuse to read.
DOF labels are treated as opaque strings: they are compared, never parsed.
"""

from ._common import (
    COHERENCE_SLACK,
    FORMAT_VERSION,
    FRF_DATASET_UNITS,
    FRF_FORMAT,
    MODEL_FORMAT,
    QUANTITY,
    SYMMETRY_RTOL,
    label_frf_units,
    read_format,
)
from .frf_file import read_frf, read_measured_frf, validate_frf, write_frf
from .model_file import Model, read_model, validate_model, write_model

__all__ = [
    "FRF_FORMAT",
    "FRF_DATASET_UNITS",
    "MODEL_FORMAT",
    "FORMAT_VERSION",
    "QUANTITY",
    "SYMMETRY_RTOL",
    "COHERENCE_SLACK",
    "Model",
    "read_frf",
    "read_measured_frf",
    "write_frf",
    "validate_frf",
    "read_model",
    "write_model",
    "validate_model",
    "read_format",
    "label_frf_units",
]
