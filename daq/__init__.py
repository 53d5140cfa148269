"""Acquisition: excitation scheduling, FRF estimation, safety limits, crash-safe storage.

Not built yet (issue 6). Depends on ``drivers`` and ``ssid``.
"""
