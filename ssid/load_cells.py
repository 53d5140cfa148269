"""Whether the measured interface reactions agree with the accelerances: a check of the load cells.

Step 1 fits ``M^-1 D_f`` and ``M^-1 D_r`` as free columns (Eq. 3.8), one per input force and
one per measured reaction. A load cell that reads ``gamma`` times its force (a sign, a
calibration, a label that puts its force at another DOF) leaves step 1's fit and its roots
exact: the free column absorbs ``1/gamma``. Step 2 then builds one symmetric M from all the
columns, and the error lands there (QA: a sign-flipped cell gave a total mass of -1.21 kg for
6.06 kg; a 10 % calibration error, M 13 % off) with nothing in the roots to show it.

The columns themselves show it. They are columns of one symmetric ``G = M^-1``: the input
force at DOF ``f`` gives ``G[:, f]`` (the force gauges are the reference), the reaction at DOF
``r`` gives ``G[:, r] / gamma_r``. So ``Df[r, f] / Dr[f, r] = gamma_r``, once per input. Each
such ratio comes with the uncertainty the data give it: each output's row of step 1 is a
linear fit over the lines (Eq. 3.7), whose covariance is ``s^2 (Z^H W Z)^-1`` with ``W`` from
the stated noise of every value in the row's equation (``H_var`` or coherence,
``H_reaction_var``) and ``s^2`` the row's reduced chi-square when it exceeds 1; the deviation
is then taken ``SIGMA_UNDERSTATED`` times larger, as measured on clean records. A load cell is
suspect when its factor (the inverse-variance mean over the inputs) lies more than
``Z_SUSPECT`` deviations from 1, or its ratios disagree with each other by as much (a label:
the column is another DOF's), and a ratio differs from 1 by more than ``FACTOR_RTOL_FLOOR``.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import numpy as np

from .errors import IdentificationError
from .frf import FRFData
from .noise import frf_noise_weights, variance_of_weight, weight_of_variance
from .step1 import Step1Data, Step1Estimate, step1_regressors

__all__ = ["FACTOR_RTOL_FLOOR", "SIGMA_UNDERSTATED", "TRIAL_EXPLAINS", "Z_SUSPECT", "correction_trial_text",
           "load_cell_check", "load_cell_correction_trial", "load_cell_warning"]

#: The stated-variance standard deviation of a ratio understates the error of step 1's
#: maximum-likelihood estimate: the noise common to a test's accelerances (the force gauge's)
#: is correlated across outputs, which the per-value variance does not say. Measured: on the
#: payload's 16-DOF substructure on its stand (20-1500 Hz, 170 lines, 1e-4 relative noise,
#: seeds 1-3) the clean load cells' ratios lay up to 25.7 of those deviations from 1, on the
#: QA's simulated acquisition up to 6; noise-free, within 1e-12 of 1. Each deviation is taken
#: this many times larger.
SIGMA_UNDERSTATED = 10.0
#: A load cell is suspect when its factor lies more than this many (inflated) deviations from
#: 1, or its ratios from the inputs disagree by as much (chi-square above its square). Clean:
#: at most 2.6; a sign flip 96, a label 32 (ratios of opposite sign), a missing reaction 21 on
#: the cell left to carry it, a 10 % calibration 1.6-1.8 on the synthetic record (within the
#: noise there) and 7 on the QA's acquisition.
Z_SUSPECT = 5.0
#: An entry of a column below this fraction of the columns' largest is taken as zero (not
#: determined), whatever its stated uncertainty.
DETERMINED_RTOL = 1e-6
#: An entry within this many (inflated) deviations of zero is not determined either: the
#: ratio's first-order deviation does not hold there.
DETERMINED_Z = 2.0
#: Corrected by their factors, suspect cells explain the misfit when it falls to at most this
#: fraction of what it was (a 10 % calibration: 14 % to about the noise; a band without its
#: higher modes: unchanged).
TRIAL_EXPLAINS = 0.5
#: Nor is a factor within 1 % of 1 reported, however small its uncertainty: a load cell's
#: calibration is not known better than that.
FACTOR_RTOL_FLOOR = 0.01


def _row_covariances(frf: FRFData, d: Step1Data, est: Step1Estimate, rows: list[int]) -> dict[int, np.ndarray]:
    """Covariance (p, p) of step 1's row estimate for each output row in ``rows``.

    The row's equation error ``e_kj = h_kj + z_kj x`` (Eq. 3.7,
    :func:`ssid.step1.step1_regressors`) is linear in ``x``. Its noise is that of every
    accelerance and reaction it holds (errors in variables): ``sum_m |delta_im + C^_im / (j w)
    - K^_im / w^2|^2 var H_mj + sum_l |Dr^_il|^2 var R_lj``, from the file's stated variances
    (``H_var`` or coherence; ``H_reaction_var``). Weighted by it, the least-squares covariance
    is ``(Z^H W Z)^-1`` (real and imaginary parts as separate equations), scaled by the reduced
    chi-square of step 1's estimate when that exceeds 1 (noise understated, model error).
    Without a stated variance: unit weights scaled by the reduced chi-square (the residual is
    the noise).
    """
    Z = step1_regressors(d, d.H)  # (L, n_in, p)
    X = est.to_x()
    w = frf_noise_weights(frf)
    var_h = None if w is None else variance_of_weight(w)
    var_r = None if frf.H_reaction_var is None else np.asarray(frf.H_reaction_var, dtype=float)
    omega = d.omega[:, None]
    out = {}
    for i in rows:
        h = d.H[:, i, :]  # (L, n_in)
        var = np.ones(h.shape)
        if var_h is not None:
            coef = np.eye(d.n)[i][None, :] + est.C_hat[i][None, :] / (1j * omega) - est.K_hat[i][None, :] / omega**2
            var = np.einsum("km,kmj->kj", np.abs(coef) ** 2, var_h)
            if var_r is not None:
                var = var + np.einsum("l,klj->kj", est.Dr_hat[i] ** 2, var_r)
        ok = d.col_ok & (d.weight[:, i, :] > 0) & (var > 0)
        wi = np.where(ok, weight_of_variance(var), 0.0)
        A = (wi[:, :, None] * Z).reshape(-1, Z.shape[2])
        A = np.concatenate([A.real, A.imag])
        reduced = float(np.sum(np.abs(wi * (h + Z @ X[i])) ** 2)) / max(A.shape[0] - A.shape[1], 1)
        out[i] = (reduced if var_h is None else max(reduced, 1.0)) * np.linalg.pinv(A.T @ A)
    return out


def load_cell_check(frf: FRFData, d: Step1Data, est: Step1Estimate) -> dict:
    """Each load cell's factor from step 1's columns, its uncertainty and whether it is suspect.

    Parameters
    ----------
    frf : FRFData
        The band's data step 1 was fitted to, with reactions; its ``H_var`` or coherence (if
        any) states the noise, else each row's residual does.
    d, est : Step1Data, Step1Estimate
        Step 1's arranged data and the estimate step 2 used.

    Returns
    -------
    dict
        ``cells``: reaction label -> ``factor`` (the inverse-variance mean of the ratios: how
        many times its force the cell read), ``sigma``, ``per_input`` (input label ->
        ``[ratio, sigma]``, only where both entries are determined: none when M^-1 is diagonal
        there), ``z``, ``inputs_disagree_chi2``, ``suspect``; ``unchecked``: the cells no ratio
        determines; ``suspect``: the suspect labels; ``test``: the criterion in words. Empty
        ``cells`` without reactions.
    """
    react, inputs = list(frf.reactions or []), list(frf.inputs)
    stated = ("H_var" if frf.H_var is not None else "coherence" if frf.coherence is not None
              else "none stated: each row's residual")
    res: dict = {"cells": {}, "suspect": [], "unchecked": [],
                 "test": (f"ratios Df[r, f] / Dr[f, r] of step 1's columns of one symmetric M^-1, per input; "
                          f"suspect when the factor is more than {Z_SUSPECT:g} sigma from 1, or the inputs' ratios "
                          f"disagree by as much, and a ratio is more than {FACTOR_RTOL_FLOOR:g} from 1; sigma from "
                          f"the stated noise ({stated}) and the rows' reduced chi-square when above 1, times "
                          f"{SIGMA_UNDERSTATED:g}")}
    if not react or d.n_r == 0:
        return res
    n, n_in = d.n, d.n_in
    rows = sorted({int(i) for i in d.in_idx} | {int(i) for i in d.r_idx})
    cov = _row_covariances(frf, d, est, rows)
    X = est.to_x()
    for k, lbl in enumerate(react):
        r = int(d.r_idx[k])
        per = {}
        num = den = 0.0
        for j, f_lbl in enumerate(inputs):
            f = int(d.in_idx[j])
            ia, ib = 2 * n + j, 2 * n + n_in + k  # Df[:, j] and Dr[:, l] within a row of X
            a, b = X[r, ia], X[f, ib]
            # Both entries must be determined: a lumped (diagonal) M has G[r, f] = 0 off its
            # diagonal, and a ratio of two noises says nothing (a chain's noise-free record gave
            # 0.06 +- 0.18 for a right cell).
            sa = SIGMA_UNDERSTATED * np.sqrt(max(cov[r][ia, ia], 0.0))
            sb = SIGMA_UNDERSTATED * np.sqrt(max(cov[f][ib, ib], 0.0))
            small = DETERMINED_RTOL * max(np.max(np.abs(X[:, ia])), np.max(np.abs(X[:, ib])))
            if not (abs(a) > max(DETERMINED_Z * sa, small) and abs(b) > max(DETERMINED_Z * sb, small)):
                continue
            g = a / b
            # delta method on a / b; a and b lie in one row when the reaction is at the input's DOF
            J = np.array([1 / b, -a / b**2])
            if r == f:
                var = float(J @ cov[r][np.ix_([ia, ib], [ia, ib])] @ J)
            else:
                var = float(J[0] ** 2 * cov[r][ia, ia] + J[1] ** 2 * cov[f][ib, ib])
            s = SIGMA_UNDERSTATED * max(float(np.sqrt(max(var, 0.0))), 1e-12 * abs(g))
            per[f_lbl] = [float(g), s]
            num += g / s**2
            den += 1 / s**2
        if not per:
            res["unchecked"].append(lbl)
            continue
        factor, sigma = num / den, float(np.sqrt(1 / den))
        # Off 1 as a whole (sign, calibration, unit), or the inputs disagreeing on it (a label:
        # the column is another DOF's, whose symmetric partners are not these).
        z = abs(factor - 1.0) / sigma
        spread = float(sum((g - factor) ** 2 / s**2 for g, s in per.values()))
        off = max(abs(g - 1.0) for g, _ in per.values()) > FACTOR_RTOL_FLOOR
        suspect = bool(off and (z > Z_SUSPECT or spread > Z_SUSPECT**2))
        res["cells"][lbl] = {"factor": float(factor), "sigma": sigma, "per_input": per, "z": float(z),
                             "inputs_disagree_chi2": spread, "suspect": suspect}
        if suspect:
            res["suspect"].append(lbl)
    return res


def load_cell_warning(check: dict) -> str | None:
    """The warning naming the suspect load cells of :func:`load_cell_check`; None if none is."""
    if not check.get("suspect"):
        return None
    cells = check["cells"]

    def said(lbl: str) -> str:
        c = cells[lbl]
        per = ", ".join(f"{g:.4g} +- {s:.2g} from input {f}" for f, (g, s) in c["per_input"].items())
        return f"{lbl} reads {c['factor']:.4g} +- {c['sigma']:.2g} times its force ({per})"

    return ("load cell(s) disagree with the accelerances: " + "; ".join(said(lbl) for lbl in check["suspect"])
            + ", where the symmetric M^-1 that step 1's columns belong to puts 1: a sign (a cell mounted or wired "
            "reversed: about -1), a calibration or unit (a factor off 1), a label (the reaction recorded at the "
            "wrong DOF: ratios that disagree between inputs), or a stand contact whose reaction was not measured "
            "(every cell off); or step 1's columns are not those of one M^-1 (a band without the modes above "
            "it: then several cells seem off). The roots in the band are not affected (step 1 fits each "
            "reaction's column freely); the written M, C, K are: check the load cells before using the matrices")


def load_cell_correction_trial(frf: FRFData, check: dict, misfit: float,
                               misfit_of: Callable[[FRFData], float]) -> dict | None:
    """Identify again with each suspect cell's reactions divided by its factor, and compare.

    Only cells whose inputs agree on one factor are corrected (a label's ratios disagree: no
    factor corrects it). ``misfit_of(frf)`` is the written model's relative RMS FRF error of an
    identification of ``frf``; ``misfit`` the one with the cells as read.

    Returns
    -------
    dict or None
        ``corrected`` (label -> factor divided out), ``misfit_as_read``, ``misfit_corrected``,
        ``explains`` (the corrected misfit is at most :data:`TRIAL_EXPLAINS` of the other);
        None when no suspect cell has one factor, or the identification fails.
    """
    cells = check["cells"]
    one = {lbl: cells[lbl]["factor"] for lbl in check["suspect"]
           if cells[lbl]["inputs_disagree_chi2"] <= Z_SUSPECT**2 and abs(cells[lbl]["factor"]) > FACTOR_RTOL_FLOOR}
    if not one or frf.H_reaction is None:
        return None
    corrected = copy.copy(frf)
    gain = np.ones(len(frf.reactions))
    for lbl, g in one.items():
        gain[list(frf.reactions).index(lbl)] = g
    corrected.H_reaction = frf.H_reaction / gain[None, :, None]
    if frf.H_reaction_var is not None:
        corrected.H_reaction_var = frf.H_reaction_var / np.abs(gain[None, :, None]) ** 2
    try:
        after = float(misfit_of(corrected))
    except (IdentificationError, np.linalg.LinAlgError):
        return None
    return {"corrected": {lbl: float(g) for lbl, g in one.items()}, "misfit_as_read": float(misfit),
            "misfit_corrected": after, "explains": bool(after <= TRIAL_EXPLAINS * misfit)}


def correction_trial_text(trial: dict | None) -> str:
    """What the correction trial showed, for the warnings (after :func:`load_cell_warning`)."""
    if trial is None:
        return ("the inputs disagree on each suspect load cell's factor, so no one factor corrects it: a label "
                "(the reaction recorded at another DOF), a reaction not measured, a band without the structure's "
                "higher modes, or noise above what the file states; no correction was tried")
    read = ", ".join(f"{lbl} by {g:.4g}" for lbl, g in trial["corrected"].items())
    before, after = 100 * trial["misfit_as_read"], 100 * trial["misfit_corrected"]
    if trial["explains"]:
        return (f"load cell(s) read by their factors ({read}): the written model then reproduces the data to "
                f"{after:.3g} % instead of {before:.3g} %: the cell(s) explain the misfit; identify was not "
                "changed by this trial (correct the calibration or wiring, or use ssidlab discrepancy, which "
                "fits the factors)")
    return (f"load cell(s) read by their factors ({read}): the written model's misfit stays {after:.3g} % "
            f"(as read {before:.3g} %): the factors do not explain it; more likely a reaction that was not "
            "measured, or a band without the structure's higher modes (which makes the cells look wrong too)")
