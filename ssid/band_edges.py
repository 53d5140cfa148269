"""Band layout for band processing (report section 5.2): where the overlapping bands lie.

Overlapping bands over a record's lines (even or logarithmic), their default width, the
fewest lines step 1 needs per band, and the line spacing that sets the selection criteria's
tolerances. :mod:`ssid.bands` processes the bands and re-exports these names.
"""

from __future__ import annotations

import numpy as np

from .frf import FRFData

__all__ = [
    "band_layout",
    "band_min_lines",
    "default_band_width_hz",
    "default_bands",
    "distance_to_nearest_line",
    "high_edge_band",
    "line_spacing_at",
    "lines_evenly_spaced",
    "low_edge_band",
    "min_lines_for_two_bands",
    "overlapping_bands",
]


def overlapping_bands(f_lo_hz: float, f_hi_hz: float, width_hz: float,
                      overlap: float = 0.5) -> list[tuple[float, float]]:
    """Bands of ``width_hz`` over [f_lo, f_hi], each overlapping the next by ``overlap``.

    Every line must lie in at least two bands for criterion 4 (a true root is found again in
    another band), so the list starts and ends with a part-band clipped at the record's
    edges: with 50 % overlap, ``(f_lo, f_lo + w/2), (f_lo, f_lo + w), (f_lo + w/2, ...)``.
    """
    if width_hz <= 0 or not 0 < overlap < 1:
        raise ValueError("band width must be > 0 and overlap in (0, 1)")
    step = width_hz * (1 - overlap)
    bands = []
    lo = f_lo_hz - step
    while lo < f_hi_hz:
        a, b = max(lo, f_lo_hz), min(lo + width_hz, f_hi_hz)
        if b > a and (not bands or (a, b) != bands[-1]):
            bands.append((a, b))
        if lo + width_hz >= f_hi_hz + step - 1e-12 * width_hz:
            break
        lo += step
    return bands


def band_min_lines(n_out: int, n_in: int, n_react: int = 0) -> int:
    """Fewest lines a band needs for step 1: enough real equations (``2 n_in`` per line) for
    the ``p = 2 n + n_in + n_r`` unknowns of each row of Eq. 3.7, plus one."""
    return int(np.ceil((2 * n_out + n_in + n_react) / (2 * n_in))) + 1


def _default_band_spacings(n_lines: int, overlap: float, min_lines: int) -> float:
    """Default band width in line spacings: 1/12 of the record, at least 24, and wide enough
    that the part-bands at the record's ends (``overlap`` of a band) hold ``min_lines``."""
    return max((n_lines - 1) / 12.0, 24.0, min_lines / overlap)


def default_band_width_hz(freq_hz: np.ndarray, overlap: float = 0.5, min_lines: int = 0) -> float:
    """Band width for band processing over a record's evenly spaced lines (Hz): 1/12 of its
    span, at least 24 lines (a band then holds one or two modes of a sparse spectrum, and
    enough lines per unknown for step 1 at a few sensors), and at least wide enough that the
    part-bands at the ends (``overlap`` of a band) hold ``min_lines``
    (:func:`band_min_lines`; with many sensors and one input, more than 12); never wider than
    the record, whose bands are then the record and its two part-bands
    (:func:`default_bands`)."""
    f = np.asarray(freq_hz, dtype=float)
    span = float(f[-1] - f[0])
    df = span / max(f.size - 1, 1)
    # The rule of _default_band_spacings, in Hz: span / 12 is kept as written so that the
    # band edges of an even record stay exactly what they were (a line on an edge belongs to
    # both bands only if the arithmetic puts it there).
    return min(max(span / 12.0, 24 * df, min_lines / overlap * df), span)


def min_lines_for_two_bands(min_lines: int, overlap: float = 0.5) -> int:
    """Fewest lines a record needs for overlapping bands whose every line lies in two bands
    that step 1 can fit (criterion 4 needs that): the smallest layout is the record and its
    two part-bands (``overlap`` of it), each holding ``min_lines`` (:func:`band_min_lines`),
    so ``overlap (L - 1)`` spacings must hold ``min_lines - 1``."""
    return int(np.ceil((min_lines - 1) / overlap - 1e-9)) + 1


def lines_evenly_spaced(freq_hz: np.ndarray, rtol: float = 1e-3) -> bool:
    """Whether a record's lines are evenly spaced (within ``rtol`` of their mean spacing;
    loose enough for frequencies stored in single precision)."""
    d = np.diff(np.asarray(freq_hz, dtype=float))
    return d.size == 0 or float(np.ptp(d)) <= rtol * float(np.mean(d))


def default_bands(freq_hz: np.ndarray, overlap: float = 0.5,
                  min_lines: int = 0) -> list[tuple[float, float]]:
    """Overlapping bands over a record's lines when the analyst gives no band width.

    Evenly spaced lines (the report's records, random excitation): bands of
    :func:`default_band_width_hz` by :func:`overlapping_bands`. Unevenly spaced lines (a
    stepped-sine sweep on a logarithmic grid, refined near resonances): bands of equal line
    count, about the count that rule gives on an even grid (1/12 of the record's spacings, at
    least 24), adjusted so that the bands step through the record a whole number of times and
    the last part-band holds half a band of lines like the first (a shorter one could hold too
    few lines for step 1, and the modes there would be found in one band only). A band of fixed
    width in Hz holds few lines where a log grid is coarse: on the payload's 16 Z sensors over
    20-1500 Hz in 152 lines 2.9 % apart, the 1/12 bands above 450 Hz held fewer than the 10
    lines step 1 needs with two shakers, and the modes at 567, 828 and 1320 Hz were lost.
    On an even grid the whole steps are taken too when the last part-band would otherwise
    hold fewer than ``min_lines`` (it would be skipped, and the lines it alone shares with
    its neighbour found in one band).

    A record shorter than one such band (a zoom sweep, a narrow --fmin/--fmax) gets the
    record as its band, with its two part-bands (``overlap`` of it): every line in two bands
    that step 1 can fit, so criterion 4 can confirm a root, as long as each part-band holds
    ``min_lines`` (:func:`min_lines_for_two_bands`; the smallest band accepted: 19 lines for
    16 sensors and two shakers, whose part-bands hold the 10 step 1 needs). A narrower
    part-band is not fitted at all (:func:`ssid.bands.process_bands` skips it), so its lines
    would lie in one fitted band again. With fewer lines than that no layout lets criterion 4
    confirm anything: the record is returned as one band, and
    :func:`ssid.bands.process_bands` warns that no root can be confirmed. (Rounded to whole
    steps of at least 12 lines as before, a 22-line zoom sweep became one band and its
    78.39 Hz mode, a perfect root, was rejected as "not repeated".)

    ``min_lines`` (:func:`band_min_lines`): the fewest lines step 1 needs; the bands are made
    wide enough that the part-bands at the ends hold that many.

    Returns
    -------
    list of (lo, hi) in Hz.
    """
    f = np.asarray(freq_hz, dtype=float)
    span = float(f.size - 1)  # in line spacings
    if f.size < 2 or f.size < min_lines_for_two_bands(min_lines, overlap):
        return [(float(f[0]), float(f[-1]))]  # no two overlapping bands step 1 can fit
    if lines_evenly_spaced(f):
        width = default_band_width_hz(f, overlap, min_lines)
        bands = overlapping_bands(float(f[0]), float(f[-1]), width, overlap)
        if np.count_nonzero(f >= bands[-1][0] - 1e-9 * width) >= min_lines:
            return bands
        # Too short a last part-band: whole steps, as on an uneven grid (below).
    # The same layout in line-index space, mapped back to Hz.
    step = _default_band_spacings(f.size, overlap, min_lines) * (1 - overlap)
    if step / (1 - overlap) >= span:
        step = span * (1 - overlap)  # the record is the band: itself and its two part-bands
    else:
        step = span / max(1, int(span / step))  # whole steps, each no shorter than asked
    index = np.arange(f.size, dtype=float)

    def at(x: float) -> float:  # an edge on a line (up to rounding) is that line's frequency
        k = round(x)
        return float(f[k]) if abs(x - k) < 1e-9 else float(np.interp(x, index, f))

    return [(at(a), at(b)) for a, b in overlapping_bands(0.0, span, step / (1 - overlap), overlap)]


def band_layout(frf: FRFData, width_hz: float | None = None,
                overlap: float = 0.5) -> tuple[list[tuple[float, float]], float | None]:
    """The overlapping bands over ``frf``'s lines and their width in Hz.

    With ``width_hz``, bands of that width (:func:`overlapping_bands`). Without,
    :func:`default_bands`, wide enough for step 1 at the record's outputs and inputs
    (:func:`band_min_lines`); the width returned is then that of its widest band on evenly
    spaced lines, None on unevenly spaced ones (the bands hold equal numbers of lines
    instead)."""
    f = frf.freq_hz
    if width_hz is not None:
        return overlapping_bands(float(f[0]), float(f[-1]), width_hz, overlap), width_hz
    bands = default_bands(f, overlap, band_min_lines(frf.n_out, frf.n_in, frf.n_react))
    if not lines_evenly_spaced(f):
        return bands, None
    width = max(hi - lo for lo, hi in bands)  # the rule's, unless the record or whole steps cut it
    rule = default_band_width_hz(f, overlap, band_min_lines(frf.n_out, frf.n_in, frf.n_react))
    return bands, rule if abs(width - rule) <= 1e-9 * rule else width


def line_spacing_at(line_freq_hz: np.ndarray, freq_hz) -> np.ndarray:
    """The record's line spacing (Hz) where each ``freq_hz`` lies: the distance between the
    two lines that bracket it (beyond the first or last line, the spacing there).

    This is the ``df`` of criteria 3 and 4: how far apart the lines are that see a root. On an
    evenly spaced record it is the spacing; on a logarithmic sweep it grows with frequency.
    """
    lines = np.asarray(line_freq_hz, dtype=float)
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if lines.size < 2:
        return np.zeros(f.shape)
    d = np.diff(lines)
    return d[np.clip(np.searchsorted(lines, f) - 1, 0, d.size - 1)]


def distance_to_nearest_line(line_freq_hz: np.ndarray, freq_hz) -> np.ndarray:
    """Distance (Hz) from each ``freq_hz`` to the record's nearest line.

    For a root narrower than the line spacing this is what locates it: its nearest line sees
    its resonance as ``r / (f_n - f)``, so a relative noise ``e`` there moves the estimate by
    about ``e |f_n - f|`` (criterion 4's tolerance, :func:`ssid.bands.repeat_tolerance_hz`).
    """
    lines = np.asarray(line_freq_hz, dtype=float)
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if lines.size == 0:
        return np.zeros(f.shape)
    return np.min(np.abs(f[:, None] - lines[None, :]), axis=1)


#: The low-edge band spans this many times the widest band that starts at the record's first
#: line: the next step of the layout's sequence there (part-band w/2, whole band w, 3w/2).
LOW_EDGE_BAND_FACTOR = 1.5


def _record_span(bands_hz: list[tuple[float, float]], line_freq_hz: np.ndarray
                 ) -> tuple[np.ndarray, float, float, float] | None:
    """The record's lines, first and last line (Hz) and the round-off that counts as at an
    edge, for :func:`low_edge_band` and :func:`high_edge_band`; None with fewer than two
    lines or no bands."""
    lines = np.asarray(line_freq_hz, dtype=float)
    if lines.size < 2 or not bands_hz:
        return None
    f0, f_end = float(lines[0]), float(lines[-1])
    return lines, f0, f_end, 1e-9 * (f_end - f0)


def low_edge_band(bands_hz: list[tuple[float, float]],
                  line_freq_hz: np.ndarray) -> tuple[float, float] | None:
    """A third band at the record's low edge, for roots narrower than the line spacing there.

    A mode below the record's first line spacing (a suspension mode) lies in the bands that
    start at the first line only: with 50 % overlap the part-band and the whole band, two
    nested fits. When the n-DOF fit of one of them puts a computational root beside the mode
    (its estimate is then far off, with an MPC near 0), criterion 4 has no second estimate
    and the mode is lost, or the bad estimate is paired with the good one. This band,
    :data:`LOW_EDGE_BAND_FACTOR` times the widest of those, holds other lines above and so
    other computational roots: a third estimate. On the payload at 12 sensors over
    1-1158 Hz (report noise, seeds 0-30) the 1.29 Hz mode was lost or 19 % off on 2 of 31
    seeds with two bands, and found within 1.9 % on every seed with three
    (:func:`ssid.bands.process_bands` counts this band's roots only when no line resolves
    them, and never takes one as a mode's estimate).

    Returns
    -------
    (lo, hi) in Hz, or None when no band starts at the first line or one already spans
    the record up to that width.
    """
    record = _record_span(bands_hz, line_freq_hz)
    if record is None:
        return None
    _, f0, f_end, tiny = record
    first = [hi - lo for lo, hi in bands_hz if lo <= f0 + tiny]
    if not first:
        return None
    hi = min(f0 + LOW_EDGE_BAND_FACTOR * max(first), f_end)
    if any(lo <= f0 + tiny and b >= hi - tiny for lo, b in bands_hz):
        return None
    return f0, hi


def high_edge_band(bands_hz: list[tuple[float, float]],
                   line_freq_hz: np.ndarray) -> tuple[float, float] | None:
    """A third band at the record's high edge, the counterpart of :func:`low_edge_band`.

    At the record's last line the layout ends as it begins: with 50 % overlap the top
    part-band lies wholly inside the band before it, two nested fits that share every line
    of the part-band and its noise. A noise root fitted there comes out of both and passes
    criterion 4: on the payload's random record with one shaker (16 sensors, 20-1500 Hz,
    bands of 123 Hz) a 1456.5 Hz root with 0.04 % damping and MPC 0.96 was confirmed by the
    bands 1376.7-1500 and 1438.3-1500 Hz, where the structure has no mode. This band, ending
    at the last line and spanning :data:`LOW_EDGE_BAND_FACTOR` times as many line spacings as
    the widest band there (the next step of the layout, counted in lines so that a log grid's
    coarse top gets a band of that many lines, not of 1.5 times its width in Hz; on an even
    grid, 1.5 widths as at the low edge), holds other lines below
    and so other computational roots: :func:`ssid.band_criteria.reject_top_nested_only`
    requires its estimate of a root that only the nested top bands found (1456.5 Hz: none
    there; the 1318.7 Hz mode: found).

    Returns
    -------
    (lo, hi) in Hz, or None when no band ends at the last line or one already spans the
    record down to that many lines.
    """
    record = _record_span(bands_hz, line_freq_hz)
    if record is None:
        return None
    lines, f0, f_end, tiny = record
    last = [int(np.count_nonzero((lines >= lo - tiny) & (lines <= hi + tiny)))
            for lo, hi in bands_hz if hi >= f_end - tiny]
    if not last:
        return None
    # In line spacings, so that on an even grid it is 1.5 widths as at the low edge.
    n = min(int(np.ceil(LOW_EDGE_BAND_FACTOR * (max(last) - 1) - 1e-9)), lines.size - 1)
    lo = float(lines[-n - 1])
    if any(a <= lo + tiny and b >= f_end - tiny for a, b in bands_hz):
        return None
    return lo, f_end
