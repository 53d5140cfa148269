"""Textual terminal UI for lab runs (issue 8): ``tui.app.LabApp``, ``ssidlab tui`` via
``tui.cli.add_tui_subcommand``. It calls ``daq`` and ``ssid`` only; see docs/tui.md."""
