"""Band processing (report section 5.2): SSID over overlapping narrow bands.

Each band goes through step 1 and the state-space eigenproblem (Eq. 3.12) on its own lines
only, which avoids the ill-conditioning of one broad-band fit. Its roots are then screened by
the report's four criteria:

1. the root's frequency lies outside its band;
2. its damping is negative;
3. its modal phase collinearity is below a threshold (Eq. 5.20);
4. it is not repeated in another band (true roots are found wherever their band overlaps).

The surviving roots, one per physical mode, get their modal scale factors 1/a~_r from
Eq. 3.23 in one of three ways: BP1 (all lines of the band the root was taken from), BP2 (the
lines near the root's resonance only) or BP3 (the lines near all selected resonances, all
roots at once), each with residual terms for the modes in the data but not in the fit
(:func:`fit_scale_factors`). With as many kept modes as measured DOFs, and their shapes
linearly independent at the sensors (:func:`strongest_roots`), M, C, K follow from Eq. 3.26:
through the state-space inverse as in step 2, or with the modes taken as real normal modes
(:func:`normal_mode_mck`), which stays positive definite on noisy broad-band data where the
state-space inverse does not.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .errors import IdentificationError
from .frf import FRFData
from .identify import identify_step1
from .modal import modal_phase_collinearity, root_frequency_damping
from .step1 import Step1Data, step1_data
from .step2 import StateSpaceModes, assemble_mck, state_space_modes

__all__ = [
    "BandResult",
    "BandRoot",
    "fit_scale_factors",
    "normal_mode_mck",
    "overlapping_bands",
    "plot_band_roots",
    "process_bands",
    "scale_selected_roots",
    "strongest_roots",
]


@dataclass
class BandRoot:
    """One oscillatory root of one band's eigenproblem and the verdict of the criteria."""

    band: int
    lam: complex
    theta: np.ndarray  # (2n,) state-space eigenvector [phi; lambda phi]
    freq_hz: float
    zeta: float
    mpc: float
    rejected: str = ""  # "" if kept, else the first criterion that rejected it
    cluster: int = -1  # index of the physical mode it was matched to


@dataclass
class BandResult:
    """Everything band processing found."""

    bands_hz: list[tuple[float, float]]
    roots: list[BandRoot]
    selected: list[BandRoot]
    data: list[Step1Data] = field(default_factory=list)  # per band (weights included)

    @property
    def freq_hz(self) -> np.ndarray:
        return np.array([r.freq_hz for r in self.selected])

    @property
    def zeta(self) -> np.ndarray:
        return np.array([r.zeta for r in self.selected])


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


def process_bands(
    frf: FRFData,
    bands_hz: list[tuple[float, float]],
    *,
    solver: str = "ml",
    mpc_min: float = 0.8,
    repeat_rtol: float = 0.005,
    min_lines: int | None = None,
) -> BandResult:
    """Run step 1 and Eq. 3.12 per band and select the structural roots (criteria 1-4).

    Parameters
    ----------
    frf : FRFData
    bands_hz : list of (lo, hi) in Hz, e.g. from :func:`overlapping_bands`.
    solver : step-1 solver per band (see :func:`ssid.identify.identify_mck`).
    mpc_min : criterion 3 threshold.
    repeat_rtol : criterion 4: two roots from different bands are the same mode when their
        frequencies agree within this fraction (and their damping within a factor 2).
    min_lines : bands with fewer valid lines are skipped (default: enough real equations for
        the step-1 unknowns per DOF).

    Returns
    -------
    BandResult; ``selected`` holds one root per physical mode, ascending in frequency.
    """
    n = frf.n_out
    p = 2 * n + frf.n_in + frf.n_react
    need = min_lines if min_lines is not None else int(np.ceil(p / (2 * frf.n_in))) + 1
    roots: list[BandRoot] = []
    data: list[Step1Data] = []
    for b, (lo, hi) in enumerate(bands_hz):
        sub = frf.band(lo, hi)
        if sub.n_freq < need:
            data.append(None)
            continue
        est, d, _ = identify_step1(sub, solver=solver)
        data.append(d)
        modes = state_space_modes(est.C_hat, est.K_hat)
        m = modes.n_pairs
        wn, zeta = root_frequency_damping(modes.lam[:m])
        mpc = modal_phase_collinearity(modes.theta_x[:, :m])
        for r in range(m):
            f = wn[r] / (2 * np.pi)
            root = BandRoot(b, complex(modes.lam[r]), modes.theta[:, r].copy(), float(f),
                            float(zeta[r]), float(mpc[r]))
            if not lo <= f <= hi:
                root.rejected = "outside band"
            elif zeta[r] < 0:
                root.rejected = "negative damping"
            elif mpc[r] < mpc_min:
                root.rejected = "low MPC"
            roots.append(root)
    _cluster_repeated(roots, repeat_rtol)
    selected = _pick_representatives(roots, bands_hz)
    return BandResult(bands_hz=list(bands_hz), roots=roots, selected=selected, data=data)


def _cluster_repeated(roots: list[BandRoot], rtol: float) -> None:
    """Criterion 4: group surviving roots of different bands that are the same mode."""
    alive = sorted((r for r in roots if not r.rejected), key=lambda r: r.freq_hz)
    clusters: list[list[BandRoot]] = []
    for r in alive:
        for cl in clusters:
            ref = cl[0]
            if (r.band not in {c.band for c in cl}
                    and abs(r.freq_hz - ref.freq_hz) <= rtol * ref.freq_hz
                    and 0.5 <= r.zeta / max(ref.zeta, 1e-12) <= 2.0):
                cl.append(r)
                break
        else:
            clusters.append([r])
    k = 0
    for cl in clusters:
        if len(cl) < 2:
            cl[0].rejected = "not repeated"
            continue
        for r in cl:
            r.cluster = k
        k += 1


def _pick_representatives(roots: list[BandRoot], bands_hz) -> list[BandRoot]:
    """One root per cluster: the one nearest the centre of its band (least edge effect)."""
    best: dict[int, BandRoot] = {}
    for r in roots:
        if r.rejected or r.cluster < 0:
            continue
        lo, hi = bands_hz[r.band]
        dist = abs(r.freq_hz - 0.5 * (lo + hi)) / (hi - lo)
        cur = best.get(r.cluster)
        if cur is None:
            best[r.cluster] = r
        else:
            clo, chi = bands_hz[cur.band]
            if dist < abs(cur.freq_hz - 0.5 * (clo + chi)) / (chi - clo):
                best[r.cluster] = r
    return sorted(best.values(), key=lambda r: r.freq_hz)


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
    th = np.column_stack([r.theta for r in sel])[: frf.n_out]
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
    theta = np.column_stack([r.theta for r in roots])
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


def fit_scale_factors(d: Step1Data, lam: np.ndarray, theta_x: np.ndarray,
                      segment: np.ndarray | None = None, residuals: bool = True) -> np.ndarray:
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

    The residual unknowns are eliminated per (s, i, j) by projecting onto the orthogonal
    complement of their weighted basis, so the normal matrix is only (2m, 2m).

    Parameters
    ----------
    d : Step1Data of the lines to fit (weights ``1/sigma`` used as given).
    lam : (m,) complex roots with Im > 0, rad/s.
    theta_x : (n, m) complex displacement partitions of their eigenvectors.
    segment : (L,) int run label of each line (default: :func:`_segments` of ``d.omega``).
    residuals : add the residual terms (False: Eq. 3.23 as written).

    Returns
    -------
    u : (m,) complex ``1/a~_r`` for the given normalisation of ``theta_x``.
    """
    lam = np.asarray(lam, dtype=complex)
    th = np.asarray(theta_x, dtype=complex)
    m = th.shape[1]
    if segment is None:
        segment = _segments(d.omega)
    N = np.zeros((2 * m, 2 * m))
    b = np.zeros(2 * m)
    for s in np.unique(segment):
        k = np.flatnonzero(segment == s)
        w = d.omega[k][:, None]
        R = -(w**2) / (1j * w - lam[None, :])  # Eq. 3.19, (Ls, m)
        Rc = -(w**2) / (1j * w - lam.conj()[None, :])
        q = np.broadcast_to(th[d.in_idx][None], (k.size, d.n_in, m))  # Eq. 3.24, (Ls, n_in, m)
        qc = q.conj()
        if d.n_r:
            q = q + np.einsum("mr,kmj->kjr", th[d.r_idx], d.Hr[k])
            qc = qc + np.einsum("mr,kmj->kjr", th[d.r_idx].conj(), d.Hr[k])
        a = R[:, None, None, :] * th[None, :, None, :] * q[:, None, :, :]  # (Ls, n, n_in, m)
        c = Rc[:, None, None, :] * th.conj()[None, :, None, :] * qc[:, None, :, :]
        A = np.concatenate([a + c, 1j * (a - c)], axis=-1)  # real unknowns [Re u, Im u]
        sw = d.weight[k]  # (Ls, n, n_in)
        A = A * sw[..., None]
        h = d.H[k] * sw
        # Real form, one block per FRF (i, j): rows [Re at the Ls lines; Im at the Ls lines].
        Ar = np.concatenate([A.real, A.imag], axis=0).transpose(1, 2, 0, 3)  # (n, n_in, 2Ls, 2m)
        hr = np.concatenate([h.real, h.imag], axis=0).transpose(1, 2, 0)  # (n, n_in, 2Ls)
        if residuals:
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
        N += Ar.T @ Ar
        b += Ar.T @ hr.reshape(-1)
    scale = np.sqrt(np.abs(np.diag(N)))
    if np.any(scale == 0):
        raise IdentificationError(
            "a mode has no valid data to fix its scale (Eq. 3.23): widen the band or add lines")
    v = np.linalg.lstsq(N / scale[:, None] / scale[None, :], b / scale, rcond=None)[0] / scale
    return v[:m] + 1j * v[m:]


def normal_mode_mck(lam: np.ndarray, theta_x: np.ndarray,
                    u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """M, C, K (n, n) from n complex pairs taken as real normal modes.

    Eq. 3.26 gives ``A_s^-1 = Theta diag(u) Theta^T``, whose partitions are, with Eq. 3.15,
    ``X = Theta_x diag(u) Theta_x^T = 0``, ``M^-1 = Theta_x diag(u lambda) Theta_x^T`` and
    ``K^-1 = -Theta_x diag(u / lambda) Theta_x^T`` (sums over both members of each pair). M
    taken from the inverse of the whole ``Theta`` (:func:`ssid.step2.assemble_mck`) is
    ``(M^-1 + X K X)^-1``: a residue ``X`` of 1e-5 of ``M^-1`` (slightly complex shapes of noisy
    bands), multiplied by the stiffness of modes three decades above the lowest, makes M
    indefinite. For a lightly damped structure whose modes are normal (what criterion 3, MPC,
    checks), ``theta_r`` is a real shape ``phi_r`` times a phase and
    ``u_r = -j / (2 omega_dr m_r)``; then X = 0 exactly and

        M^-1 = Phi diag(1/m) Phi^T,  K^-1 = Phi diag(1/(m omega^2)) Phi^T,
        C = M Phi diag(2 zeta omega / m) Phi^T M      (modal damping, report section 6.2.3)

    with ``omega_r = |lambda_r|``, ``zeta_r`` of Eq. 5.18. M and K are positive definite when
    every modal mass ``m_r > 0`` and the shapes are independent, and eig(K, M) = omega_r^2
    exactly: the scale factors set the modal masses, not the frequencies.

    Parameters
    ----------
    lam : (n,) complex roots (Im > 0), rad/s.
    theta_x : (n, n) complex displacement shapes, any normalisation.
    u : (n,) complex ``1/a~_r`` for that normalisation (Eq. 3.23).

    Returns
    -------
    (M, C, K, m): m (n,) the modal masses of the real shapes ``phi_r`` (kg for unit-free
    shapes if H is in (m/s^2)/N); M, C, K in the units of Eq. 3.15.
    """
    lam = np.asarray(lam, dtype=complex)
    th = np.asarray(theta_x, dtype=complex)
    # Phase that makes each shape most nearly real: maximises |Re(e^{j a} theta)|^2 =
    # (|theta|^2 + Re(e^{2ja} theta^T theta)) / 2.
    alpha = -0.5 * np.angle(np.sum(th * th, axis=0))
    phi = (th * np.exp(1j * alpha)).real
    u_real = u * np.exp(-2j * alpha)  # u theta theta^T = u_real phi phi^T (to the imag part)
    wn = np.abs(lam)
    zeta = -lam.real / wn
    wd = lam.imag
    inv_m = -2 * wd * u_real.imag  # u_real = -j / (2 omega_d m)
    Minv = (phi * inv_m) @ phi.T
    Kinv = (phi * (inv_m / wn**2)) @ phi.T
    M = np.linalg.inv(Minv)
    K = np.linalg.inv(Kinv)
    MP = M @ phi
    C = (MP * (2 * zeta * wn * inv_m)) @ MP.T
    with np.errstate(divide="ignore"):
        # Symmetric by construction; remove rounding asymmetry only.
        return (M + M.T) / 2, (C + C.T) / 2, (K + K.T) / 2, 1.0 / inv_m


def scale_selected_roots(
    frf: FRFData,
    result: BandResult,
    method: str = "BP3",
    half_widths: float = 3.0,
    *,
    residuals: bool = True,
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
        window (BP2) or run of contiguous lines (BP3).
    assembly : "state-space": Eq. 3.26 through :func:`ssid.step2.assemble_mck` (the report's);
        "normal": :func:`normal_mode_mck` (real normal modes, modal damping).
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
        model = list(sel) + [r for r in _pick_representatives(result.roots, result.bands_hz)
                             if not any(r is s for s in sel)]
        d_all = step1_data(frf, _weights_on_grid(frf, result))
        d = _subset(d_all, _near_resonance(d_all, model, half_widths))
        u = fit_scale_factors(d, np.array([r.lam for r in model]),
                              np.column_stack([r.theta[:n] for r in model]),
                              residuals=residuals)[: len(sel)]
    elif method in ("BP1", "BP2"):
        u = np.empty(len(sel), dtype=complex)
        for i, r in enumerate(sel):
            d = result.data[r.band]
            companions = [r] + [c for c in result.roots if c.band == r.band and c is not r]
            if method == "BP2":
                d = _subset(d, _near_resonance(d, [r], half_widths))
            # One run of lines (the band, or the window): one residual pair per FRF.
            u[i] = fit_scale_factors(d, np.array([c.lam for c in companions]),
                                     np.column_stack([c.theta[:n] for c in companions]),
                                     np.zeros(d.omega.size, dtype=int), residuals)[0]
    else:
        raise ValueError(f"unknown scale-factor method {method!r}; use BP1, BP2 or BP3")
    if not assemble or len(sel) != n:
        return u, None
    theta = np.column_stack([r.theta for r in sel])
    sv = np.linalg.svd(theta[:n] / np.linalg.norm(theta[:n], axis=0), compute_uv=False)
    if sv[-1] < 1e-8 * sv[0]:
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


def plot_band_roots(path: str, result: BandResult, true_freq_hz: np.ndarray | None = None) -> None:
    """Stabilisation-style chart: each band's roots against frequency, marked by verdict."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5))
    for b, (lo, hi) in enumerate(result.bands_hz):
        ax.plot([lo, hi], [b, b], color="0.85", lw=6, solid_capstyle="butt", zorder=0)
    marks = {"": ("o", "tab:green", "kept"), "not repeated": ("x", "tab:orange", "not repeated"),
             "low MPC": ("s", "tab:purple", "low MPC"), "negative damping": ("v", "tab:red", "negative damping"),
             "outside band": (".", "0.6", "outside band")}
    seen = set()
    for r in result.roots:
        mk, col, lab = marks[r.rejected]
        ax.scatter(r.freq_hz, r.band, marker=mk, color=col, s=28,
                   label=None if lab in seen else lab, zorder=2)
        seen.add(lab)
    for r in result.selected:
        ax.axvline(r.freq_hz, color="tab:green", lw=0.6, alpha=0.5, zorder=1)
    if true_freq_hz is not None:
        for f in true_freq_hz:
            ax.axvline(f, color="k", lw=0.5, ls=":", zorder=1)
    lo = min(b[0] for b in result.bands_hz)
    hi = max(b[1] for b in result.bands_hz)
    ax.set_xlim(lo, hi)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("band")
    ax.set_title("roots per band (green: selected; dotted: true modes if known)")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
