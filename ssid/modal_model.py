"""The band-processed modal model (beyond the report): n-DOF M, C, K from the modes band
processing found, completed where the bands found too few.

An n-DOF model fitted to a band holding more modes than it has DOFs compromises between
them; band processing (report section 5.2, :mod:`ssid.bands`) locates each mode in narrow
overlapping bands instead, where it is well determined. :func:`modal_model_from_bands` keeps n
of them with independent shapes, scales them (BP1-BP3, Eq. 3.23) and assembles M, C, K as real
normal modes (:mod:`ssid.real_modes`). One or a few modes short, it completes them with a
residual pair above the band, rigid-body modes below it, or both (:mod:`ssid.band_residual`),
keeping the completion whose M, C, K predict the data best. :func:`identify_mck_modal` runs
band processing and this in one call; the band search (:mod:`ssid.band_select`) takes the
result as one of its candidates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .band_residual import (
    fit_residual_pair,
    fit_rigid_body_modes,
    fit_rigid_body_modes_and_pair,
    normal_mode_accelerance,
    rigid_body_fit_refusal,
)
from .band_scaling import root_shapes, scale_selected_roots, strongest_roots
from .bands import BandResult, band_layout, process_bands
from .correlate import modal_assurance, pair_modes_by_mac_and_frequency
from .errors import IdentificationError
from .fit_checks import misfits, relative_noise_level
from .frf import FRFData
from .modal import modal_phase_collinearity, physical_checks, real_modes, unit_max_shapes
from .noise import data_noise_weights
from .real_modes import normal_mode_mck, normal_mode_shapes, real_mode_mck, shapes_independent
from .result import SSIDResult, model_frf_errors, model_output_error

__all__ = ["identify_mck_modal", "modal_model_from_bands", "modal_model_misfit_warning"]


def identify_mck_modal(
    frf: FRFData,
    *,
    band_width_hz: float | None = None,
    scale: str = "BP3",
    solver: str = "ml",
    prefer_shapes: np.ndarray | None = None,
    prefer_freq_hz: np.ndarray | None = None,
    residual_pair: bool = True,
    rigid_body: bool = True,
) -> SSIDResult:
    """Reduced-order M, C, K assembled from band-processed modes (beyond the report).

    An n-DOF model fitted to a band holding more than n modes (or whose n modes are spatially
    truncated) compromises between them; band processing (section 5.2) instead locates every
    mode of the band in narrow overlapping bands (50 % overlap), where each is well
    determined, and :func:`modal_model_from_bands` assembles the model from them.

    Parameters
    ----------
    frf : FRFData
        Accelerances (L, n, n_in) without interface reactions.
    band_width_hz : float, optional
        Width of the overlapping bands. Default: :func:`ssid.bands.band_layout` (bands
        of :func:`ssid.bands.default_band_width_hz` on evenly spaced lines, of equal line count
        otherwise).
    scale, prefer_shapes, prefer_freq_hz, residual_pair, rigid_body
        As for :func:`modal_model_from_bands`.
    solver : step-1 solver in each band (as for :func:`ssid.identify.identify_mck`).

    Returns
    -------
    SSIDResult, as :func:`modal_model_from_bands`.

    Raises
    ------
    IdentificationError
        As :func:`modal_model_from_bands`.
    """
    if frf.H_reaction is not None:
        raise IdentificationError("the modal (band-processed) model is not available with "
                                  "measured interface reactions")
    bands, band_width_hz = band_layout(frf, band_width_hz)
    res = process_bands(frf, bands, solver=solver)
    return modal_model_from_bands(frf, res, scale=scale, band_width_hz=band_width_hz,
                                  prefer_shapes=prefer_shapes, prefer_freq_hz=prefer_freq_hz,
                                  residual_pair=residual_pair, rigid_body=rigid_body)


def modal_model_from_bands(
    frf: FRFData,
    res: BandResult,
    *,
    scale: str = "BP3",
    band_width_hz: float | None = None,
    prefer_shapes: np.ndarray | None = None,
    prefer_freq_hz: np.ndarray | None = None,
    residual_pair: bool = True,
    rigid_body: bool = True,
) -> SSIDResult:
    """n-DOF M, C, K from the modes band processing found (``res`` of :func:`process_bands`
    on ``frf``).

    Keeps the n strongest selected roots with independent shapes at the sensors
    (:func:`ssid.band_scaling.strongest_roots`), fits their scale factors (Eq. 3.23) and
    assembles M, C, K as real normal modes (:func:`ssid.real_modes.normal_mode_mck`):
    physical whenever every kept modal mass is positive, with eig(K, M) the kept roots'
    |lambda|^2 exactly. Which n modes it holds is the data's choice (their contribution to
    the measured FRFs), unless an analyst lists target modes (``prefer_shapes``, e.g. an FE
    model's at the sensors): roots paired with them (MAC x frequency ratio, MAC >= 0.8) are
    kept first, as the report picked its band-processing roots by hand. The modes it leaves
    out are simply absent from the model. With one mode too few (``residual_pair``), the
    last pair is fitted to what the found modes leave of the FRFs above the band
    (:func:`ssid.band_residual.fit_residual_pair`): a residual pair, which stands for the
    modes above the band; its damping ratio is the found modes' median (not in the data).
    With n - r modes found and a free-free structure (``rigid_body``), r rigid-body modes are
    fitted to the mass line of that residual (:func:`ssid.band_residual.fit_rigid_body_modes`,
    at most one per input): a free structure's accelerance tends to it below its first
    elastic mode, whose rigid-body modes (or suspension modes below the first line) the bands
    cannot find. With r + 1 modes short, r rigid-body modes and a pair are fitted together
    (:func:`ssid.band_residual.fit_rigid_body_modes_and_pair`): a free structure whose band
    also stops short of the modes above it. Each completion is fitted with the found modes'
    residues free alongside it, so that their scale factors' errors stay out of it. Where
    more than one fits, the one whose M, C, K predict the data best (weighted output error)
    is kept.

    Parameters
    ----------
    frf : FRFData
        Accelerances (L, n, n_in) without interface reactions.
    res : BandResult
    scale : {"BP1", "BP2", "BP3"}
        Scale-factor estimate (section 5.2.2).
    band_width_hz : float, optional
        Recorded in ``info["bands"]`` (the width ``res`` was processed with; None for bands
        of equal line count).
    prefer_shapes : (n, k) array, optional
        Target mode shapes at ``frf.outputs`` (real or complex), with ``prefer_freq_hz``
        (k,) their frequencies, Hz.
    residual_pair : bool
        Complete a model one mode short with a residual pair, or one r + 1 modes short with
        a pair and r rigid-body modes when ``rigid_body`` too (default); False to fit no pair.
    rigid_body : bool
        Complete a model r modes short with r rigid-body modes where the residual shows a
        mass line, or with r - 1 and a pair when ``residual_pair`` too (default); False to
        refuse it.

    Returns
    -------
    SSIDResult with ``solver`` set to ``"bands"``; ``info["bands"]`` holds the band width,
    how many modes the bands selected, the kept frequencies, the residual pair's frequency
    (``residual_pair_hz``, None without one; the pair is then the last mode, and a warning
    says so) and the number of rigid-body modes (``n_rigid_body_modes``, also the result's;
    a warning says so; they are not among the listed modes, as in :func:`ssid.identify.identify_mck`),
    ``band_result`` is ``res``.

    Raises
    ------
    IdentificationError
        With reactions in the data (step 1 is not determined in a narrow band with reactions,
        docs/algorithm.md known limits), when the bands found fewer independent modes than
        DOFs and neither a residual pair nor rigid-body modes complete them (the message
        gives each one's reason), or when a kept modal mass is not positive.
    """
    if frf.H_reaction is not None:
        raise IdentificationError("the modal (band-processed) model is not available with "
                                  "measured interface reactions")
    f = frf.freq_hz
    n = frf.n_out
    prefer = None
    if prefer_shapes is not None and res.selected:
        if prefer_freq_hz is None or np.shape(prefer_shapes) != (n, len(prefer_freq_hz)):
            raise ValueError("prefer_shapes must be (n_outputs, k) with prefer_freq_hz (k,)")
        roots = root_shapes(res.selected, n)
        pairs = pair_modes_by_mac_and_frequency(modal_assurance(roots, prefer_shapes),
                                                res.freq_hz, prefer_freq_hz, 0.8)
        prefer = [p.test for p in pairs]
    kept = strongest_roots(frf, res, n, prefer=prefer)
    m = len(kept.selected)
    if m == 0:
        raise IdentificationError(f"band processing found no mode: no modal model of {n} DOFs")
    lam = np.array([r.lam for r in kept.selected])
    theta = root_shapes(kept.selected, n)
    w = data_noise_weights(frf)
    pair_hz, n_rigid, share = None, 0, None
    if m == n:
        M, C, K = scale_selected_roots(frf, kept, scale, assembly="normal")[1]
    else:
        done = _complete_found_modes(frf, kept, scale, lam, theta, w, residual_pair, rigid_body)
        M, C, K = done.mck
        n_rigid, share = done.n_rigid, done.mass_line_share
        if done.lam_r is not None:
            lam, theta = np.append(lam, done.lam_r), np.column_stack([theta, done.phi_r])
            pair_hz = float(np.abs(done.lam_r) / (2 * np.pi))
    shapes = unit_max_shapes(theta)
    try:
        wu, phi = real_modes(M, K)
    except np.linalg.LinAlgError as exc:
        raise IdentificationError("a kept mode has a modal mass <= 0: the modal model is not "
                                  "physical") from exc
    wu[np.argsort(np.abs(wu))[:n_rigid]] = 0.0  # zero by construction; rounding leaves +-1e-6 rad/s
    zeta = -lam.real / np.abs(lam)
    checks, warnings = physical_checks(M, C, K, zeta)
    if pair_hz is not None:
        warnings.append(f"{m} modes found in the band; the model's last pair ({pair_hz:.4g} Hz, "
                        f"damping ratio assumed) is fitted to the residual of the modes above "
                        f"the band and stands for them, not for one of them")
    if n_rigid:
        warnings.append(f"{m} modes found in the band and {n_rigid} rigid-body mode(s) (free-free "
                        f"structure) fitted to the mass line of what they leave of the FRFs ("
                        f"{100 * share:.0f} % of it well below the lowest found mode): K is "
                        "singular by design, its null space the rigid-body shapes, and C is zero "
                        "on them")
    checks["frf_relative_rms_error"] = model_frf_errors(frf, M, C, K, w)[1]
    return SSIDResult(
        M=M, C=C, K=K, dofs=list(frf.outputs),
        natural_freq_hz=np.abs(lam) / (2 * np.pi), damping_ratio=zeta,
        mpc=modal_phase_collinearity(shapes), mode_shapes=shapes,
        undamped_freq_hz=wu / (2 * np.pi), real_mode_shapes=phi,
        real_roots=np.zeros(0), solver="bands", damping="modal",
        band_hz=(float(f[0]), float(f[-1])), checks=checks, warnings=warnings,
        n_rigid_body_modes=n_rigid,
        info={"bands": {"band_width_hz": band_width_hz, "n_selected": len(res.selected),
                        "kept_freq_hz": [float(v) for v in kept.freq_hz],
                        "residual_pair_hz": pair_hz, "n_rigid_body_modes": n_rigid}},
        band_result=res,
    )


def modal_model_misfit_warning(frf: FRFData, model: SSIDResult) -> str | None:
    """A warning when a band-processed model (:func:`modal_model_from_bands` on ``frf``) misses
    the data it came from by as much as ``ssidlab identify`` and ``pseudo-dof`` warn of
    (:func:`ssid.fit_checks.misfits`: 5 % and three times the data's noise), for
    ``ssidlab bands --out``: each of its modes was found in two bands, yet together they may
    not make up the measured FRFs (modes found but left out for want of DOFs, modes outside
    the band, scale factors that miss). On six Z sensors of the payload's free sweep (9 modes
    found, 6 kept, BP1) the written model missed its data by 80 % with nothing said. Not
    added to the model's own warnings: ``identify --select-band`` chooses this model for a
    reduced order, where missing the modes it cannot hold is the point, and states its FRF
    error there. Worded here: identify's advice (check the modes with ``ssidlab bands``) is
    this command.
    """
    err = float(model.checks["frf_relative_rms_error"])
    noise = relative_noise_level(frf)  # the weights model_frf_errors used (data_noise_weights)
    if not misfits(err, noise):
        return None
    n, n_found = model.M.shape[0], len(model.band_result.selected)
    left = (f"it holds {n} of the {n_found} modes found, and the others are in the data too"
            if n_found > n else "modes outside the band, or scale factors that miss")
    return (f"the written M, C, K reproduce the measured FRFs only to {100 * err:.3g} % (relative "
            f"RMS; the data's noise is about {100 * noise:.2g} %): each of its modes was found in "
            f"two bands, but together they miss the data ({left}); trust the modes, not the "
            "matrices' FRFs, or try another --scale or --targets")


@dataclass
class _Completion:
    """The found modes completed to n: by a residual pair above the band, by rigid-body
    modes below it or by both, and the weighted output error of the M, C, K that gives."""

    cost: float
    mck: tuple[np.ndarray, np.ndarray, np.ndarray]
    lam_r: complex | None = None  # the residual pair's root
    phi_r: np.ndarray | None = None  # its shape (n,), unit modal mass
    n_rigid: int = 0
    mass_line_share: float | None = None


def _complete_found_modes(frf: FRFData, kept: BandResult, scale: str, lam: np.ndarray,
                          theta: np.ndarray, w: np.ndarray, residual_pair: bool,
                          rigid_body: bool) -> _Completion:
    """The m < n kept roots (``lam`` (m,), displacement shapes ``theta`` (n, m)) as real
    normal modes, completed to n modes from what they leave of the FRFs (noise weights
    ``w``): with one residual pair above the band (m = n - 1, ``residual_pair``), with
    n - m rigid-body modes fitted to its mass line (``rigid_body``), or with n - m - 1
    rigid-body modes and a pair fitted together (both), whichever predicts the data best;
    IdentificationError with each way's reason when none fits."""
    n, m = frf.n_out, lam.size
    short = n - m
    omega = 2 * np.pi * frf.freq_hz
    omega_low = 0.5 * float(np.min(np.abs(lam)))
    reasons: list[str] = []
    try_pair = residual_pair and short == 1
    if residual_pair and short > 1 and not rigid_body:
        reasons.append(f"a residual pair alone completes a model one mode short, not {short}")
    # Said before the scale factors are fitted (BP3 over the whole record): most records
    # that are modes short can be completed in no way.
    rigid_why = rigid_body_fit_refusal(omega, frf.n_in, short, omega_low) if rigid_body else None
    if rigid_why is not None:
        reasons.append(f"no {short} rigid-body mode(s) below the band ({rigid_why})")
    try_rigid = rigid_body and rigid_why is None
    both_why = (rigid_body_fit_refusal(omega, frf.n_in, short - 1, omega_low)
                if rigid_body and residual_pair and short > 1 else None)
    if both_why is not None and both_why != rigid_why:
        reasons.append(f"no {short - 1} rigid-body mode(s) below the band with a pair above it ({both_why})")
    try_both = rigid_body and residual_pair and short > 1 and both_why is None

    def refusal() -> IdentificationError:
        return IdentificationError(f"band processing found {m} modes with independent shapes, {n} "
                                   f"are needed for a modal model of {n} DOFs; "
                                   + "; ".join(reasons or ["completing them was not asked for"]))

    if not (try_pair or try_rigid or try_both):
        raise refusal()
    u = scale_selected_roots(frf, kept, scale, assemble=False)[0]
    phi, inv_m = normal_mode_shapes(lam, theta, u)
    # strongest_roots tests independence only when it has more roots than DOFs to choose from:
    # fewer found ones can be dependent (a symmetry class with more modes than it has
    # dimensions at the sensors).
    if not shapes_independent(phi):
        raise IdentificationError("the found modes' shapes are linearly dependent at the "
                                  "sensors: no modal model of this order")
    resid = np.where(w > 0, frf.H, 0.0) - normal_mode_accelerance(omega, lam, phi, inv_m,
                                                                   frf.input_index())
    # The pair's damping ratio is not in the band's data: the found modes' median.
    zeta = float(np.median(-lam.real / np.abs(lam)))
    tried = []
    if try_pair:
        try:
            lam_r, phi_r = fit_residual_pair(omega, resid, w, frf.input_index(), zeta, found=lam)
            if not shapes_independent(np.column_stack([phi, phi_r])):
                raise IdentificationError("its shape lies in the span of the found modes' at the "
                                          "sensors")
            # The pair's real shape is for unit modal mass: u = -j / (2 omega_d) (Eq. 3.23's
            # scale factor of a real normal mode, normal_mode_mck's convention).
            mck = normal_mode_mck(np.append(lam, lam_r), np.column_stack([theta, phi_r]),
                                  np.append(u, -0.5j / lam_r.imag))[:3]
            tried.append(_Completion(model_output_error(frf, *mck, w), mck, lam_r=lam_r, phi_r=phi_r))
        except IdentificationError as exc:
            reasons.insert(0, f"no residual pair above the band ({exc})")
    if try_rigid:
        try:
            phi_rb, share = fit_rigid_body_modes(omega, resid, w, frf.input_index(), short, omega_low,
                                                found=lam)
            mck = _rigid_body_mck(lam, phi, inv_m, phi_rb)
            tried.append(_Completion(model_output_error(frf, *mck, w), mck, n_rigid=short,
                                     mass_line_share=share))
        except IdentificationError as exc:
            reasons.append(f"no {short} rigid-body mode(s) below the band ({exc})")
    if try_both:
        try:
            phi_rb, share, lam_r, phi_r = fit_rigid_body_modes_and_pair(
                omega, resid, w, frf.input_index(), short - 1, omega_low, zeta, found=lam)
            # phi_r is for unit modal mass: its inverse modal mass is 1.
            mck = _rigid_body_mck(np.append(lam, lam_r), np.column_stack([phi, phi_r]),
                                  np.append(inv_m, 1.0), phi_rb)
            tried.append(_Completion(model_output_error(frf, *mck, w), mck, lam_r=lam_r, phi_r=phi_r,
                                     n_rigid=short - 1, mass_line_share=share))
        except IdentificationError as exc:
            reasons.append(f"no {short - 1} rigid-body mode(s) below the band with a pair above it ({exc})")
    if not tried:
        raise refusal()
    return min(tried, key=lambda c: c.cost)


def _rigid_body_mck(lam: np.ndarray, phi: np.ndarray, inv_m: np.ndarray,
                    phi_rb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """M, C, K of rigid-body shapes ``phi_rb`` (n, r), for unit modal mass, and found real
    modes (roots ``lam``, shapes ``phi`` (n, m), inverse modal masses ``inv_m``), by
    :func:`ssid.real_modes.real_mode_mck` with omega = zeta = 0 on the rigid-body modes."""
    if np.any(inv_m <= 0):
        raise IdentificationError("a kept mode has a modal mass <= 0: the modal model is not physical")
    shapes = np.column_stack([phi_rb, phi])
    if not shapes_independent(shapes):
        raise IdentificationError("the rigid-body shapes lie in the span of the found modes' at "
                                  "the sensors")
    r = phi_rb.shape[1]
    wn = np.concatenate([np.zeros(r), np.abs(lam)])
    zeta = np.concatenate([np.zeros(r), -lam.real / np.abs(lam)])
    return real_mode_mck(shapes, np.concatenate([np.ones(r), inv_m]), wn, zeta)
