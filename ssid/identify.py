"""``identify_mck``: the SSID pipeline from an FRF file's data to M, C, K and modal results.

Step 1 (``ssid.step1``) estimates ``M^-1 C, M^-1 K, M^-1 D`` ; step 2 (``ssid.step2``) solves the
state-space eigenproblem, fits the modal scale factors and rebuilds M, C, K, whose damping matrix
and refinement ``ssid.written_model`` chooses; the result is an ``ssid.result.SSIDResult``. The
default solver ``"ml"`` is ours (see ``docs/algorithm.md``): a weighted equation-error start
followed by a maximum-likelihood (output-error) refinement, with weights from the file's variances
or coherence when it has them and from the fit's own residuals when it does not.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import replace

import numpy as np

from .errors import IdentificationError, InputError
from .fit_checks import (
    misfit_warning,
    modes_not_held_warning,
    relative_noise_level,
    unresolved_damping_warning,
)
from .frf import FRFData, requested_band, require_frequency_dependence, require_response
from .load_cells import correction_trial_text, load_cell_check, load_cell_correction_trial, load_cell_warning
from .modal import (
    complex_modes,
    modal_phase_collinearity,
    physical_checks,
    root_frequency_damping,
    unit_max_shapes,
)
from .noise import data_noise_weights, frf_noise_weights
from .reaction_fit import refit_where_reactions_undetermined
from .reciprocity import reciprocity_check
from .result import SSIDResult, model_accelerance, model_frf_errors, model_output_error
from .solvers import power_of_two_near
from .step1 import Step1Data, Step1Estimate, estimate_equation_error, step1_data
from .step1_ml import step1_maximum_likelihood
from .step1_reaction_spread import reaction_fit_note, undetermined_reactions_warning
from .step1_refine import output_error_cost
from .written_model import (
    STEP1_DAMPING_MISMATCH_MAX,
    choose_damping,
    hard_problems,
    refine_written_model,
    step2_mck,
    undamped_modes,
    written_root_freq_hz,
)

__all__ = ["SSIDResult", "identify_mck", "identify_step1", "SOLVERS", "DAMPING_OPTIONS",
           "model_accelerance", "model_frf_errors", "model_output_error"]

SOLVERS = ("ml", "ls", "tls", "stls")
#: ``damping`` of :func:`identify_mck`: the damping matrix the delivered model carries.
DAMPING_OPTIONS = ("auto", "identified", "modal")


@contextlib.contextmanager
def singular_fit_refused() -> Iterator[None]:
    """Turn a linear-algebra failure of an identification's fits into an IdentificationError.

    The data that pass the entry checks (:func:`ssid.frf.require_response`,
    :func:`ssid.frf.require_frequency_dependence`) can still leave a fit without a solution:
    a singular dynamic-stiffness matrix or normal matrix, an SVD that does not converge. That
    is a property of the data, not a bug, and its user needs a message rather than a
    traceback. Only ``numpy.linalg.LinAlgError`` is turned; any other exception is a bug and
    passes unchanged. Also usable as a decorator of an identification entry point.
    """
    try:
        yield
    except np.linalg.LinAlgError as exc:
        raise IdentificationError(
            f"the fit has no unique solution on these FRFs ({exc}): the response does not "
            "determine a model (outputs that read alike, or no resonance in the band?)") from exc


def _rigid_body_note(n_rigid: int, rigid: dict) -> str:
    """What the result says about the rigid-body modes it holds (``rigid``: the info of
    :func:`ssid.rigid_body.choose_rigid_body_modes`)."""
    test = next(t for t in rigid["tests"] if t["n_rigid_body_modes"] == n_rigid)
    f_line = rigid["lowest_line_rad_per_s"] / (2 * np.pi)
    return (f"{n_rigid} rigid-body mode(s): the {2 * n_rigid} roots nearest 0 "
            f"(|lambda| <= {max(test['roots_abs_rad_per_s']):.3g} rad/s, below the lowest line at "
            f"{f_line:.4g} Hz) fit the data as well as rigid-body motion does, and are taken as such: K is "
            "singular, its null space the rigid-body shapes, and C is zero on them. That is a free-free "
            "structure's; suspension modes far enough below the band that the noise hides their stiffness "
            "(a structure on bungees or soft mounts) show the same way, and so, on a structure held to "
            "ground, do a mode no input excites and a DOF without mass (which the identified M cannot hold)")


def _real_roots_warning(real_roots: np.ndarray, m: int, n: int, n_rigid: int, rigid: dict) -> str:
    """The warning for real roots; those below the lowest line that failed the rigid-body test
    are named as what they are: not rigid-body modes, by the data."""
    said = (f"{real_roots.size} real (non-oscillatory) root(s): the model has {m} oscillatory modes"
            f"{f' and {n_rigid} rigid-body mode(s)' if n_rigid else ''} for {n} DOFs")
    tests = rigid.get("tests", []) if rigid else []
    rejected = tests[-1] if tests and tests[-1]["n_rigid_body_modes"] > n_rigid else None
    if rejected is not None:
        return (f"{said}; the roots nearest 0 (|lambda| <= {max(rejected['roots_abs_rad_per_s']):.3g} rad/s, "
                "below the lowest line) fit the data significantly better than rigid-body modes "
                "would (a likelihood-ratio test), so K is not made singular there")
    return f"{said} (noise or too few modes in the band)"


# Largest |H| (valid values) inside which step 1 works on the data as they are. Outside, it works
# on H divided by the power of two nearest that largest value and scales M^-1 D back: the
# equation-error starts (the report's TLS) are not invariant to the scale of H beside the unit
# columns of D, and the starts' output errors (squared weighted residuals) left float64 at
# |H| ~ 1e-90, where band processing then found 14 of the 15 modes it finds at |H| ~ 1. Inside
# (1e-12 to 1e12: accelerances in any unit a lab uses) nothing is scaled, and results stay bit for
# bit what they were.
_STEP1_UNSCALED_LARGEST_H = (2.0**-40, 2.0**40)


def identify_step1(
    frf: FRFData, solver: str = "ml", candidates: dict | None = None, restart_real_roots: bool = True,
    low_line_starts: bool = True, search_above_band: bool = True, model_error_levels: bool = True,
) -> tuple[Step1Estimate, Step1Data, dict]:
    """Step 1 of SSID on all lines of ``frf``: ``M^-1 C, M^-1 K, M^-1 D`` (Eqs. 3.6-3.9).

    Data whose largest |H| lies far from 1 (outside 2^-40 to 2^40) are fitted divided by a power
    of two near it, exactly, and the estimates, the arranged data and the starts come back in
    the data's own scale (``_STEP1_UNSCALED_LARGEST_H``).

    Returns the estimate, the arranged data with the noise weights the solver used (step 2
    and band processing reuse them), and ``info`` (with a ``warnings`` list). With ``ml``,
    ``candidates`` (if given) receives the equation-error starts by name, and without
    reactions a model left with real roots is refined once more from oscillatory ones
    (:func:`ssid.step1_refine.oscillatory_start`) unless ``restart_real_roots`` is False.
    Band processing turns it off: its band fits have more roots than the band has modes, and
    their real roots are the computational ones its criteria reject; made oscillatory, they
    came out alike in neighbouring bands as false modes (a 1.53 Hz one beside the 1.29 Hz
    suspension mode on the 12-sensor payload, 1-1158 Hz, seed 4). ``low_line_starts`` adds
    the starts of :func:`ssid.step1.starts_above_low_lines` (``ml`` without reactions); band
    processing turns it off too, as its criteria were tuned on where its band fits stop, and
    so it does ``search_above_band`` (:func:`ssid.step1_refine.refine_roots_above_band`,
    ``ml`` without reactions), whose moved roots would be its band fits' computational ones.
    ``model_error_levels`` (``ml`` without reactions or file variances) takes an FRF's flat
    noise level from its differences where the fit's residuals show model error
    (:func:`ssid.step1_ml.step1_maximum_likelihood`, step 4); band processing turns it off:
    the error its band fits leave is that of modes narrower than a line at the low edge, and
    weighting it as noise kept the 1.29 Hz suspension mode of the 16-sensor payload (1-2300 Hz,
    200 Hz bands) within 0.06-0.22 % on seeds 1-5, against 0.17-1.26 % with the differences'
    levels.
    """
    if solver not in SOLVERS:
        raise InputError(f"unknown solver {solver!r}; choose one of {', '.join(SOLVERS)}")
    valid = frf.valid_mask()
    largest = float(np.max(np.abs(np.where(valid, np.nan_to_num(frf.H), 0.0)), initial=0.0))
    lo, hi = _STEP1_UNSCALED_LARGEST_H
    unit = power_of_two_near(largest)
    options = (restart_real_roots, low_line_starts, search_above_band, model_error_levels)
    if largest == 0.0 or lo <= largest <= hi or unit == 1.0:
        return _identify_step1(frf, solver, candidates, *options)
    scaled = replace(frf, H=frf.H / unit, H_var=None if frf.H_var is None else frf.H_var / unit**2)
    starts: dict | None = None if candidates is None else {}
    est, d, info = _identify_step1(scaled, solver, starts, *options)
    if candidates is not None:
        candidates.update({name: _step1_in_scale(e, unit) for name, e in starts.items()})
    # Weights are 1/sigma up to a common factor shared with the reactions' (not scaled).
    return _step1_in_scale(est, unit), replace(d, H=d.H * unit, weight=d.weight / unit), info


def _step1_in_scale(est: Step1Estimate, unit: float) -> Step1Estimate:
    """A step-1 estimate of H / ``unit`` for H itself: ``M^-1 C``, ``M^-1 K`` do not depend on the
    scale of H; ``M^-1 D_f``, ``M^-1 D_r`` scale with it (the accelerance is ``M^-1`` times forces)."""
    return Step1Estimate(est.C_hat, est.K_hat, est.Df_hat * unit, est.Dr_hat * unit)


def _identify_step1(
    frf: FRFData, solver: str, candidates: dict | None, restart_real_roots: bool, low_line_starts: bool,
    search_above_band: bool, model_error_levels: bool,
) -> tuple[Step1Estimate, Step1Data, dict]:
    """:func:`identify_step1` on data of any scale (the arguments are its own)."""
    valid = frf.valid_mask()
    weights = frf_noise_weights(frf)
    info: dict = {"n_lines": frf.n_freq, "n_values_blanked": int(np.count_nonzero(~valid))}
    if frf.n_react and weights is not None and solver == "ml":
        # Measured, not assumed: on the payload on its stand under the report's noise, the
        # search from the variances of the averages (H_var, H_reaction_var, as acquisition
        # writes them) ended at 190 times the true model's cost on one seed of four (22 %,
        # 7 modes missed) and 3-4 % on two others; from levels estimated from the data and
        # re-estimated at the fit, 0.5-2.1 % on seeds 1-7 (docs/algorithm.md, known limits).
        weights = None
        info["noise_levels"] = ("estimated from the data (the file's variances or coherence are "
                                "not used with reactions)")
    know_noise = weights is not None
    d = step1_data(frf, weights)
    warnings: list[str] = []
    if not d.col_ok.all():
        warnings.append(
            f"{int(np.count_nonzero(~d.col_ok))} (line, input) columns hold a blanked value and "
            "are left out of the equation-error fits"
        )
    if solver == "ml":
        est = step1_maximum_likelihood(d, valid, know_noise, info, candidates, restart_real_roots,
                                       low_line_starts, search_above_band, model_error_levels)
        if "ml_skipped" in info:
            warnings.append(info["ml_skipped"])
    else:
        est = estimate_equation_error(d, solver)
    info["warnings"] = warnings
    return est, d, info


@singular_fit_refused()
def identify_mck(
    frf: FRFData,
    *,
    solver: str = "ml",
    f_min_hz: float | None = None,
    f_max_hz: float | None = None,
    damping: str = "auto",
    search_above_band: bool = True,
    check_load_cells: bool = True,
) -> SSIDResult:
    """Identify M, C, K of a substructure from accelerance FRFs with SSID.

    Parameters
    ----------
    frf : FRFData
        Accelerances ``H`` (n_freq, n_out, n_in) at all outputs for each input, optionally the
        interface reactions ``H_reaction`` (substructure on a test stand, section 3.1), a
        ``valid`` mask (blanked values are not used by any fit), ``H_var`` or ``coherence``.
    solver : {"ml", "ls", "tls", "stls"}
        Step-1 solver: ``ml`` (default) maximum-likelihood output-error refinement;
        ``ls``, ``tls``, ``stls`` the report's least squares, total least squares and scaled
        TLS on the equation-error form (Eqs. 3.7, 5.5, 5.14, section 5.1.3).
    f_min_hz, f_max_hz : float, optional
        Band of lines to use (default: all).
    damping : {"auto", "identified", "modal"}
        ``identified``: C from the A_s partition (Eq. 3.15); ``modal``: C rebuilt from the
        identified damping ratios and the real modes of (K, M) (section 6.2.3); ``auto``
        (default): of those two, and of step 1's ``M^-1 C`` on the written M (``step1``,
        where the fit is one second-order system, :func:`ssid.written_model.choose_damping`),
        the one whose model predicts the band's measurements better (``info["damping_choice"]``;
        ``checks["frf_relative_rms_error"]`` is the delivered model's relative RMS FRF error).
        With ``auto`` and ``ml`` and no reactions, a written model that misses data step 1's
        own model holds is then refined by output error, M, C and K together, and written when
        physical (``damping`` ``"output_error"``, ``info["output_error_refinement"]``;
        :func:`ssid.written_model.refine_written_model`).
    search_above_band : bool
        With ``ml`` and no reactions: after the refinement, search along the frequencies of
        the roots above the band (:func:`ssid.step1_refine.refine_roots_above_band`).
    check_load_cells : bool
        With reactions: check the load cells against the accelerances
        (:func:`ssid.load_cells.load_cell_check`), and where one is suspect identify again
        with its reactions divided by its factor to see whether that explains the misfit
        (``info["load_cells"]["correction_trial"]``).

    Returns
    -------
    SSIDResult

    Raises
    ------
    InputError
        FRFs no analysis can use (:func:`ssid.frf.require_response`), an unknown ``solver`` or
        ``damping``, a band limit that is not a finite number.
    IdentificationError
        Too few valid lines, FRFs that do not determine a model (the same at every line, of
        rank below the outputs; :func:`ssid.frf.require_frequency_dependence`), or a fit
        without a unique solution (:func:`singular_fit_refused`).
    """
    if solver not in SOLVERS:
        raise InputError(f"unknown solver {solver!r}; choose one of {', '.join(SOLVERS)}")
    if damping not in DAMPING_OPTIONS:
        raise InputError(f"unknown damping option {damping!r}; choose {', '.join(DAMPING_OPTIONS)}")
    frf = require_response(frf)
    lo, hi = requested_band(frf, f_min_hz, f_max_hz)
    data = frf.band(lo, hi)
    if data.n_freq == 0:
        raise IdentificationError(f"no frequency lines between {lo:g} and {hi:g} Hz")
    require_frequency_dependence(data)
    starts: dict = {}
    est, d, info = identify_step1(data, solver=solver, candidates=starts, search_above_band=search_above_band)
    warnings = list(info.pop("warnings"))
    undetermined = None
    if data.n_react:  # a reaction step 1 cannot separate from the substructure (soft or stiff stand)
        undetermined, info["reaction_spread"] = undetermined_reactions_warning(data, d, est)
        warnings.extend([undetermined] if undetermined else [])
    warnings.extend(f"{p.describe()}; the symmetric M, C, K that SSID fits cannot hold both: check these "
                    "transducers before trusting the model" for p in reciprocity_check(data) if not p.reciprocal)

    step1_weight = d.weight
    modes, M, C, K, asm, rigid = step2_mck(d, est, solver)
    written_from = est  # the step-1 estimate whose roots the written model holds
    if solver == "ml" and (problems := hard_problems(modes, M, K)):
        # The refinement fits the data best but cannot hold what the data lack (e.g. a
        # reduced-order model with modes outside its reach); a start that is physical wins.
        tried = {"ml": (problems, output_error_cost(d, est))}
        best = None
        for name, cand in starts.items():
            d.weight = step1_weight
            try:
                res = step2_mck(d, cand, solver)
            except (IdentificationError, np.linalg.LinAlgError):
                continue
            score = (hard_problems(res[0], res[1], res[3]), output_error_cost(d, cand))
            tried[name] = score
            if score < tried["ml"] and (best is None or score < tried[best[0]]):
                best = (name, res, cand)
        info["candidates"] = {k: {"problems": v[0], "output_error": v[1]} for k, v in tried.items()}
        if best is not None:
            modes, M, C, K, asm, rigid = best[1]
            written_from = best[2]
            info["selected"] = best[0]
            warnings.append(
                f"the maximum-likelihood refinement gave a non-physical model; the "
                f"{best[0]} start, with fewer problems, is used instead"
            )
    info.update(asm)
    # Step 1's free reaction columns absorb a load cell's sign or gain, and step 2's M takes
    # the error (QA: -1.21 kg total mass for 6.06 kg): say which cell, from the columns.
    # Where step 1 cannot determine a reaction's column (a soft or stiff stand) its ratios to
    # the inputs' columns say nothing about the cell: not checked (the QA's soft stand named
    # every cell, none of them wrong).
    cells = (load_cell_check(data, d, written_from) if data.n_react and check_load_cells and not undetermined
             else None)
    if cells is not None:
        info["load_cells"] = cells
        said = load_cell_warning(cells)
        if said:
            warnings.append(said)
    if rigid:
        info["rigid_body"] = rigid
    n_rigid = modes.n_rigid

    m = modes.n_pairs
    lam, theta, real_roots = modes.lam[:m], modes.theta_x[:, :m], modes.lam[2 * m :].real
    w = data_noise_weights(data)  # one estimate for the damping choice and the fit checks
    refit = None
    # A reaction step 1 cannot determine puts its error in M, C, K (QA's soft stand: M 240 % off);
    # fitted in physical coordinates, where D_r is known, 0.03 % (ssid.reaction_fit). Its roots
    # and shapes are then the model's own, and step 2's rigid-body or real roots are gone.
    # Only with the file's variances: the fit weights each equation by the reactions' noise,
    # which nothing else gives (the 8-DOF stand at 2 % noise, seeds 1 and 3: with them M 2-3 %
    # and K 1.4-1.6 % off, step 2's 56-102 % and 5-9 %; without them K came out 76-81 % off).
    stated = data.H_var is not None and data.H_reaction_var is not None
    if (undetermined and damping == "auto" and stated
            and (refit := refit_where_reactions_undetermined(data, M, C, K, w))):
        info["reaction_fit"] = refit[3]
        warnings[warnings.index(undetermined)] = undetermined + reaction_fit_note(refit[3])
        if refit[3]["accepted"]:
            M, C, K = refit[:3]
            lam, theta = complex_modes(M, C, K)
            n_rigid, real_roots = 0, np.zeros(0)
    wn, zeta = root_frequency_damping(lam)
    shapes = unit_max_shapes(theta)
    mpc = modal_phase_collinearity(shapes)
    if n_rigid:
        warnings.append(_rigid_body_note(n_rigid, rigid))
    if real_roots.size:
        warnings.append(_real_roots_warning(real_roots, m, d.n, n_rigid, rigid))

    undamped, phi = undamped_modes(M, K, n_rigid)
    # The modal C takes the ratios in the order of eig(K, M), whose first r are rigid (0 Hz).
    zeta_all = np.concatenate([np.zeros(n_rigid), zeta])
    # M C^ is the written model's C only where the written M is that of step 1's system: the
    # fit is one second-order system (the three copies of M agree, as on full-order chains
    # under noise: 8e-6 to 3e-4), not a reduced-order one (a 5-of-14-DOF model: 0.023, where
    # M C^ gave its first mode 4.7 % damping against the roots' 2.0 %).
    one_system = asm.get("mass_copies_mismatch", np.inf) < STEP1_DAMPING_MISMATCH_MAX
    C_step1 = M @ written_from.C_hat if one_system and not n_rigid else None
    requested = damping
    if refit and refit[3]["accepted"]:  # C is the fit's own: the one that reproduces the data
        damping = "output_error"
        info["damping_choice"] = {"weighted_output_error": {damping: refit[3]["cost"]}, "chosen": damping,
                                  "frf_relative_rms_error": {damping: refit[3]["frf_relative_rms_error"]}}
    else:
        C, damping, info["damping_choice"] = choose_damping(data, M, C, K, zeta_all, damping,
                                                            phi is not None, w, C_step1)
    frf_error = info["damping_choice"]["frf_relative_rms_error"][damping]
    noise = relative_noise_level(data, w)
    band = (float(data.freq_hz[0]), float(data.freq_hz[-1]))
    # Not with reactions: taken as exact loads, their noise biases the fit (the guide's record
    # on its stand: 0.228 % refined to 0.016 %, but the worst undamped mode of its M, K outside
    # the band went from 0.2 % to 2 % off the simulated truth, and in the band none came closer).
    if requested == "auto" and solver == "ml" and not n_rigid and not data.n_react:
        refined = refine_written_model(data, M, C, K, w, noise,
                                       (info["damping_choice"]["weighted_output_error"][damping], frf_error),
                                       d, written_from)
        if refined is not None:
            info["output_error_refinement"] = refined[3]
            if refined[3]["accepted"]:
                M, C, K = refined[:3]
                frf_error = refined[3]["frf_relative_rms_error"]
                damping = "output_error"
                undamped, phi = undamped_modes(M, K, n_rigid)
    checks, chk_warn = physical_checks(M, C, K, zeta)
    checks.update({k: v for k, v in asm.items()})
    checks["frf_relative_rms_error"] = frf_error
    warnings.extend(chk_warn)
    f_n = wn / (2 * np.pi)
    in_band = (int(np.count_nonzero((f_n >= band[0]) & (f_n <= band[1]))), int(f_n.size))
    explained = False
    if cells and cells["suspect"]:
        # What the cells' factors would explain: identified again with the suspect cells read
        # by their factors. A short band also makes cells look wrong, and correcting them
        # then leaves the misfit where it was (the payload on its stand at 20-600 Hz).
        trial = load_cell_correction_trial(
            data, cells, frf_error,
            lambda f: identify_mck(f, solver=solver, damping=requested, search_above_band=search_above_band,
                                   check_load_cells=False).checks["frf_relative_rms_error"])
        cells["correction_trial"] = trial
        explained = bool(trial and trial["explains"])
        warnings.append(correction_trial_text(trial))
    warnings.extend(said for said in (misfit_warning(checks["frf_relative_rms_error"], noise,
                                                     reactions=bool(data.n_react), modes_in_band=in_band,
                                                     load_cells_suspect=explained,
                                                     reactions_undetermined=bool(undetermined)),
                                      unresolved_damping_warning(data.freq_hz, wn / (2 * np.pi), zeta, noise),
                                      # M not definite: the physical checks have said more already
                                      None if phi is None else
                                      modes_not_held_warning(wn / (2 * np.pi), written_root_freq_hz(M, C, K),
                                                             band if damping == "output_error" else None))
                    if said)
    return SSIDResult(
        M=M,
        C=C,
        K=K,
        dofs=list(data.outputs),
        natural_freq_hz=wn / (2 * np.pi),
        damping_ratio=zeta,
        mpc=mpc,
        mode_shapes=shapes,
        undamped_freq_hz=undamped,
        real_mode_shapes=phi,
        real_roots=real_roots,
        n_rigid_body_modes=n_rigid,
        solver=solver,
        damping=damping,
        band_hz=band,
        checks=checks,
        warnings=warnings,
        info=info,
        # Step 2 re-weights d for Eq. 3.23: the data as step 1 weighted it.
        step1=(written_from, replace(d, weight=step1_weight)),
    )

