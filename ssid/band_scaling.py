"""Band processing, part 2 (report section 5.2): modal scale factors and M, C, K.

The roots that :func:`ssid.bands.process_bands` selected (one per physical mode) get their
modal scale factors ``1/a~_r`` from Eq. 3.23 in one of three ways: BP1 (all lines of the band
the root was taken from), BP2 (the lines near the root's resonance only) or BP3 (the lines
near all selected resonances, all roots at once), each with residual terms for the modes in
the data but not in the fit (:func:`fit_scale_factors`), dropped in a run of lines too short
to tell them from the modes' own skirts. With as many kept modes as measured DOFs, and their
shapes linearly independent at the sensors (:func:`strongest_roots`), M, C, K follow from
Eq. 3.26: through the state-space inverse as in step 2, or with the modes taken as real
normal modes (:func:`ssid.real_modes.normal_mode_mck`), which stays positive definite on noisy
broad-band data where the state-space inverse does not.

Root selection (criteria 1-4) is in :mod:`ssid.bands`, which re-exports this module's public
names.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from .errors import IdentificationError
from .frf import FRFData
from .real_modes import normal_mode_mck, shapes_independent
from .step1 import Step1Data, step1_data
from .step2 import StateSpaceModes, assemble_mck

if TYPE_CHECKING:  # only for annotations: ssid.bands imports this module
    from .bands import BandResult, BandRoot

__all__ = [
    "fit_scale_factors",
    "frf_share",
    "residual_runs",
    "root_shapes",
    "scale_selected_roots",
    "strongest_roots",
]


def root_shapes(roots: list[BandRoot], n: int | None = None) -> np.ndarray:
    """The roots' state-space eigenvectors as columns, (2n, k); with ``n``, their
    displacement partition (the mode shapes at the n outputs), (n, k)."""
    theta = np.column_stack([r.theta for r in roots])
    return theta if n is None else theta[:n]


def strongest_roots(frf: FRFData, result: BandResult, n_keep: int, *,
                    prefer: list[int] | None = None, min_independence: float = 1e-2) -> BandResult:
    """Keep ``n_keep`` selected roots with linearly independent shapes, strongest first.

    A narrow band finds every mode its lines hold, local ones included, so band processing can
    select more modes than there are sensors; the state-space basis of step 2 holds exactly
    one pair per DOF, and the mode matrix ``Theta`` of Eq. 3.26 must be invertible: ``M^-1 =
    Theta_x diag(u lambda) Theta_x^T`` (the (x, x') partition of ``A_s^-1``, Eq. 3.26) is
    singular when the kept shapes are linearly dependent at the sensors, whatever the scale
    factors. This is not rare: on a structure with a symmetry plane, symmetric modes span only
    the symmetric subspace of the sensors, and keeping more symmetric modes than its dimension
    gives a singular M (the payload of chapter 6 has this).

    The roots are taken greedily: first those in ``prefer`` (indices into
    ``result.selected``, e.g. the roots an analyst paired with target modes, as the report
    picked its roots by hand), then the rest by decreasing contribution to the measured FRFs,
    ``|1/a~_r| |theta_r|^2 max_j |theta_r^T d_j| omega_r / zeta_r`` (Eq. 3.17 at resonance, the
    scale factors from a BP3 fit of all selected roots). A root is skipped when the part of its
    displacement shape (n,) outside the span of the shapes already kept is below
    ``min_independence`` of its norm (the sine of its angle to that span).

    Returns
    -------
    BandResult with ``selected`` replaced by the kept roots (ascending frequency); fewer than
    ``n_keep`` when the selected shapes do not span that many dimensions.
    """
    sel = result.selected
    prefer = list(prefer or [])
    if len(sel) <= n_keep and not prefer:
        return result
    u, _ = scale_selected_roots(frf, result, "BP3", assemble=False)
    th = root_shapes(sel, frf.n_out)
    drive = np.abs(th[frf.input_index()]).max(axis=0)
    wn = np.array([2 * np.pi * r.freq_hz for r in sel])
    zeta = np.array([max(r.zeta, 1e-6) for r in sel])
    strength = np.abs(u) * np.sum(np.abs(th) ** 2, axis=0) * drive * wn / zeta
    order = prefer + [i for i in np.argsort(strength)[::-1] if i not in prefer]
    keep: list[int] = []
    Q = np.zeros((th.shape[0], 0), dtype=complex)  # orthonormal basis of the kept shapes
    for i in order:
        t = th[:, i] / np.linalg.norm(th[:, i])
        r = t - Q @ (Q.conj().T @ t)
        nr = np.linalg.norm(r)
        if nr >= min_independence:
            keep.append(int(i))
            Q = np.column_stack([Q, r / nr])
        if len(keep) == n_keep:
            break
    return replace(result, selected=[sel[i] for i in sorted(keep)])


def _modes_of(roots: list[BandRoot]) -> StateSpaceModes:
    lam = np.array([r.lam for r in roots])
    theta = root_shapes(roots)
    return StateSpaceModes(lam=np.concatenate([lam, lam.conj()]),
                           theta=np.hstack([theta, theta.conj()]), n_pairs=len(roots))


def _near_resonance(d: Step1Data, roots: list[BandRoot], half_widths: float) -> np.ndarray:
    """Lines within ``half_widths`` half-power bandwidths (at least 3 lines) of any root."""
    f = d.omega / (2 * np.pi)
    df = np.median(np.diff(f)) if f.size > 1 else 1.0
    keep = np.zeros(f.size, dtype=bool)
    for r in roots:
        bw = max(half_widths * r.zeta * r.freq_hz, 3 * df)
        keep |= np.abs(f - r.freq_hz) <= bw
    return keep


def _subset(d: Step1Data, lines: np.ndarray) -> Step1Data:
    return replace(d, omega=d.omega[lines], H=d.H[lines], Hr=d.Hr[lines],
                   weight=d.weight[lines], weight_r=d.weight_r[lines], col_ok=d.col_ok[lines])


def _segments(omega: np.ndarray) -> np.ndarray:
    """Label (L,) of the contiguous runs of the chosen lines ``omega`` (rad/s, ascending).

    A gap of more than 1.5 median line spacings starts a new run.
    """
    if omega.size < 2:
        return np.zeros(omega.size, dtype=int)
    dw = np.diff(omega)
    return np.concatenate([[0], np.cumsum(dw > 1.5 * np.median(dw))])


def residual_runs(omega: np.ndarray, segment: np.ndarray, lam: np.ndarray) -> dict[int, bool]:
    """Which runs of lines may carry residual terms: those with no unresolved mode in them.

    A root ``lambda_r`` is resolved when its half-power band ``2 zeta_r omega_r`` (Eq. 5.18,
    ``omega_r = |lambda_r|``) is at least the line spacing ``d omega``: then some line falls
    within it and the peak, which no combination of the residual terms ``{1, w^2}`` can
    mimic, is in the data. An unresolved root within a run's span (widened by one line
    spacing each side) leaves only its mass or stiffness line there, which the residual terms
    absorb (see :func:`fit_scale_factors`): that run gets none.

    Parameters
    ----------
    omega : (L,) line frequencies, rad/s, ascending.
    segment : (L,) run label of each line.
    lam : (m,) roots in the model, rad/s.

    Returns
    -------
    {run label: keep residual terms}.
    """
    omega = np.asarray(omega, dtype=float)
    dw = float(np.median(np.diff(omega))) if omega.size > 1 else np.inf
    lam = np.asarray(lam, dtype=complex)
    wn = np.abs(lam)
    unresolved = wn[2 * (-lam.real) < dw]  # 2 zeta wn = -2 Re(lambda)
    keep = {}
    for s in np.unique(segment):
        w = omega[segment == s]
        keep[int(s)] = not np.any((unresolved >= w[0] - dw) & (unresolved <= w[-1] + dw))
    return keep


def _mode_terms(d: Step1Data, k: np.ndarray, lam: np.ndarray,
                th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pair's term of the modal sum (Eqs. 3.17, 3.19, 3.24) at lines ``k`` for a unit
    scale factor, ``R_kr theta_ir q_kjr``, and its conjugate mode's, ``R'_kr conj(theta_ir)
    q'_kjr``: both (len(k), n, n_in, m). A factor ``u_r`` makes the pair's accelerance
    ``u_r a + conj(u_r) c``."""
    w = d.omega[k][:, None]
    R = -(w**2) / (1j * w - lam[None, :])  # Eq. 3.19, (Ls, m)
    Rc = -(w**2) / (1j * w - lam.conj()[None, :])
    m = th.shape[1]
    q = np.broadcast_to(th[d.in_idx][None], (k.size, d.n_in, m))  # Eq. 3.24, (Ls, n_in, m)
    qc = q.conj()
    if d.n_r:
        q = q + np.einsum("mr,kmj->kjr", th[d.r_idx], d.Hr[k])
        qc = qc + np.einsum("mr,kmj->kjr", th[d.r_idx].conj(), d.Hr[k])
    a = R[:, None, None, :] * th[None, :, None, :] * q[:, None, :, :]
    c = Rc[:, None, None, :] * th.conj()[None, :, None, :] * qc[:, None, :, :]
    return a, c


def frf_share(d: Step1Data, roots: list[BandRoot]) -> np.ndarray:
    """Each root's largest share of its band's FRFs: ``max_k ||H_r(w_k)|| / ||H(w_k)||``
    (Frobenius norm over outputs and inputs), ``H_r`` its term of the modal sum with the
    scale factors of Eq. 3.23 fitted on the band with all ``roots`` (:func:`fit_scale_factors`,
    residual terms included). A mode near its resonance holds most of the response (0.96-1.0
    for the payload's modes at 10 sensors); a root fitted to noise beside it, a few thousandths
    to a few hundredths.

    Parameters
    ----------
    d : Step1Data of the band (its lines and weights).
    roots : the band's roots.

    Returns
    -------
    (len(roots),) shares.
    """
    lam = np.array([r.lam for r in roots])
    th = root_shapes(roots, d.n)  # (n, m)
    u = fit_scale_factors(d, lam, th, residuals=True)
    a, c = _mode_terms(d, np.arange(d.omega.size), lam, th)
    h_r = np.linalg.norm(a * u + c * u.conj(), axis=(1, 2))  # (L, m)
    h = np.maximum(np.linalg.norm(d.H, axis=(1, 2)), 1e-300)[:, None]
    return np.max(h_r / h, axis=0)


def fit_scale_factors(d: Step1Data, lam: np.ndarray, theta_x: np.ndarray,
                      segment: np.ndarray | None = None,
                      residuals: bool | str = True, local: bool = False) -> np.ndarray:
    """Weighted least-squares ``1/a~_r`` of Eq. 3.23 for some complex pairs, with residuals.

    Model of each accelerance value (line k, output i, input j), Eqs. 3.17, 3.19, 3.24::

        H_kij = sum_r [u_r R_kr theta_ir q_kjr + conj(u_r) R'_kr conj(theta_ir) q'_kjr]
                + E0_sij + E2_sij g(w_k)

    ``R_kr = -w_k^2 / (j w_k - lambda_r)``, ``R'`` the same with ``conj(lambda_r)``,
    ``q_kjr = theta_r^T (D_f e_j + D_r h_r,kj)`` (``q'`` with ``conj(theta_r)``). Each pair has
    one complex factor (its real and imaginary parts are the unknowns), so the conjugate mode
    gets the conjugate factor and A_s is real.

    The residual terms stand for the modes that are in the data but not in ``lam``: a mode far
    below the lines adds its mass line (a constant accelerance), one far above its static
    compliance times ``-w^2``; both are real for light damping, so ``E0, E2`` are real, one pair
    per FRF (i, j) and per run ``s`` of contiguous lines (``segment``), because a mode just
    outside a run is neither far below nor far above all the other runs. ``g`` is ``w^2``
    centred and scaled on the run (same span as ``{1, w^2}``, better conditioned). Without
    them the fit forces the tails of the missing modes onto the modes it has: on the 52-DOF
    payload seen by 16 sensors over 1-2300 Hz, 22 modes in the data and 16 in the model,
    scale factors were off by up to 20 % (BP2) and 70 % (BP3), and 0.4 % of that reached the
    frequencies of M, K; with the residuals 0.3 % and 0.004 %.

    The residual terms need the modes of their run to have a signature of their own: a mode
    whose half-power band ``2 zeta f`` is narrower than the line spacing ``df`` (unresolved:
    its peak falls between two lines) adds, at every line of its run but the two that
    bracket it, its mass line ``1/m_r`` (lines above it) or stiffness line ``-w^2/k_r`` (lines
    below) times its shape: exactly what ``E0, E2``, free per FRF, fit, so its modal mass is
    left to the one or two lines that bracket it. With ``residuals="auto"`` a run keeps its
    residual terms only when no unresolved mode lies within its span (widened by ``df``):
    an unresolved mode (half-power band below one line spacing) is, by that definition,
    not separable from them there. On the payload (1-2300 Hz, df = 2.25 Hz) this drops them
    in the run of six lines around the 1.29, 2.83 and 6.21 Hz suspension modes only.

    The residual unknowns are eliminated per (s, i, j) by projecting onto the orthogonal
    complement of their weighted basis, so the normal matrix is only (2m, 2m).

    Parameters
    ----------
    d : Step1Data of the lines to fit (weights ``1/sigma`` used as given).
    lam : (m,) complex roots with Im > 0, rad/s.
    theta_x : (n, m) complex displacement partitions of their eigenvectors.
    segment : (L,) int run label of each line (default: :func:`_segments` of ``d.omega``).
    residuals : True: residual terms in every run; False: none (Eq. 3.23 as written);
        "auto": in the runs whose modes are all resolved (:func:`residual_runs`).
    local : each mode's scale factor gets equations only from the runs that hold its
        resonance (within one line spacing of their first and last lines) and from runs
        without residual terms; every run's model still holds all modes, so the normal
        equations become ``sum_s A_loc,s^T A_s v = sum_s A_loc,s^T h_s`` (``A_loc,s``: ``A_s``
        with the columns of the modes resonant outside run s zeroed), exact on noise-free
        data. Why: far above its resonance a mode's tail is its mass line (which the residual
        terms take) plus ``j w 2 Re(u_r theta_r theta_r^T)``, its part of ``X = Theta_x
        diag(u) Theta_x^T`` (Eq. 3.26), zero for a normal mode, set by the slight complexity
        of noisy shapes and growing with ``w``. Over a record of three decades the hundreds of
        lines far above a 1 Hz mode then fix its scale factor through that term instead of
        its resonance: on the payload with the report's noise the modal masses of the
        1.29-6.21 Hz modes came out 40-300 times off, some negative; with ``local`` within
        3 % of their BP2 values (seeds 1, 2).

    Returns
    -------
    u : (m,) complex ``1/a~_r`` for the given normalisation of ``theta_x``.
    """
    lam = np.asarray(lam, dtype=complex)
    th = np.asarray(theta_x, dtype=complex)
    m = th.shape[1]
    if segment is None:
        segment = _segments(d.omega)
    if residuals == "auto":
        with_res = residual_runs(d.omega, segment, lam)
    elif residuals in (True, False):
        with_res = {int(s): bool(residuals) for s in np.unique(segment)}
    else:
        raise ValueError(f"residuals must be True, False or 'auto', not {residuals!r}")
    wr = np.abs(lam)  # rad/s
    dw = float(np.median(np.diff(d.omega))) if d.omega.size > 1 else np.inf
    N = np.zeros((2 * m, 2 * m))
    b = np.zeros(2 * m)
    for s in np.unique(segment):
        k = np.flatnonzero(segment == s)
        a, c = _mode_terms(d, k, lam, th)
        A = np.concatenate([a + c, 1j * (a - c)], axis=-1)  # real unknowns [Re u, Im u]
        sw = d.weight[k]  # (Ls, n, n_in)
        A = A * sw[..., None]
        h = d.H[k] * sw
        # Real form, one block per FRF (i, j): rows [Re at the Ls lines; Im at the Ls lines].
        Ar = np.concatenate([A.real, A.imag], axis=0).transpose(1, 2, 0, 3)  # (n, n_in, 2Ls, 2m)
        hr = np.concatenate([h.real, h.imag], axis=0).transpose(1, 2, 0)  # (n, n_in, 2Ls)
        if with_res[int(s)]:
            w2 = d.omega[k] ** 2
            g = (w2 - w2.mean()) / max(np.ptp(w2), 1e-12 * w2.mean())
            G = np.zeros((2 * k.size, 2))
            G[: k.size, 0] = 1.0
            G[: k.size, 1] = g
            Gw = G[None, None] * np.concatenate([sw, sw], axis=0).transpose(1, 2, 0)[..., None]
            U, sv, _ = np.linalg.svd(Gw, full_matrices=False)  # (n, n_in, 2Ls, 2)
            U = U * (sv > 1e-10 * np.maximum(sv[..., :1], 1e-300))[..., None, :]
            Ar = Ar - U @ (np.swapaxes(U, -1, -2) @ Ar)
            hr = hr - (U @ (np.swapaxes(U, -1, -2) @ hr[..., None]))[..., 0]
        Ar = Ar.reshape(-1, 2 * m)
        At = Ar  # test functions: the columns whose equations are kept
        if local and with_res[int(s)]:
            # The modes resonant outside this run (beyond one line spacing) stay in its model
            # but get no equations from it: their scale factors come from their own runs.
            far = (wr < d.omega[k[0]] - dw) | (wr > d.omega[k[-1]] + dw)
            At = Ar * ~np.concatenate([far, far])
        N += At.T @ Ar
        b += At.T @ hr.reshape(-1)
    scale = np.sqrt(np.abs(np.diag(N)))
    if np.any(scale == 0):
        raise IdentificationError(
            "a mode has no valid data to fix its scale (Eq. 3.23): no line of the fit holds its "
            "resonance (the lines near it are missing, blanked or carry no weight)")
    v = np.linalg.lstsq(N / scale[:, None] / scale[None, :], b / scale, rcond=None)[0] / scale
    return v[:m] + 1j * v[m:]


def scale_selected_roots(
    frf: FRFData,
    result: BandResult,
    method: str = "BP3",
    half_widths: float = 3.0,
    *,
    residuals: bool | str = "auto",
    assembly: str = "state-space",
    assemble: bool = True,
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray] | None]:
    """Modal scale factors of the selected roots by BP1, BP2 or BP3, and M, C, K if possible.

    Parameters
    ----------
    frf : the full FRF data (BP3 uses lines from all bands).
    result : from :func:`process_bands` (``selected`` possibly reduced by
        :func:`strongest_roots`).
    method : section 5.2. "BP1": Eq. 3.23 on all lines of the band the root was taken from,
        with all that band's oscillatory roots in the model (the band's own state-space model,
        so that its other modes are not forced into this one). "BP2": as BP1 on the lines
        within ``half_widths`` half-power bandwidths (at least 3 lines) of the root. "BP3": one
        fit of all roots that passed the four criteria (every physical mode found, not only
        the kept ones: the others are in the data too) over the lines near any of their
        resonances in the whole record.
    half_widths : BP2/BP3 line window, in half-power bandwidths ``zeta f``.
    residuals : residual terms in Eq. 3.23 (see :func:`fit_scale_factors`), per band (BP1),
        window (BP2) or run of contiguous lines (BP3): True, False or "auto" (only where no
        unresolved selected mode lies, :func:`residual_runs`).
    assembly : "state-space": Eq. 3.26 through :func:`ssid.step2.assemble_mck` (the report's);
        "normal": :func:`ssid.real_modes.normal_mode_mck` (real normal modes, modal damping).
    assemble : False to return the scale factors only.

    Returns
    -------
    (u, mck): ``u`` (m,) complex scale factors ``1/a~_r`` of ``result.selected`` (for their
    ``theta`` normalisation) and ``mck`` = (M, C, K) when the number of selected modes equals
    the number of measured DOFs (the state-space basis is then complete), else None.

    Raises
    ------
    IdentificationError
        When the selected shapes are linearly dependent (the mode matrix of Eq. 3.26 is
        singular: no M exists; choose the roots with :func:`strongest_roots`).
    """
    sel = result.selected
    if not sel:
        raise IdentificationError("band processing selected no roots")
    n = frf.n_out
    if method == "BP3":
        # Global: one fit over the lines near all physical roots of the whole record, with the
        # noise weights the bands estimated.
        model = list(sel) + [r for r in result.representatives()
                             if not any(r is s for s in sel)]
        d_all = step1_data(frf, _weights_on_grid(frf, result))
        d = _subset(d_all, _near_resonance(d_all, model, half_widths))
        # local: each root is fitted on the runs that hold its resonance only (see
        # fit_scale_factors); far runs otherwise set the suspension modes' masses.
        u = fit_scale_factors(d, np.array([r.lam for r in model]),
                              root_shapes(model, n),
                              residuals=residuals, local=True)[: len(sel)]
    elif method in ("BP1", "BP2"):
        u = np.empty(len(sel), dtype=complex)
        for i, r in enumerate(sel):
            d = result.data[r.band]
            companions = [r] + [c for c in result.roots if c.band == r.band and c is not r]
            if method == "BP2":
                d = _subset(d, _near_resonance(d, [r], half_widths))
            # One run of lines (the band, or the window): one residual pair per FRF.
            one_run = np.zeros(d.omega.size, dtype=int)
            use_res = residuals
            if residuals == "auto":
                # Only roots that passed the criteria count: the band's computational roots
                # (often nearly undamped) model noise, not a mode the residuals could absorb.
                use_res = residual_runs(d.omega, one_run,
                                        [c.lam for c in companions if not c.rejected])[0]
            u[i] = fit_scale_factors(d, np.array([c.lam for c in companions]),
                                     root_shapes(companions, n),
                                     one_run, use_res)[0]
    else:
        raise ValueError(f"unknown scale-factor method {method!r}; use BP1, BP2 or BP3")
    if not assemble or len(sel) != n:
        return u, None
    theta = root_shapes(sel)
    if not shapes_independent(theta[:n]):
        raise IdentificationError(
            "the selected roots' shapes are linearly dependent at the sensors (Eq. 3.26 has no "
            "inverse, M^-1 is singular); select independent roots (strongest_roots)")
    lam = np.array([r.lam for r in sel])
    if assembly == "state-space":
        M, C, K, _ = assemble_mck(_modes_of(sel), np.concatenate([u, u.conj()]))
    elif assembly == "normal":
        M, C, K, _ = normal_mode_mck(lam, theta[:n], u)
    else:
        raise ValueError(f"unknown assembly {assembly!r}; use 'state-space' or 'normal'")
    return u, (M, C, K)


def _weights_on_grid(frf: FRFData, result: BandResult) -> np.ndarray:
    """Noise weights for the full record assembled from the bands' own estimates."""
    w = np.zeros(frf.H.shape)
    f = frf.freq_hz
    for (lo, hi), d in zip(result.bands_hz, result.data):
        if d is None:
            continue
        sel = (f >= lo) & (f <= hi)
        w[sel] = np.where(w[sel] > 0, np.minimum(w[sel], d.weight), d.weight)
    w[w == 0] = np.median(w[w > 0]) if np.any(w > 0) else 1.0
    return w * frf.valid_mask()
