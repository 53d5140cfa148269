"""Instrument drivers (transport -> protocol -> device). Not built yet (issue 5)."""
