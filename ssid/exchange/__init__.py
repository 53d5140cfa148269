"""Data exchange with other programs: UFF (universal files) and Nastran DMIG.

* :mod:`ssid.exchange.uff`, :mod:`ssid.exchange.uff_read` -- FRFs and coherence as UFF
  dataset 58 / 58b (pyuff), written and read;
* :mod:`ssid.exchange.uff_coherence` -- which coherence (ordinary, multiple) a UFF gives;
* :mod:`ssid.exchange.uff_grid` -- one frequency grid from the functions' abscissae;
* :mod:`ssid.exchange.uff_modes` -- mode shapes as dataset 55;
* :mod:`ssid.exchange.uff_geometry` -- units (164) and nodes (2411, 15);
* :mod:`ssid.exchange.uff_units` -- the units of dataset 58's axes (labels, exponents, 164);
* :mod:`ssid.exchange.dmig` -- Nastran DMIG bulk-data cards;
* :mod:`ssid.exchange.labels` -- DOF labels <-> node and direction.

Model export to MATLAB, OP4 and DMIG is :mod:`ssid.export`. Formats, mappings and limits are
described in ``docs/exchange.md``.
"""

from .labels import DIRECTIONS, format_dof_label, parse_dof_label
from .uff import UFFWarning, write_uff_frf
from .uff_geometry import read_uff_geometry, write_uff_geometry
from .uff_modes import (
    UFFModes,
    modes_from_model,
    modes_from_result,
    read_uff_modes,
    write_uff_modes,
)
from .uff_read import read_uff_frf

__all__ = [
    "DIRECTIONS",
    "UFFModes",
    "UFFWarning",
    "format_dof_label",
    "modes_from_model",
    "modes_from_result",
    "parse_dof_label",
    "read_uff_frf",
    "read_uff_geometry",
    "read_uff_modes",
    "write_uff_frf",
    "write_uff_geometry",
    "write_uff_modes",
]
