"""Typed, range-checked reading of one TOML table, for the setup file and its ``[sim]`` part.

tomllib gives plain dicts; a setup needs every value's type and range checked, a missing
required key named, and an unknown key (a typo that would silently fall back to a default)
refused, each as one line that names the file, the table and the key.
"""

from __future__ import annotations

import math
from typing import Any

from ssid.errors import InputError

__all__ = ["TomlTable"]


class TomlTable:
    """Typed access to one TOML table; every failure names the file, table and key."""

    def __init__(self, src: str, where: str, data: Any) -> None:
        self.src, self.where = src, where
        if not isinstance(data, dict):
            raise self.error(None, "must be a table")
        self.data = data
        self.used: set[str] = set()

    def error(self, key: str | None, problem: str) -> InputError:
        loc = f"{self.where} {key}" if key else self.where
        return InputError(f"{self.src}: {loc}: {problem}")

    def _get(self, key: str, default: Any, required: bool) -> Any:
        self.used.add(key)
        if key not in self.data:
            if required:
                raise self.error(key, "missing (required)")
            return default
        return self.data[key]

    def str(self, key: str, default: str | None = None, *, required: bool = False,
            choices: tuple[str, ...] | None = None) -> str | None:
        v = self._get(key, default, required)
        if v is None:
            return None
        if not isinstance(v, str) or not v.strip():
            raise self.error(key, f"must be a non-empty string, got {v!r}")
        if choices and v not in choices:
            raise self.error(key, f"must be one of {', '.join(choices)}, got {v!r}")
        return v

    def num(self, key: str, default: float | None = None, *, required: bool = False,
            lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False,
            finite: bool = False) -> float:
        """A number in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``). With ``finite``, ``inf``
        is refused too where the range is unbounded: TOML writes it, and a physical quantity
        (a mass, a stiffness) that is infinite is no value."""
        v = self._get(key, default, required)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.error(key, f"must be a number, got {v!r}")
        v = float(v)
        if finite and math.isinf(v):
            raise self.error(key, f"must be a finite number, got {v:g}")
        if math.isnan(v) or (v <= lo if lo_open else v < lo) or v > hi:
            rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
            raise self.error(key, f"must be in {rng}, got {v:g}")
        return v

    def int(self, key: str, default: int | None = None, *, required: bool = False,
            lo: int = -2**62, hi: int = 2**62) -> int:
        v = self._get(key, default, required)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.error(key, f"must be a whole number, got {v!r}")
        if not lo <= v <= hi:
            raise self.error(key, f"must be in [{lo}, {hi}], got {v}")
        return v

    def bool(self, key: str, default: bool) -> bool:
        v = self._get(key, default, False)
        if not isinstance(v, bool):
            raise self.error(key, f"must be true or false, got {v!r}")
        return v

    def done(self) -> None:
        """Unknown keys are errors: a typo must not silently fall back to a default."""
        extra = sorted(set(self.data) - self.used)
        if extra:
            raise self.error(extra[0], "unknown key")
