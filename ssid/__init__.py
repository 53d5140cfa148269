"""Frequency-domain Substructure System Identification (Blades & Craig) and its companions.

Pure science: this package imports none of ``daq``, ``drivers``, ``sim_devices`` or ``tui``.
"""
