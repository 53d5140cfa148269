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

Why by hand: the fit is a one-parameter search (the pole) around a closed-form linear
least-squares solve (the residues), variable projection reduced to its simplest case; no
library fits one real normal mode to a matrix residual with a real residue constraint.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from .errors import IdentificationError

__all__ = ["fit_residual_pair", "normal_mode_accelerance"]


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
