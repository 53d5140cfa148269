"""Textual terminal UI for lab runs. Not built yet (issue 8)."""
