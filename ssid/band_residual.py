"""One pair above the band for a modal model one mode short (beyond the report).

An n-DOF modal model needs n modes (:func:`ssid.band_select.modal_model_from_bands`). When
band processing finds n - 1 in the measured band, the modes above the band are in the data
too, as what the found modes leave of the FRFs: their resonances' lower skirts. The nearest
of them, when its skirt reaches into the band, sets the shape of that residual; the others
add nearly frequency-independent residual flexibility. :func:`fit_residual_pair` fits one
real normal mode above the band to that residual, so that the model keeps every found mode
exactly and spends its last pair where the data point.

What such a pair is: a mode of the *model*, fitted to the residual of all modes above the
band. When one mode dominates that residual (the next one lies near the edge) it lands near
that mode; otherwise it is an effective pole, and its frequency and shape are a compromise.
Its damping ratio is not in the band's data at all (its resonance is outside); it is set to
the median of the found modes'. A structural-dynamics analogue is a residual-flexibility
("residual mode") term made into a mode so that the model stays second order.

Below the band, a free-free structure's rigid-body modes are in the data the same way: a
rigid-body mode adds ``phi phi_in^T`` to the accelerance at every line (its pole at 0:
``-w^2 / (0 - w^2) = 1``), the mass line the low-frequency accelerance of a free structure
tends to. :func:`fit_rigid_body_modes` fits rigid-body shapes to that mass line.

Why by hand: the pair's fit is a one-parameter search (the pole) around a closed-form linear
least-squares solve (the residues), variable projection reduced to its simplest case; no
library fits one real normal mode to a matrix residual with a real residue constraint. The
mass line's is a two-term weighted linear fit per value pair, solved for all pairs at once
through their 2 x 2 normal equations (one ``lstsq`` per pair would loop in Python).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from .errors import IdentificationError

__all__ = ["MASS_LINE_SHARE_MIN", "fit_residual_pair", "fit_rigid_body_modes", "normal_mode_accelerance",
           "rigid_body_fit_refusal"]

#: Least share of the weighted power the found modes leave of the FRFs, on the lines well
#: below the lowest found mode, that a mass line must explain to be taken for rigid-body
#: modes: there a free structure's accelerance is its mass line, while a grounded one's falls
#: as w^2 (what remains of it after the found modes is residual flexibility and noise).
MASS_LINE_SHARE_MIN = 0.75


def normal_mode_accelerance(omega: np.ndarray, lam: np.ndarray, phi: np.ndarray,
                            inv_m: np.ndarray, input_index: np.ndarray) -> np.ndarray:
    """Accelerance (L, n, n_in) of real normal modes with modal damping.

    ``H_ij(w) = -w^2 sum_r phi_ir phi_jr / (m_r (w_r^2 - w^2 + 2 j zeta_r w_r w))`` with
    ``w_r = |lam_r|``, ``zeta_r = -Re lam_r / |lam_r|`` (Eq. 5.18), j the inputs' DOFs.

    Parameters
    ----------
    omega : (L,) rad/s.
    lam : (m,) roots (Im > 0), rad/s.
    phi : (n, m) real shapes at the outputs.
    inv_m : (m,) inverse modal masses of ``phi``.
    input_index : (n_in,) index of each input's DOF among the outputs.
    """
    wn = np.abs(lam)
    zeta = -lam.real / wn
    den = wn[None] ** 2 - omega[:, None] ** 2 + 2j * zeta[None] * wn[None] * omega[:, None]
    return -omega[:, None, None] ** 2 * np.einsum(
        "r,ir,jr,kr->kij", inv_m, phi, phi[input_index], 1.0 / den)


def fit_residual_pair(
    omega: np.ndarray,
    residual: np.ndarray,
    weight: np.ndarray,
    input_index: np.ndarray,
    zeta: float,
    max_ratio: float = 10.0,
) -> tuple[complex, np.ndarray]:
    """One real normal mode above the band fitted to a residual accelerance.

    Minimises ``sum_kij w_kij^2 |R_kij - b_k(w_r) A_ij|^2`` with
    ``b_k = -w_k^2 / (w_r^2 - w_k^2 + 2 j zeta w_r w_k)``: for a given pole ``w_r`` each real
    residue ``A_ij`` is a weighted linear least-squares solve in closed form, so only
    ``w_r`` is searched (a grid, then a bounded scalar search around its best point), between
    the band's upper edge and ``max_ratio`` times it. A mode's residue is ``A = phi phi_in^T``
    (unit modal mass): ``phi_in`` is the leading eigenvector of the symmetric part of ``A``'s
    input rows (scaled by the square root of its eigenvalue), and ``phi = A phi_in / |phi_in|^2``.

    Parameters
    ----------
    omega : (L,) measured lines, rad/s, ascending.
    residual : (L, n, n_in) what the found modes leave of the accelerances.
    weight : (L, n, n_in) noise weights ``1/sigma`` (0 for blanked values).
    input_index : (n_in,) index of each input's DOF among the outputs.
    zeta : damping ratio given to the pair (not determined by the band's lines).
    max_ratio : the pole is searched up to this many times the band's upper edge.

    Returns
    -------
    (lam, phi): the root ``w_r (-zeta + j sqrt(1 - zeta^2))`` and the shape (n,) at the
    outputs for unit modal mass.

    Raises
    ------
    IdentificationError
        When the best pole is at either end of the search (the residual shows no resonance
        skirt: a pole there is not determined), or the residue's input rows have no positive
        part (the residual is not a mode's: a mode above the band adds positive flexibility
        at its driving points).
    """
    w2 = weight**2
    R = np.where(w2 > 0, residual, 0.0)  # a blanked value (NaN) has weight 0: it must not poison the sums
    wmax = float(omega[-1])

    def solve(log_wr: float) -> tuple[float, np.ndarray]:
        wr = np.exp(log_wr)
        b = -omega**2 / (wr**2 - omega**2 + 2j * zeta * wr * omega)  # (L,)
        num = np.einsum("k,kij->ij", b.conj(), w2 * R).real
        den = np.einsum("k,kij->ij", np.abs(b) ** 2, w2)
        A = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
        # sum w^2 |R - b A|^2 = sum w^2 |R|^2 - sum_ij A_ij num_ij at the solve's A
        return float(np.sum(w2 * np.abs(R) ** 2) - np.sum(A * num)), A

    lo, hi = np.log(wmax), np.log(max_ratio * wmax)
    grid = np.linspace(lo, hi, 200)
    costs = [solve(x)[0] for x in grid]
    i = int(np.argmin(costs))
    if i == 0 or i == grid.size - 1:
        raise IdentificationError(
            f"the residual above the band shows no resonance between {wmax / (2 * np.pi):.4g} and "
            f"{max_ratio * wmax / (2 * np.pi):.4g} Hz: no pair can be fitted to it")
    best = minimize_scalar(lambda x: solve(x)[0], bounds=(grid[i - 1], grid[i + 1]), method="bounded",
                           options={"xatol": 1e-7})
    wr = float(np.exp(best.x))
    A = solve(best.x)[1]
    S = A[input_index]
    ev, V = np.linalg.eigh((S + S.T) / 2)
    if ev[-1] <= 0:
        raise IdentificationError("the residual above the band has no positive driving-point "
                                  "flexibility: it is not a mode's, no pair can be fitted to it")
    phi_in = V[:, -1] * np.sqrt(ev[-1])
    phi = A @ phi_in / (phi_in @ phi_in)
    return complex(wr * (-zeta + 1j * np.sqrt(1.0 - zeta**2))), phi


def rigid_body_fit_refusal(omega: np.ndarray, n_in: int, n_rigid: int, omega_low: float) -> str | None:
    """Why :func:`fit_rigid_body_modes` cannot run on these lines and inputs, before any fit
    (None if it can): more rigid-body modes than inputs, or no line below ``omega_low``."""
    if n_rigid > n_in:
        return f"{n_rigid} rigid-body modes need at least as many inputs; the data have {n_in}"
    if not np.any(omega < omega_low):
        return "no line lies well below the lowest mode found: a mass line cannot be told from that mode's skirt"
    return None


def fit_rigid_body_modes(
    omega: np.ndarray,
    residual: np.ndarray,
    weight: np.ndarray,
    input_index: np.ndarray,
    n_rigid: int,
    omega_low: float,
) -> tuple[np.ndarray, float]:
    """Rigid-body mode shapes fitted to the mass line of a residual accelerance.

    Fits ``R_kij = A_ij - (w_k / w_L)^2 F_ij`` by weighted linear least squares, each value
    pair ``(i, j)`` in closed form: ``A`` the mass line, the sum of the rigid-body modes'
    ``phi phi_in^T`` (unit modal mass), and ``F`` the residual flexibility of modes above the
    band, fitted so that it does not bias ``A`` and then dropped (``w_L`` the highest line,
    for scaling only). ``A``'s input rows are ``Phi_in Phi_in^T``: ``Phi_in`` (n_in, r) from
    the ``n_rigid`` leading eigenpairs of their symmetric part, and ``Phi = A Phi_in
    (Phi_in^T Phi_in)^-1`` (n, r), the shapes up to a rotation among themselves (any basis
    of the rigid-body motions is one).

    Parameters
    ----------
    omega : (L,) measured lines, rad/s, ascending.
    residual : (L, n, n_in) what the found modes leave of the accelerances.
    weight : (L, n, n_in) noise weights ``1/sigma`` (0 for blanked values).
    input_index : (n_in,) index of each input's DOF among the outputs.
    n_rigid : number of rigid-body modes, at most the number of inputs.
    omega_low : rad/s; the lines below it (well below the lowest found mode) judge whether
        the mass line is what the residual holds there.

    Returns
    -------
    (Phi, share): the shapes (n, n_rigid) for unit modal mass, and the share of the residual's
    weighted power below ``omega_low`` that the mass line ``A`` alone explains.

    Raises
    ------
    IdentificationError
        With more rigid-body modes than inputs (their shapes are not determined), no line
        below ``omega_low``, a share below :data:`MASS_LINE_SHARE_MIN` (the residual is not a
        free structure's mass line), or fewer than ``n_rigid`` positive driving-point masses
        in it.
    """
    why = rigid_body_fit_refusal(omega, len(input_index), n_rigid, omega_low)
    if why is not None:
        raise IdentificationError(why)
    low = omega < omega_low
    w2 = weight**2
    R = np.where(w2 > 0, residual, 0.0).real  # basis and coefficients are real: Re R is what fits
    g = -(omega / omega[-1]) ** 2  # (L,)
    G = np.stack([np.stack([np.einsum("kij->ij", w2), np.einsum("k,kij->ij", g, w2)], -1),
                  np.stack([np.einsum("k,kij->ij", g, w2), np.einsum("k,kij->ij", g**2, w2)], -1)], -2)
    b = np.stack([np.einsum("kij->ij", w2 * R), np.einsum("k,kij->ij", g, w2 * R)], -1)
    ok = np.linalg.det(G) > 0
    coef = np.zeros(b.shape)
    coef[ok] = np.linalg.solve(G[ok], b[ok][..., None])[..., 0]
    A = coef[..., 0]
    # The mass line alone, not with F: a grounded structure's residual there is F's w^2 term.
    full = np.where(w2 > 0, residual, 0.0)
    power = float(np.sum(w2[low] * np.abs(full[low]) ** 2))
    left = float(np.sum(w2[low] * np.abs(full[low] - A[None]) ** 2))
    share = 1.0 - left / power if power > 0 else 0.0
    if share < MASS_LINE_SHARE_MIN:
        raise IdentificationError(
            f"a mass line explains {100 * max(share, 0.0):.0f} % of what the found modes leave of the "
            f"FRFs well below the lowest of them (at least {100 * MASS_LINE_SHARE_MIN:.0f} % wanted): "
            "the data do not show rigid-body modes")
    S = A[input_index]
    ev, V = np.linalg.eigh((S + S.T) / 2)
    ev, V = ev[::-1][:n_rigid], V[:, ::-1][:, :n_rigid]
    if ev[-1] <= 0:
        raise IdentificationError(f"the mass line has {int(np.sum(ev > 0))} positive driving-point "
                                  f"mass(es), {n_rigid} rigid-body modes need as many")
    phi_in = V * np.sqrt(ev)
    return A @ phi_in @ np.linalg.inv(phi_in.T @ phi_in), share
