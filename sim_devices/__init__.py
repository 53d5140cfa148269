"""Simulated instruments on real transports, driven by ``ssid.models`` physics. Not built yet (issue 5)."""
