"""RMS limits for random excitation: their keys, the window they are taken over, and the
sliding RMS a random run checks them with.

A random test is specified by RMS levels (an acceleration RMS, "grms", or a force RMS),
and its peak limit is only a backstop: under Gaussian drive the largest sample grows with
the record's length, so a peak limit trips by chance, more often the longer the blocks and
the more averages. An RMS over a fixed window does not.
"""

from __future__ import annotations

import math

import numpy as np

from ssid.errors import InputError

__all__ = ["RMS_LIMIT_KEYS", "RMS_WINDOW_S", "SlidingRms", "refuse_rms_limits"]

#: The window (s of record) an RMS limit is taken over, checked on every piece the random run
#: reads (``daq.random_run.LIMIT_CHECK_S``). Fixed in time, not the block: the limit then
#: means the same whatever ``block_size`` and ``averages`` (blocks run from 0.25 s to 2 s and
#: more across setups), the dependence on the analysis that made the peak limit trip by
#: chance. Long enough to be stable: a mean square over T of a response of effective
#: bandwidth B scatters by 1/sqrt(B T), its root by half that, about 5 % over 1 s for a
#: response spread over 100 Hz (the 3-DOF example at 40-200 Hz: the 1 s RMS of an
#: accelerometer between 0.71 and 0.79 of an overall 0.75 m/s^2); a 0.1 s window would
#: scatter three times more. Short enough to trip quickly: the sum of squares is divided by
#: the whole window from the first piece on (the record before the drive counts as zero), so
#: a level k times the limit trips after at most 1/k^2 s of drive (0.25 s at twice the
#: limit), and the peak limit stays the backstop within a piece.
RMS_WINDOW_S = 1.0

#: The RMS limits' keys in ``[limits]``, each with the peak limit of the same quantity, which
#: a stepped-sine setup is told to use instead, and its unit.
RMS_LIMIT_KEYS = {"max_accel_rms_m_per_s2": ("max_accel_m_per_s2", "m/s^2"),
                  "max_force_rms_n": ("max_force_n", "N"),
                  "max_reaction_rms_n": ("max_reaction_n", "N")}


def refuse_rms_limits(src: str, given: dict) -> None:
    """Refuse an RMS limit in a stepped-sine setup.

    A sine's RMS is exactly its peak / sqrt(2), so the peak limit says the same. Applied
    beside the peak limit, a line's abort or hold would name a limit not written for sine;
    ignored, the engineer would believe a limit held that does not. So it is refused, with
    the peak limit that says the same.

    Parameters
    ----------
    src : str
        The setup file, for the message.
    given : dict
        The ``[limits]`` table as read (its values already checked as numbers).

    Raises
    ------
    InputError
        An RMS key is in ``given``.
    """
    for key, (peak_key, unit) in RMS_LIMIT_KEYS.items():
        if key in given:
            v = float(given[key])
            raise InputError(f"{src}: [limits] {key}: RMS limits apply to random excitation only; a stepped-sine "
                             f"line is limited by its peak: set {peak_key} (a sine's peak is sqrt(2) times its "
                             f"RMS: {math.sqrt(2) * v:g} {unit} for an RMS of {v:g} {unit})")


class SlidingRms:
    """Per-channel RMS over the last :data:`RMS_WINDOW_S` of a record read in pieces.

    Kept for the whole run, across averages, pauses and restarts: the drive level of a
    random run is fixed, so the record before a pause is a fair part of the estimate, and
    forgetting it would only delay a trip.

    Parameters
    ----------
    n_ch : int
        Channels in each piece.
    fs_hz : float
        Sample rate of the record.
    """

    def __init__(self, n_ch: int, fs_hz: float) -> None:
        self.n = max(1, int(round(RMS_WINDOW_S * fs_hz)))
        self.tail = np.zeros((n_ch, 0))

    def add(self, data: np.ndarray) -> np.ndarray:
        """Add a piece ``(n_ch, n)`` of the record; return each channel's RMS over the window.

        The sum of squares is divided by the whole window even before a window's worth was
        read (the record before the drive counting as zero): a short start then never reads
        as more than it is, and a gross exceedance still trips within a fraction of the window.
        """
        self.tail = np.hstack([self.tail, np.asarray(data, float)])[:, -self.n:]
        return np.sqrt(np.sum(self.tail ** 2, axis=1) / self.n)
