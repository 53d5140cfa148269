"""One pair above the band for a modal model one mode short (beyond the report).

An n-DOF modal model needs n modes (:func:`ssid.modal_model.modal_model_from_bands`). When
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
tends to. :func:`fit_rigid_body_modes` fits rigid-body shapes to that mass line, and
:func:`fit_rigid_body_modes_and_pair` fits both together, rigid-body modes below the band and
a pair above it, for a free structure whose band also stops short of the modes above it.

Why by hand: each fit is a weighted linear least-squares solve of a few terms per value pair
(the mass line, the pair, the found modes) with real coefficients (the residues), solved for
all pairs at once through their small normal equations (one ``lstsq`` per pair would loop
in Python); where a pole is fitted, it is a one-parameter search around that solve,
variable projection reduced to its simplest case. No library fits real normal modes to a
matrix residual with a real residue constraint.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from .errors import IdentificationError

__all__ = ["MASS_LINE_SHARE_MIN", "fit_residual_pair", "fit_rigid_body_modes", "fit_rigid_body_modes_and_pair",
           "normal_mode_accelerance", "rigid_body_fit_refusal"]

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


def _real_residues(R: np.ndarray, w2: np.ndarray, basis: np.ndarray) -> tuple[np.ndarray, float]:
    """Real coefficients ``c_ij`` (n, n_in, q) minimising ``sum_k w2_kij |R_kij - sum_a
    basis_ak c_ija|^2`` for each value pair, and the minimum summed over the pairs.

    ``basis`` (q, L) is complex (a pole's response) or real (a mass line, a w^2 term). The
    coefficients solve each pair's q x q normal equations ``Re(B^H W B) c = Re(B^H W R)``,
    all pairs' Gram matrices in one matrix product over the lines; a pair with singular ones
    (all its values blanked) gets 0. At the solution the weighted residual is
    ``sum w2 |R|^2 - c . rhs``, so the cost needs no second pass over the lines.
    """
    q, L = basis.shape
    shape = R.shape[1:]
    w2f = w2.reshape(L, -1)
    G = ((basis.conj()[:, None] * basis[None]).real.reshape(q * q, L) @ w2f).T.reshape(*shape, q, q)
    rhs = (basis.conj() @ (w2 * R).reshape(L, -1)).real.T.reshape(*shape, q)
    # Pairs whose Gram matrix is singular (all values blanked, or fewer valid lines than
    # terms) keep coefficients 0; judged after unit-diagonal scaling, as the terms' sizes differ.
    d = np.diagonal(G, axis1=-2, axis2=-1)
    ok = np.all(d > 0, axis=-1)
    s = 1.0 / np.sqrt(d[ok])
    Gs = G[ok] * s[..., :, None] * s[..., None, :]
    ok[ok] = np.linalg.cond(Gs) < 1e12
    coef = np.zeros(rhs.shape)
    coef[ok] = np.linalg.solve(G[ok], rhs[ok][..., None])[..., 0]
    return coef, float(np.sum(w2 * np.abs(R) ** 2) - np.sum(coef * rhs))


def _found_mode_responses(omega: np.ndarray, found: np.ndarray | None) -> np.ndarray:
    """Responses (m, L) of the found modes (roots ``found`` (m,), Im > 0) per unit residue, to
    join a completion's fit with free residues; (0, L) without them."""
    if found is None or len(found) == 0:
        return np.zeros((0, omega.size), dtype=complex)
    found = np.asarray(found)
    return np.stack([_pole_response(omega, abs(lam), -lam.real / abs(lam)) for lam in found])


def _pole_response(omega: np.ndarray, wr: float, zeta: float) -> np.ndarray:
    """``b_k = -w_k^2 / (w_r^2 - w_k^2 + 2 j zeta w_r w_k)`` (L,): a real normal mode's
    accelerance per unit residue ``phi phi_in^T`` (unit modal mass)."""
    return -omega**2 / (wr**2 - omega**2 + 2j * zeta * wr * omega)


def _search_pole(cost, wmax: float, max_ratio: float) -> float:
    """The pole ``w_r`` (rad/s) minimising ``cost(log w_r)`` between ``wmax`` and ``max_ratio``
    times it: a grid, then a bounded scalar search around its best point. Raises when the
    best point is at either end (the residual shows no resonance skirt there)."""
    grid = np.linspace(np.log(wmax), np.log(max_ratio * wmax), 200)
    costs = [cost(x) for x in grid]
    i = int(np.argmin(costs))
    if i == 0 or i == grid.size - 1:
        raise IdentificationError(
            f"the residual above the band shows no resonance between {wmax / (2 * np.pi):.4g} and "
            f"{max_ratio * wmax / (2 * np.pi):.4g} Hz: no pair can be fitted to it")
    best = minimize_scalar(cost, bounds=(grid[i - 1], grid[i + 1]), method="bounded", options={"xatol": 1e-7})
    return float(np.exp(best.x))


def _unit_mass_shapes(A: np.ndarray, input_index: np.ndarray, r: int) -> np.ndarray | None:
    """Shapes ``Phi`` (n, r) for unit modal mass of a residue ``A = Phi Phi_in^T`` (n, n_in):
    ``Phi_in`` from the r leading eigenpairs of the symmetric part of ``A``'s input rows,
    ``Phi = A Phi_in (Phi_in^T Phi_in)^-1``; None when fewer than r eigenvalues are positive
    (the residue is not r modes': a mode adds positive terms at its driving points). Positive
    means above rounding, 1e-9 of the largest magnitude: a residue of negative rank 1 has
    its other eigenvalues at +-1e-17 of it."""
    S = A[input_index]
    ev, V = np.linalg.eigh((S + S.T) / 2)
    tol = 1e-9 * float(np.abs(ev).max())
    ev, V = ev[::-1][:r], V[:, ::-1][:, :r]
    if ev[-1] <= tol:
        return None
    phi_in = V * np.sqrt(ev)
    return A @ phi_in @ np.linalg.inv(phi_in.T @ phi_in)


def _mass_line_share(residual: np.ndarray, w2: np.ndarray, A: np.ndarray, low: np.ndarray) -> float:
    """Share of the residual's weighted power on the ``low`` lines that the mass line ``A``
    (n, n_in) alone explains; refused below :data:`MASS_LINE_SHARE_MIN`."""
    full = np.where(w2 > 0, residual, 0.0)
    power = float(np.sum(w2[low] * np.abs(full[low]) ** 2))
    left = float(np.sum(w2[low] * np.abs(full[low] - A[None]) ** 2))
    share = 1.0 - left / power if power > 0 else 0.0
    if share < MASS_LINE_SHARE_MIN:
        raise IdentificationError(
            f"a mass line explains {100 * max(share, 0.0):.0f} % of what the found modes leave of the "
            f"FRFs well below the lowest of them (at least {100 * MASS_LINE_SHARE_MIN:.0f} % wanted): "
            "the data do not show rigid-body modes")
    return share


def fit_residual_pair(
    omega: np.ndarray,
    residual: np.ndarray,
    weight: np.ndarray,
    input_index: np.ndarray,
    zeta: float,
    max_ratio: float = 10.0,
    found: np.ndarray | None = None,
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
    found : (m,) complex, optional
        Roots of the modes the residual was taken from. Their responses join the fit with
        free real residues, so that what their scale factors got wrong (largest at their
        resonances) is not taken into the pair's.

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

    free = _found_mode_responses(omega, found)

    def fit(wr: float) -> tuple[np.ndarray, float]:
        return _real_residues(R, w2, np.vstack([_pole_response(omega, wr, zeta)[None], free]))

    wr = _search_pole(lambda x: fit(np.exp(x))[1], float(omega[-1]), max_ratio)
    return _pair(wr, zeta, fit(wr)[0][..., 0], input_index)


def _pair(wr: float, zeta: float, P: np.ndarray, input_index: np.ndarray) -> tuple[complex, np.ndarray]:
    """The pair's root ``w_r (-zeta + j sqrt(1 - zeta^2))`` and its shape (n,) from its
    residue ``P`` (n, n_in); refused when ``P`` has no positive driving-point part."""
    phi = _unit_mass_shapes(P, input_index, 1)
    if phi is None:
        raise IdentificationError("the residual above the band has no positive driving-point "
                                  "flexibility: it is not a mode's, no pair can be fitted to it")
    return complex(wr * (-zeta + 1j * np.sqrt(1.0 - zeta**2))), phi[:, 0]


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
    found: np.ndarray | None = None,
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
    found : (m,) complex, optional
        As for :func:`fit_residual_pair`.

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
    w2 = weight**2
    R = np.where(w2 > 0, residual, 0.0)  # a blanked value (NaN) has weight 0: it must not poison the sums
    basis = np.vstack([np.ones_like(omega), -(omega / omega[-1]) ** 2, _found_mode_responses(omega, found)])
    A = _real_residues(R, w2, basis)[0][..., 0]
    # The mass line alone, not with F: a grounded structure's residual there is F's w^2 term.
    share = _mass_line_share(residual, w2, A, omega < omega_low)
    return _rigid_body_shapes(A, input_index, n_rigid), share


def _rigid_body_shapes(A: np.ndarray, input_index: np.ndarray, n_rigid: int) -> np.ndarray:
    """Rigid-body shapes (n, n_rigid) for unit modal mass from the mass line ``A`` (n, n_in);
    refused when it has fewer than ``n_rigid`` positive driving-point masses."""
    phi = _unit_mass_shapes(A, input_index, n_rigid)
    if phi is None:
        S = A[input_index]
        ev = np.linalg.eigvalsh((S + S.T) / 2)
        n_pos = int(np.sum(ev > 1e-9 * np.abs(ev).max()))
        raise IdentificationError(f"the mass line has {n_pos} positive driving-point mass(es), "
                                  f"{n_rigid} rigid-body modes need as many")
    return phi


def fit_rigid_body_modes_and_pair(
    omega: np.ndarray,
    residual: np.ndarray,
    weight: np.ndarray,
    input_index: np.ndarray,
    n_rigid: int,
    omega_low: float,
    zeta: float,
    max_ratio: float = 10.0,
    found: np.ndarray | None = None,
) -> tuple[np.ndarray, float, complex, np.ndarray]:
    """Rigid-body modes below the band and one pair above it, fitted together to a residual.

    A free structure measured from above its rigid-body modes, whose band also stops short of
    the modes above it, leaves both in what the found modes leave of the FRFs: the mass line
    and the skirt of the modes above. Fitted one after the other, each would take part of the
    other (the mass line fit's ``w^2`` term is not a near pole's skirt, and a pair alone
    cannot hold a constant). So they are fitted together: ``R_kij = A_ij + b_k(w_r) P_ij``,
    ``A`` the mass line and ``P`` the pair's residue, both real, in closed form for each
    pole ``w_r`` (as in :func:`fit_residual_pair`, whose ``b_k`` and pole search this uses).
    The shapes come from ``A`` as in :func:`fit_rigid_body_modes` and from ``P`` as in
    :func:`fit_residual_pair`.

    Parameters
    ----------
    omega, residual, weight, input_index, n_rigid, omega_low
        As for :func:`fit_rigid_body_modes`.
    zeta, max_ratio, found
        As for :func:`fit_residual_pair`.

    Returns
    -------
    (Phi, share, lam, phi): the rigid-body shapes (n, n_rigid) and the mass line's share as
    :func:`fit_rigid_body_modes` returns them, the pair's root and shape (n,) as
    :func:`fit_residual_pair` does.

    Raises
    ------
    IdentificationError
        For any reason either of the two refuses.
    """
    why = rigid_body_fit_refusal(omega, len(input_index), n_rigid, omega_low)
    if why is not None:
        raise IdentificationError(why)
    w2 = weight**2
    R = np.where(w2 > 0, residual, 0.0)
    one, free = np.ones_like(omega), _found_mode_responses(omega, found)

    def fit(wr: float) -> tuple[np.ndarray, float]:
        return _real_residues(R, w2, np.vstack([one, _pole_response(omega, wr, zeta), free]))

    wr = _search_pole(lambda x: fit(np.exp(x))[1], float(omega[-1]), max_ratio)
    coef = fit(wr)[0]
    A, P = coef[..., 0], coef[..., 1]
    share = _mass_line_share(residual, w2, A, omega < omega_low)
    return (_rigid_body_shapes(A, input_index, n_rigid), share) + _pair(wr, zeta, P, input_index)
