"""Units of the FRFs in a UFF file: dataset 164 and the axis records (8-10) of each dataset 58.

A dataset 58 says what its axes are (specific data types) and, in records 8-10, may say in
which units: a units label (``g``, ``in/s^2``, ``lbf``, ``rad/s``) and length/force exponents
relative to the file's dataset 164. :class:`FileUnits` turns these into the factors that make
a function an accelerance in SI ((m/s^2)/N, (rad/s^2)/(N m) ...) over an abscissa in Hz.

Rules (the reasons are in ``docs/exchange.md``, "Units of other programs' files"):

* a **recognised label** gives its axis's unit outright, whatever a dataset 164 says; where
  the two disagree the label is followed and the file gets one warning; an ordinate label
  carrying the whole FRF unit as a ratio (``Gs/N``, ``g/lbf``, ``mm/s/N``, ``(m/s^2)/N``)
  gives the ordinate's and the denominator's unit, each checked like a label of its own;
* an axis without a label (``NONE``, blank) is in the units of the dataset 164, SI without
  one; its length/force exponents are used where the standard makes them relevant (specific
  data type general/unknown, or a scalar DOF) and not all zero;
* an FRF's ordinate or denominator label that is not recognised is refused: the label says
  the values are in a unit whose factor is unknown, and reading them as the 164 (or SI)
  would be a wrong scale behind a warning; an unrecognised abscissa label is reported once
  per file and read in Hz (a frequency's unit does not depend on the 164);
* a label contradicting the axis's data type or its DOF (``mm/s`` on an acceleration,
  ``g`` on a rotation, a force over ``g``) is refused with a one-line ``InputError``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ssid.errors import InputError

from .labels import format_dof_label
from .uff_geometry import unit_factors

__all__ = [
    "SPEC_ACCELERATION", "SPEC_DISPLACEMENT", "SPEC_FORCE", "SPEC_FREQUENCY", "SPEC_GENERAL",
    "SPEC_NAMES", "SPEC_REACTION", "SPEC_VELOCITY", "FileUnits", "normalise_label",
]

SPEC_GENERAL, SPEC_DISPLACEMENT, SPEC_REACTION = 1, 8, 9
SPEC_VELOCITY, SPEC_ACCELERATION, SPEC_FORCE, SPEC_FREQUENCY = 11, 12, 13, 18
SPEC_NAMES = {2: "stress", 3: "strain", 5: "temperature", 6: "heat flux", 8: "displacement",
              9: "reaction force", 11: "velocity", 12: "acceleration", 13: "excitation force",
              15: "pressure", 16: "mass", 17: "time", 18: "frequency", 19: "rpm", 20: "order"}
_UNKNOWN = (0, SPEC_GENERAL)
# What each typed axis must be; a label of another kind contradicts it.
_SPEC_KIND = {SPEC_DISPLACEMENT: "displacement", SPEC_VELOCITY: "velocity",
              SPEC_ACCELERATION: "acceleration", SPEC_REACTION: "force", SPEC_FORCE: "force"}
_KIND_SPEC = {"displacement": SPEC_DISPLACEMENT, "velocity": SPEC_VELOCITY,
              "acceleration": SPEC_ACCELERATION}
_SI_NAME = {("acceleration", False): "m/s^2", ("acceleration", True): "rad/s^2",
            ("velocity", False): "m/s", ("velocity", True): "rad/s",
            ("displacement", False): "m", ("displacement", True): "rad",
            ("force", False): "N", ("force", True): "N*m"}
_BLANK = {"", "none"}
# Two labels agree with a dataset 164 when their factors match to this (164 factors are
# written as D25.17 by most programs, but E13.5 by some).
_AGREE_RTOL = 1e-5


@dataclass(frozen=True)
class _Unit:
    kind: str  # displacement, velocity, acceleration, force, frequency, time or order
    si: float  # SI (Hz for a frequency) per unit
    rotational: bool = False


# ------------------------------------------------------------------------------------------
# The label table, written by hand: no units library knows that "g" is 9.80665 m/s^2 here
# (pint reads a gram) or that "rpm" on an abscissa is 1/60 Hz (pint gives 2 pi/60 rad/s), and
# a dependency for some 60 entries is not worth it. Keys are normalised (normalise_label).
# Exact definitions: inch 0.0254 m, foot 0.3048 m, g_n 9.80665 m/s^2, lbf 0.45359237 g_n N.
# ------------------------------------------------------------------------------------------
_G, _IN, _FT, _LBF = 9.80665, 0.0254, 0.3048, 0.45359237 * 9.80665
_DEG = math.pi / 180


def _units(kind: str, entries: dict[str, float], rotational: bool = False) -> dict[str, _Unit]:
    return {label: _Unit(kind, si, rotational) for label, si in entries.items()}


_MOTION: dict[str, _Unit] = {
    **_units("acceleration", {
        "m/s^2": 1.0, "mm/s^2": 1e-3, "cm/s^2": 1e-2, "in/s^2": _IN, "inch/s^2": _IN,
        "ft/s^2": _FT, "g": _G, "gs": _G, "g's": _G, "gn": _G,
        # On a motion axis "mg" is milli-g (a milligram is no motion unit).
        "mg": 1e-3 * _G}),
    **_units("velocity", {
        "m/s": 1.0, "mm/s": 1e-3, "cm/s": 1e-2, "um/s": 1e-6, "in/s": _IN, "inch/s": _IN,
        "ips": _IN, "ft/s": _FT}),
    **_units("displacement", {
        "m": 1.0, "mm": 1e-3, "cm": 1e-2, "um": 1e-6, "micron": 1e-6, "microns": 1e-6,
        "nm": 1e-9, "in": _IN, "inch": _IN, "mil": 1e-3 * _IN, "mils": 1e-3 * _IN, "ft": _FT}),
    **_units("acceleration", rotational=True, entries={"rad/s^2": 1.0, "deg/s^2": _DEG}),
    **_units("velocity", rotational=True, entries={"rad/s": 1.0, "deg/s": _DEG}),
    **_units("displacement", rotational=True, entries={"rad": 1.0, "deg": _DEG}),
}
_FORCE: dict[str, _Unit] = {
    **_units("force", {
        "n": 1.0, "kn": 1e3, "lbf": _LBF, "lb": _LBF, "lbs": _LBF, "kgf": _G}),
    # "nm" is a newton metre on a force axis (a nanometre on a motion axis).
    **_units("force", rotational=True, entries={
        "n*m": 1.0, "m*n": 1.0, "nm": 1.0, "n*mm": 1e-3, "nmm": 1e-3, "kn*m": 1e3, "knm": 1e3,
        "lbf*in": _LBF * _IN, "in*lbf": _LBF * _IN, "lb*in": _LBF * _IN, "in*lb": _LBF * _IN,
        "lbf*ft": _LBF * _FT, "ft*lbf": _LBF * _FT, "lb*ft": _LBF * _FT, "ft*lb": _LBF * _FT}),
}
_ABSCISSA: dict[str, _Unit] = {
    **_units("frequency", {
        "hz": 1.0, "1/s": 1.0, "cps": 1.0, "khz": 1e3, "rad/s": 1 / (2 * math.pi),
        "rpm": 1 / 60, "r/min": 1 / 60, "rev/min": 1 / 60, "cpm": 1 / 60}),
    **_units("time", {"s": 1.0, "ms": 1e-3}),
    **_units("order", {"order": 1.0, "orders": 1.0}),
}

_SPELLING = str.maketrans({"²": "^2", "³": "^3", "µ": "u", "μ": "u", "·": "*", "×": "*",
                           "°": "deg"})


def normalise_label(label: Any) -> str:
    """A units label in the table's spelling: lower case, no blanks, ``^`` for powers, ``*``
    for products (``m/s**2``, ``M/S2``, ``m/sec^2``, ``m s^-2``, ``m/s/s``, ``[m/s²]`` ->
    ``m/s^2``; ``N-m``, ``N.m`` -> ``n*m``)."""
    s = "".join(str(label).translate(_SPELLING).replace("**", "^").split()).lower()
    while len(s) > 2 and s[0] + s[-1] in ("()", "[]"):
        s = s[1:-1]
    s = re.sub(r"sec(ond)?s?(?![a-z])", "s", s)
    s = re.sub(r"(?<=[a-z])[-.](?=[a-z])", "*", s)
    s = re.sub(r"(/s/s|/s2|\*?s\^?-2)$", "/s^2", s)
    return re.sub(r"\*?s\^?-1$", "/s", s)


def _describe(unit: _Unit) -> str:
    if unit.kind == "force":
        return "a moment" if unit.rotational else "a force"
    return ("an angular " if unit.rotational else "a" + "n" * (unit.kind[0] in "aeiou") + " ") + unit.kind


def _text(label: Any) -> str:
    """A units label as written, without the blanks that pad its field."""
    return "" if label is None else str(label).strip()


def _rotational(direction: int) -> bool | None:
    """Whether a DOF direction is a rotation; None for a scalar point (either)."""
    return None if direction == 0 else abs(direction) > 3


@dataclass
class FileUnits:
    """The unit rules of one UFF file; collects what its labels gave rise to for the warnings."""

    src: str
    length: float = 1.0
    force: float = 1.0
    has_164: bool = False
    unrecognised: dict[str, int] = field(default_factory=dict)  # abscissa label -> dataset
    disagree: list[str] = field(default_factory=list)

    @classmethod
    def of(cls, src: str, datasets: list[dict]) -> FileUnits:
        length, force = unit_factors(src, datasets)
        return cls(src, length, force, any(d.get("type") == 164 for d in datasets))

    # -- helpers -------------------------------------------------------------------------------

    def _where(self, d: dict) -> str:
        return f"{self.src}: dataset {d['_index'] + 1} (58)"

    def _lookup(self, text: str, table: dict[str, _Unit],
                other: dict[str, _Unit]) -> tuple[_Unit | None, bool] | None:
        """The unit a label names in ``table`` (or, as a contradiction, in ``other``) and
        whether it came from ``other``; ``(None, False)`` for no label, None for a label not
        recognised."""
        key = normalise_label(text)
        if key in _BLANK:
            return None, False
        if key in table:
            return table[key], False
        if key in other:
            return other[key], True
        return None

    def _factor_164(self, d: dict, axis: str, spec: int, direction: int, is_force: bool,
                    unit: _Unit | None) -> float:
        """The dataset-164 factor of an axis (file units per SI unit). The standard makes the
        length/force exponents relevant for a general or unknown data type and for a scalar
        DOF; all zero (what most writers put) means "not given". A scalar DOF is a rotation
        when its label says so, else a translation."""
        exps = [int(d.get(f"{axis}_{q}_unit_exp") or 0) for q in ("len", "force")]
        if (spec in _UNKNOWN or direction == 0) and any(exps):
            return self.length ** exps[0] * self.force ** exps[1]
        rotation = _rotational(direction)
        if rotation is None:
            rotation = unit is not None and unit.rotational
        if is_force:  # a moment is force x length
            return self.force * self.length if rotation else self.force
        return 1.0 if rotation else self.length  # radians take no factor

    def _axis(self, d: dict, axis: str, name: str, spec: int, direction: int,
              table: dict[str, _Unit], other: dict[str, _Unit], label: str,
              whole: str | None = None) -> tuple[_Unit | None, float]:
        """(unit the label names or None, SI per file unit) of the ordinate or denominator.

        ``label`` is the axis's units label, or its part of the ordinate label ``whole`` when
        that carries the whole FRF unit (``Gs/N``); messages name both."""
        shown = repr(label) if whole is None else f"{label!r} (of {whole!r})"
        said = f"{name} unit label {label!r}" if whole is None else f"{name} unit {shown}"
        found = self._lookup(label, table, other)
        if found is None:
            # The file says the values are in a unit whose factor is unknown: taking them as
            # SI (or the 164's) would give a wrong scale behind a warning (docs/exchange.md).
            units = "the units of dataset 164" if self.has_164 else "SI (the file has no dataset 164)"
            raise InputError(f"{self._where(d)}: {said} is not a unit ssidlab knows, so the "
                             "FRF's scale cannot be known; change it to a unit listed in "
                             "docs/exchange.md (e.g. 'g', 'mm/s', 'N', 'g/N') or to NONE to "
                             f"read the {name} in {units}")
        unit, wrong_table = found
        f164 = self._factor_164(d, axis, spec, direction, table is _FORCE, unit)
        if unit is None:
            return None, 1.0 / f164
        expected = _SPEC_KIND.get(spec)
        if wrong_table or (expected is not None and unit.kind != expected):
            what = (f"{SPEC_NAMES.get(spec, spec)} (specific data type {spec})" if expected
                    else "a force" if table is _FORCE else "a response (motion)")
            raise InputError(f"{self._where(d)}: {said} is {_describe(unit)} unit, but the "
                             f"{name} is {what}")
        rotation = _rotational(direction)
        if rotation is not None and unit.rotational != rotation:
            dof = format_dof_label(d.get(f"{'rsp' if axis == 'ordinate' else 'ref'}_node", 0), direction)
            raise InputError(f"{self._where(d)}: {said} is {_describe(unit)} unit, but {dof} "
                             f"is a {'rotation' if rotation else 'translation'}")
        if self.has_164 and not math.isclose(unit.si * f164, 1.0, rel_tol=_AGREE_RTOL):
            self.disagree.append(f"{shown} in dataset {d['_index'] + 1} (58), where "
                                 f"dataset 164 makes the unit {1 / f164:.6g} "
                                 f"{_SI_NAME[(unit.kind, unit.rotational)]}")
        return unit, unit.si

    def _ratio(self, d: dict, ordinate: str, denominator: str, table: dict[str, _Unit],
               other: dict[str, _Unit]) -> tuple[str, str] | None:
        """(numerator, denominator) of an ordinate label that carries the whole FRF unit
        (``Gs/N``, ``g/lbf``, ``mm/s/N``, ``(m/s^2)/N``: ME'scope and others write the FRF's
        unit on the ordinate and NONE on the denominator), or None for a plain label.

        The label is cut at the last ``/`` that leaves two known units (a motion or force unit
        each; a part of the wrong kind is then refused by :meth:`_axis` with its reason). A
        denominator label naming another unit than the ratio's contradicts it."""
        if self._lookup(ordinate, table, other) is not None:
            return None  # blank or a plain unit: "m/s" is no ratio
        for k in reversed([i for i, c in enumerate(ordinate) if c == "/"]):
            num, den = ordinate[:k].strip(), ordinate[k + 1:].strip()
            num_found = self._lookup(num, table, other)
            den_found = self._lookup(den, _FORCE, _MOTION)
            if num_found and num_found[0] and den_found and den_found[0]:
                break
        else:
            return None
        given = self._lookup(denominator, _FORCE, _MOTION)
        if given != (None, False) and given != den_found:
            raise InputError(f"{self._where(d)}: ordinate unit label {ordinate!r} gives the "
                             f"denominator's unit ({den!r}), but the denominator label is "
                             f"{denominator!r}")
        return num, den

    # -- what uff.py asks --------------------------------------------------------------------

    def abscissa_factor(self, d: dict) -> float:
        """Hz per abscissa unit of a function (1 without a recognised label)."""
        label = _text(d.get("abscissa_axis_units_lab"))
        found = self._lookup(label, _ABSCISSA, {})
        if found is None:
            # Reported, not refused: a frequency's unit does not depend on the 164 (which has
            # no time factor), so an abscissa typed or taken as frequency is in Hz by default.
            self.unrecognised.setdefault(label, d["_index"])
            return 1.0
        unit = found[0]
        if unit is None:
            return 1.0
        if unit.kind != "frequency":
            raise InputError(f"{self._where(d)}: abscissa unit label {label!r} is "
                             f"{'a time' if unit.kind == 'time' else 'an order'}, not a frequency")
        return unit.si

    def frf_factor(self, d: dict, kind: str, freq_hz: np.ndarray) -> tuple[Any, bool]:
        """Factor turning an FRF (``kind`` "frf") or a reaction ("reaction") into SI
        accelerance or reaction per force, and whether the file said what both the ordinate
        and the denominator are (by data type or by label)."""
        spec = int(d.get("ordinate_spec_data_type") or 0)
        den = int(d.get("orddenom_spec_data_type") or 0)
        if kind == "frf" and spec not in (*_UNKNOWN, *_KIND_SPEC.values()):
            raise InputError(f"{self._where(d)}: FRF ordinate is "
                             f"{SPEC_NAMES.get(spec, f'specific data type {spec}')}; only "
                             "acceleration, velocity or displacement per force can become an "
                             "accelerance")
        if den not in (*_UNKNOWN, SPEC_FORCE):
            # Per acceleration (a transmissibility), per pressure: no FRF of the file's kind.
            raise InputError(f"{self._where(d)}: FRF per "
                             f"{SPEC_NAMES.get(den, f'specific data type {den}')}; an FRF file "
                             "holds responses per input force (denominator: excitation force, "
                             "specific data type 13)")
        table, other = (_FORCE, _MOTION) if kind == "reaction" else (_MOTION, _FORCE)
        ordinate = _text(d.get("ordinate_axis_units_lab"))
        denominator = _text(d.get("orddenom_axis_units_lab"))
        whole = None
        ratio = self._ratio(d, ordinate, denominator, table, other)
        if ratio is not None:
            whole, (ordinate, denominator) = ordinate, ratio
        num_unit, k_num = self._axis(d, "ordinate", "ordinate", spec, int(d.get("rsp_dir") or 0),
                                     table, other, ordinate, whole)
        den_unit, k_den = self._axis(d, "orddenom", "denominator", den,
                                     int(d.get("ref_dir") or 0), _FORCE, _MOTION, denominator,
                                     whole)
        known = den == SPEC_FORCE or den_unit is not None
        if kind == "reaction":
            return k_num / k_den, known
        if spec in _UNKNOWN and num_unit is not None:
            spec = _KIND_SPEC[num_unit.kind]  # the label says what the ordinate is
        omega = 2 * np.pi * freq_hz
        motion = {SPEC_VELOCITY: 1j * omega, SPEC_DISPLACEMENT: -(omega**2)}.get(spec, 1.0)
        return motion * (k_num / k_den), known and spec not in _UNKNOWN

    def warnings(self) -> list[str]:
        """One message per kind of finding in the file (none when there was nothing to say)."""
        out = []
        if self.unrecognised:
            labels = ", ".join(map(repr, self.unrecognised))
            first = min(self.unrecognised.values()) + 1
            out.append(f"{self.src}: abscissa unit label(s) {labels} not recognised (first in "
                       f"dataset {first}); read as frequency in Hz")
        if self.disagree:
            out.append(f"{self.src}: {len(self.disagree)} axis unit label(s) disagree with "
                       f"dataset 164, e.g. {self.disagree[0]}; the labels were followed")
        return out
