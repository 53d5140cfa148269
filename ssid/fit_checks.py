"""What the measured lines say about an identified model that its own checks cannot.

:func:`ssid.modal.physical_checks` asks whether M, C, K can be a structure's. A model can be
physical and still not describe the data: a fit that failed under noise, a band holding more
than the model can hold, a free-free structure whose mass the lines do not fix. Nor do the
lines determine every number a model carries: a resonance narrower than the line spacing is
seen only on its skirts, which do not depend on its damping. These checks compare the
written model with the data it came from, and say so where the numbers are not backed by it.
"""

from __future__ import annotations

import numpy as np

from .frf import FRFData
from .noise import data_noise_weights

__all__ = ["DAMPING_SIGNATURE_FLOOR", "MISFIT_FLOOR", "MISFIT_NOISE_RATIO", "MODES_HELD_RTOL", "misfit_warning",
           "misfits", "modes_not_held_warning", "relative_noise_level", "unresolved_damping_warning"]

#: Relative RMS difference between the model's FRFs and the data above which, when it is
#: also MISFIT_NOISE_RATIO times the data's own noise, the model is said not to reproduce
#: the data. 5 %: on the audits behind this check, models whose modes and matrices were right
#: reproduced their data within 3 % (1 % noise), and those badly wrong were 12-99 % off.
MISFIT_FLOOR = 0.05
#: The data's relative noise (from the file's variances or coherence, else the FRFs'
#: roughness, which can understate it several times) times this is what a right model may
#: miss by.
MISFIT_NOISE_RATIO = 3.0


def relative_noise_level(frf: FRFData, w: np.ndarray | None = None) -> float:
    """The data's noise relative to its response, ``sqrt(sum sigma^2) / ||H||`` over the valid
    values, from the noise weights ``w = 1 / sigma`` (default
    :func:`ssid.noise.data_noise_weights`; 0 where a value is left out)."""
    w = data_noise_weights(frf) if w is None else w
    ok = w > 0
    sigma = np.where(ok, 1.0 / np.where(ok, w, 1.0), 0.0)
    scale = float(np.linalg.norm(np.where(ok, frf.H, 0.0)))
    return float(np.sqrt(np.sum(sigma**2)) / scale) if scale > 0 else np.inf


def misfits(frf_relative_rms_error: float, noise: float) -> bool:
    """Whether a model's FRFs miss the data they were fitted to by more than
    :data:`MISFIT_FLOOR` and :data:`MISFIT_NOISE_RATIO` times the noise (or by a non-finite
    amount): the criterion of :func:`misfit_warning`, for commands that word their own."""
    e = float(frf_relative_rms_error)
    return not np.isfinite(e) or (e > MISFIT_FLOOR and e > MISFIT_NOISE_RATIO * noise)


def misfit_warning(frf_relative_rms_error: float, noise: float, *, reactions: bool = False,
                   modes_in_band: tuple[int, int] | None = None, load_cells_suspect: bool = False,
                   reactions_undetermined: bool = False) -> str | None:
    """A warning when the written model's FRFs differ from the data of the band it was fitted
    to by more than :data:`MISFIT_FLOOR` and :data:`MISFIT_NOISE_RATIO` times the noise.

    Parameters
    ----------
    frf_relative_rms_error : float
        ``||H - H_model|| / ||H||`` of the written M, C, K over the valid values.
    noise : float
        The data's relative noise level (:func:`relative_noise_level`).
    reactions : bool
        The data hold interface reactions. Band processing (``ssidlab bands``), which checks
        the modes band by band, refuses them (step 1 with reactions is not determined in a
        narrow band, docs/algorithm.md): the advice is then what does help.
    modes_in_band : (int, int), optional
        How many of the model's modes lie in the band, and how many it has: said with
        ``reactions``, where the modes outside the band are what the lines lack.
    load_cells_suspect : bool
        Load cells read by their factors explain the misfit (``ssid.load_cells``): they are
        the advice, not the band.
    reactions_undetermined : bool
        Step 1 cannot determine a reaction's term (``ssid.step1_reaction_spread``: a stand
        much softer or stiffer than the substructure): a wider band does not help.
    """
    e = float(frf_relative_rms_error)
    if not misfits(e, noise):
        return None
    said = (f"the written M, C, K reproduce the measured FRFs only to {100 * e:.3g} % (RMS; "
            f"the data's noise is about {100 * noise:.2g} %): the fit failed, or the band "
            "holds what a model of this order cannot (more modes than DOFs, modes outside "
            "it, a free-free structure); ")
    # A short band leaves step 1's columns short of the modes above it, which the load-cell
    # check reads as a wrong cell too (the payload on its stand, 20-600 Hz, 7 of 16 modes in
    # it: 4+Z "read" 0.17); a wrong cell with the modes in the band does not need a wider one.
    held = "" if modes_in_band is None else f" ({modes_in_band[0]} of its {modes_in_band[1]} modes lie in it)"
    head = (f"the written M, C, K reproduce the measured FRFs only to {100 * e:.3g} % (RMS; the data's "
            f"noise is about {100 * noise:.2g} %): ")
    if load_cells_suspect:
        return (head + "the load cell(s) named above, read by their factors, explain it (see above): check the "
                "load cells first (sign, calibration, label) and correct them before using the matrices")
    if reactions_undetermined:
        # A wider band does not separate a soft stand's reactions from the substructure's own
        # interface stiffness and damping (the QA's 2e4 N/m, 400 N s/m stand: 104 % misfit).
        return (head + "the reaction term(s) named above are not determined by these data (see above), which "
                "puts the stand's interface into M, C, K; a wider band does not help: trust only the modes "
                f"inside the band{held}, and for the matrices test on a stand whose interface forces the data "
                "can separate, or free")
    if not reactions:
        return said + "check its modes against the data (e.g. ssidlab bands) before using the matrices"
    # A short stepped sine on a stand (20-600 Hz, 16 DOFs, 7 of 15 modes in the band) missed
    # its data by 462 %; the same setup swept over 20-1500 Hz reproduced them to 0.37 %, and
    # four times the lines over 20-600 Hz to 55 %: the modes above the band were what it lacked.
    return (said + "with interface reactions in the record band processing (ssidlab bands) does not "
            f"apply: trust only the modes inside the band{held}, and for the matrices measure a wider "
            "band, one that reaches the structure's higher modes (more lines in the same band do not "
            "hold the modes outside it)")


#: Relative difference between a root of the written M, C, K and the identified root it stands
#: for above which the matrices are said not to hold the identified modes. The written model
#: is step 2's fit to step 1's roots: on the guide's records (docs/guide.md sections 3 and 7)
#: its roots lie within 0.0005 % and 0.03 % of them in the band, 0.02 % and 0.18 % in all. A full-order
#: 8-DOF chain under 1 % noise with one input held its roots to 0.003 % while its written K
#: put the top mode 3 % off (M, K 12 % and 26 % off), with nothing else to say so.
MODES_HELD_RTOL = 0.01


def modes_not_held_warning(root_freq_hz: np.ndarray, written_root_freq_hz: np.ndarray,
                           band_hz: tuple[float, float] | None = None) -> str | None:
    """A warning when the written model's roots are not the identified ones.

    Parameters
    ----------
    root_freq_hz : (m,) Hz
        The identified (step 1) roots' natural frequencies ``|lambda| / 2 pi``, oscillatory ones.
    written_root_freq_hz : (m',) Hz
        The same of the written M, C, K's own roots. Compared in ascending order when
        ``m' == m``; otherwise the real-root and definiteness checks speak for the model.
    band_hz : (low, high), optional
        Compare only where the identified root lies in this band. For a model fitted to the
        data themselves (:mod:`ssid.step2_refine`): outside the band neither it nor step 1 is
        held by the lines (on the free payload, 20-1500 Hz at 0.02 % noise, its lowest root was
        0.19 % from the true one and step 1's 1.7 %).
    """
    f = np.sort(np.asarray(root_freq_hz, dtype=float))
    g = np.sort(np.asarray(written_root_freq_hz, dtype=float))
    if f.size == 0 or f.size != g.size or not np.all(np.isfinite(g)):
        return None
    rel = np.abs(g / f - 1)
    if band_hz is not None:
        rel = np.where((f >= band_hz[0]) & (f <= band_hz[1]), rel, 0.0)
    k = int(np.argmax(rel))
    if rel[k] <= MODES_HELD_RTOL:
        return None
    return (f"the written M, C, K do not hold the identified modes: their mode {k + 1} is at "
            f"{g[k]:.6g} Hz, the identified root at {f[k]:.6g} Hz ({100 * rel[k]:.3g} % off): the "
            "roots are what the data determine best, and the matrices, fitted to the same noisy lines, "
            "are less certain: use them with care")


#: Below this share of the response at the nearest line, a resonance's damping is taken as
#: not seen (whatever the data's stated noise: calibration and nonlinearity alone exceed it).
DAMPING_SIGNATURE_FLOOR = 0.01


def unresolved_damping_warning(line_freq_hz: np.ndarray, freq_hz: np.ndarray, zeta: np.ndarray,
                               noise: float) -> str | None:
    """A warning naming the modes inside the band whose damping the lines do not see.

    At a line ``d`` Hz from a resonance at ``f``, the damping term of the mode's response is
    about ``zeta f / d`` of the rest (the imaginary part of ``1 / (f_n^2 - f^2 + 2 j zeta f_n
    f)`` over its real part); when that is below the data's noise (times
    :data:`MISFIT_NOISE_RATIO`) or :data:`DAMPING_SIGNATURE_FLOOR` at the line nearest the
    mode, the lines see only the skirts of the resonance and its damping ratio (and C) is not
    determined by them. When no mode lies in the band at all, that is the warning instead:
    every resonance is seen only by its tail.

    Parameters
    ----------
    line_freq_hz : (n_freq,) array
        The lines of the band the model was identified on, Hz.
    freq_hz, zeta : (m,) arrays
        The model's modes: natural frequencies, Hz, and damping ratios.
    noise : float
        The data's relative noise level (:func:`relative_noise_level`).
    """
    lines = np.asarray(line_freq_hz, dtype=float)
    f = np.asarray(freq_hz, dtype=float)
    z = np.asarray(zeta, dtype=float)
    inside = (f >= lines[0]) & (f <= lines[-1])
    if f.size and not inside.any():
        return (f"no mode of the model lies in the band ({lines[0]:g}-{lines[-1]:g} Hz): the lines "
                "see only the tails of its resonances, so its frequencies and damping are "
                "extrapolated, not measured")
    nearest = np.min(np.abs(lines[None, :] - f[:, None]), axis=1) if f.size else f
    with np.errstate(divide="ignore", invalid="ignore"):
        signature = np.where(nearest > 0, z * f / np.where(nearest > 0, nearest, 1.0), np.inf)
    floor = max(DAMPING_SIGNATURE_FLOOR, MISFIT_NOISE_RATIO * noise)
    unseen = inside & (z > 0) & (signature < floor)
    if not unseen.any():
        return None
    listed = ", ".join(f"{v:.4g}" for v in f[unseen])
    return (f"mode(s) at {listed} Hz: so lightly damped for the line spacing that their damping "
            f"shows at the nearest line as under {100 * floor:.2g} % of the response, within "
            "the noise: the lines do not determine their damping (nor C); measure with finer "
            "lines around them")
