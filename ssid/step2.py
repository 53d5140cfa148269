"""SSID step 2: M, C, K from the step-1 matrices and the FRFs (Eqs. 3.10-3.26).

The state-space eigenproblem of Eq. 3.12 gives the complex modes; Eq. 3.23 fits their modal
scale factors 1/a~_r to the measured accelerances; Eq. 3.26 then rebuilds the symmetric state
matrices A_s, B_s of Eq. 3.15 whose partitions are M, C and K.

Two things differ from the report's MATLAB listing, on purpose:

* Conjugate modes get conjugate scale factors. The listing solves ``E \\ Y`` with complex
  unknowns, so A_s comes out complex and only its real part is kept. We solve for the real and
  imaginary parts of one factor per pair, which makes A_s real by construction and halves the
  unknowns.
* Eq. 3.23 is never formed. Its matrix has (lines x outputs x inputs) rows and 2n columns; its
  normal matrix is ``(Theta_x^H diag(b) Theta_x) o (P^H diag(a) P)`` (Hadamard product) when the
  weights factor as ``a_kj b_i``, where ``P[kj, r] = R_kr theta_r^T (D_f e_j + D_r h_r,kj)``
  (Eqs. 3.19, 3.24). Weights that do not factor (blanked values, per-value variances) are
  split into a short sum of such products by an SVD, or, failing that, accumulated in chunks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import IdentificationError
from .modal import companion_matrix
from .step1 import Step1Data

__all__ = ["StateSpaceModes", "ScaleFactors", "state_space_modes", "fit_scale_factors", "modal_scale_factors",
           "assemble_mck"]


@dataclass
class StateSpaceModes:
    """Complex modes of Eq. 3.12, ordered ``[upper pairs, their conjugates, real roots]``.

    Attributes
    ----------
    lam : (2n,) complex
        Eigenvalues lambda_r, rad/s. Oscillatory roots first (Im > 0, ascending |lambda|),
        then their conjugates in the same order, then real (overdamped) roots.
    theta : (2n, 2n) complex
        Eigenvectors ``[phi; lambda phi]``, columns in the order of ``lam``.
    n_pairs : int
        Number of complex-conjugate pairs.
    rigid_shapes : (n, r) float or None
        Rigid-body modes (free-free structure, :mod:`ssid.rigid_body`), orthonormal columns:
        each is a double root at ``lambda = 0`` with one eigenvector ``[phi; 0]`` and one
        principal vector ``[0; phi]`` (a Jordan block, which no eigenvector basis holds), and
        is not among ``lam``, ``theta``. None: no rigid-body modes.
    near_rigid_kc : ((r, r), (r, r)) float or None
        When set, ``rigid_shapes`` hold ``2 r`` roots near 0 that are *not* rigid-body modes
        (the data show their stiffness): ``(Phi0^T K^ Phi0, Phi0^T C^ Phi0)``, the stiffness
        and damping per unit mass of the ``r``-DOF motion in those shapes. Such roots are as
        nearly defective as rigid-body modes, so they too enter step 2 as one block on their
        shapes rather than through their nearly parallel eigenvectors. None: the shapes are
        rigid-body modes (``K^ Phi0 = C^ Phi0 = 0``).
    """

    lam: np.ndarray
    theta: np.ndarray
    n_pairs: int
    rigid_shapes: np.ndarray | None = None
    near_rigid_kc: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def n(self) -> int:
        return self.theta.shape[0] // 2

    @property
    def n_block(self) -> int:
        """Number of shapes ``r`` in ``rigid_shapes`` (rigid or near-rigid)."""
        return 0 if self.rigid_shapes is None else self.rigid_shapes.shape[1]

    @property
    def n_rigid(self) -> int:
        """Number of rigid-body modes ``r`` (0 when the shapes are near-rigid)."""
        return 0 if self.near_rigid_kc is not None else self.n_block

    @property
    def theta_x(self) -> np.ndarray:
        """Displacement partition of the eigenvectors, (n, 2n)."""
        return self.theta[: self.n]


def state_space_modes(C_hat: np.ndarray, K_hat: np.ndarray) -> StateSpaceModes:
    """Solve ``(lambda A^_s + B^_s) theta = 0`` (Eqs. 3.11-3.12).

    ``A^_s`` is always invertible, and ``-A^_s^-1 B^_s = [[0, I], [-K^, -C^]]``, so the
    generalised problem is the standard eigenproblem of that companion matrix.
    """
    lam, V = np.linalg.eig(companion_matrix(C_hat, K_hat))
    scale = np.max(np.abs(lam)) if lam.size else 1.0
    is_real = np.abs(lam.imag) <= 1e-10 * max(scale, 1e-300)
    upper = np.flatnonzero(~is_real & (lam.imag > 0))
    upper = upper[np.argsort(np.abs(lam[upper]))]
    n_lower = int(np.count_nonzero(~is_real & (lam.imag < 0)))
    if n_lower != upper.size:
        raise IdentificationError("state-space eigenvalues do not come in conjugate pairs")
    real = np.flatnonzero(is_real)
    real = real[np.argsort(np.abs(lam[real]))]
    V_up = V[:, upper]
    # Real roots have real eigenvectors; remove the arbitrary phase eig() may leave on them.
    V_re = V[:, real]
    if real.size:
        phase = np.exp(-1j * np.angle(V_re[np.argmax(np.abs(V_re), axis=0), np.arange(real.size)]))
        V_re = (V_re * phase).real.astype(complex)
    lam_all = np.concatenate([lam[upper], lam[upper].conj(), lam[real].real.astype(complex)])
    theta = np.hstack([V_up, V_up.conj(), V_re])
    return StateSpaceModes(lam=lam_all, theta=theta, n_pairs=int(upper.size))


def _factor_weights(w2: np.ndarray, max_terms: int = 4) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """Write ``w2[kj, i]`` as ``sum_t a_t[kj] b_t[i]`` with few terms, or return None."""
    if np.all(w2 == w2[:1]):  # same weight profile over outputs in every column
        return [(np.ones(w2.shape[0]), w2[0])]
    col = w2[:, :1]
    if np.all(col > 0) and np.allclose(w2 / col, w2[:1] / col[:1], rtol=1e-12, atol=0):
        return [(col[:, 0], w2[0] / col[0, 0])]
    U, s, Vt = np.linalg.svd(w2, full_matrices=False)
    rank = int(np.count_nonzero(s > 1e-13 * s[0])) if s.size and s[0] > 0 else 0
    if rank == 0 or rank > max_terms:
        return None
    return [(U[:, t] * s[t], Vt[t]) for t in range(rank)]


@dataclass
class ScaleFactors:
    """The fit of Eq. 3.23: modal scale factors and, for rigid-body modes, their mass line.

    Attributes
    ----------
    u : (q,) complex
        ``1/a~_r`` for the roots ``modes.lam``; a conjugate root's is its partner's conjugate.
    rigid_inv_mass : (r, r) float
        ``(Phi0^T M Phi0)^-1`` for the rigid-body shapes ``Phi0`` (``modes.rigid_shapes``):
        their accelerance is the mass line ``Phi0 rigid_inv_mass Phi0^T``, constant in
        frequency. (0, 0) without rigid-body modes.
    cost : float or None
        Weighted residual ``sum w^2 |H - H_fit|^2`` of the fit (``with_cost``), else None.
    """

    u: np.ndarray
    rigid_inv_mass: np.ndarray
    cost: float | None = None


def _root_terms(modes: StateSpaceModes) -> np.ndarray:
    """``c = T v`` for the roots' scale factors, with ``v`` real: a conjugate pair shares
    (Re, Im), a real root has a real factor. (ns, ns) complex."""
    ns, m = modes.lam.size, modes.n_pairs
    T = np.zeros((ns, ns), dtype=complex)
    i = np.arange(m)
    T[i, i] = 1.0
    T[i, m + i] = 1j
    T[m + i, i] = 1.0
    T[m + i, m + i] = -1j
    j = np.arange(2 * m, ns)
    T[j, j] = 1.0
    return T


def _block_factors(modes: StateSpaceModes, omega: np.ndarray, rigid_stiffness_test: bool) -> list[np.ndarray]:
    """Frequency factors ``F_f`` (L, r, r) of the block on ``Phi0 = modes.rigid_shapes``, whose
    accelerance is ``sum_f Phi0 F_f(w) G_f Phi0^T`` with ``G_f`` symmetric unknowns.

    Rigid-body modes: ``F = I`` (the mass line, ``G = (Phi0^T M Phi0)^-1``), and for the
    stiffness test also ``I / w^2`` and ``j I / w`` (:func:`fit_scale_factors`). Near-rigid
    shapes with ``(K^r, C^r) = modes.near_rigid_kc``: the ``r``-DOF accelerance
    ``-w^2 Phi0 (Mr (-w^2 I + j w C^r + K^r))^-1 Phi0^T`` is ``F = -w^2 (-w^2 I + j w C^r +
    K^r)^-1`` times ``G = Mr^-1``, linear in ``G`` as the mass line is (and equal to it for
    ``K^r = C^r = 0``).
    """
    r = modes.n_block
    eye = np.eye(r)
    if modes.near_rigid_kc is not None:
        if rigid_stiffness_test:
            raise ValueError("the rigid-body stiffness test applies to rigid-body shapes only")
        Kr, Cr = modes.near_rigid_kc
        w = omega[:, None, None]
        return [-(w**2) * np.linalg.inv(-(w**2) * eye + 1j * w * Cr + Kr)]
    # The mass line is constant; the stiffness and damping terms of the test go as 1/w^2, j/w.
    scalars = [np.ones(omega.size), 1.0 / omega**2, 1j / omega][: 3 if rigid_stiffness_test else 1]
    return [f[:, None, None] * eye for f in scalars]


def fit_scale_factors(d: Step1Data, modes: StateSpaceModes, with_cost: bool = False,
                      rigid_stiffness_test: bool = False) -> ScaleFactors:
    """Weighted least-squares estimate of ``1/a~_r`` from Eq. 3.23, and of the rigid-body
    modes' mass line when ``modes`` has rigid-body shapes.

    A rigid-body mode (a double root at 0 with eigenvector ``[phi; 0]`` and principal vector
    ``[0; phi]``) adds ``phi phi^T / (phi^T M phi)`` to the accelerance at every line: the
    mass line. For several, ``Phi0 (Phi0^T M Phi0)^-1 Phi0^T``, whose symmetric ``r x r``
    middle factor is fitted with the scale factors (it is linear in the data, as they are).
    Near-rigid shapes (``modes.near_rigid_kc``) add their ``r``-DOF accelerance, linear in the
    same middle factor (:func:`_block_factors`).

    Parameters
    ----------
    d : Step1Data
        Measured accelerances ``H`` (L, n, n_in), reactions ``Hr`` and weights ``1/sigma``.
    modes : StateSpaceModes
    with_cost : bool
        Also return the weighted residual of the fit (``ScaleFactors.cost``).
    rigid_stiffness_test : bool
        Fit the rigid-body shapes' accelerance to first order in a stiffness ``Kr`` and a
        damping ``Cr`` between them and the ground instead of as a pure mass line:
        ``Phi0 (Mr - Kr / w^2 + Cr / (j w))^-1 Phi0^T`` is, to first order,
        ``Phi0 (G + S_K / w^2 + j S_C / w) Phi0^T`` with ``S_K = G Kr G``, ``S_C = G Cr G``
        symmetric: ``r (r + 1)`` more unknowns, linear as the others. Its residual is what
        :func:`ssid.rigid_body.choose_rigid_body_modes` tests the mass line alone against.

    Returns
    -------
    ScaleFactors
        ``rigid_inv_mass`` is the block's ``G = Mr^-1`` (rigid or near-rigid shapes).
    """
    theta_x = modes.theta_x
    n, ns = theta_x.shape
    r = modes.n_block
    basis = theta_x if r == 0 else np.hstack([theta_x, modes.rigid_shapes])  # (n, ns + r)
    nb = basis.shape[1]
    lam = modes.lam
    w = d.omega[:, None]
    R = -(w**2) / (1j * w - lam[None, :])  # Eq. 3.19, (L, ns)
    # q_kjr = theta_r^T (D_f e_j + D_r h_r,kj) of Eq. 3.24, (L, n_in, nb)
    q = np.broadcast_to(basis[d.in_idx][None], (d.omega.size, d.n_in, nb))
    if d.n_r:
        q = q + np.einsum("mr,kmj->kjr", basis[d.r_idx], d.Hr)
    # The model is H_kj = sum_t c_t Bt[:, t] Pt[kj, t] with c = T v, v real. One term per
    # root (the report's Eq. 3.23, left as it was); the block's terms are (a, e, b) of
    # Phi0[:, a] F_f[a, e] G_f[e, b] q_b, G_f[e, b] = G_f[b, e] one unknown.
    # Rows (k, j), sized explicitly: with every root taken as a rigid-body mode (a free
    # structure's mass line and nothing else), ns is 0 and reshape(-1, 0) is ambiguous.
    Pt = (R[:, None, :] * q[:, :, :ns]).reshape(d.omega.size * d.n_in, ns)
    Bt = basis[:, :ns]
    T = _root_terms(modes)
    n_sym = r * (r + 1) // 2
    if r:
        cols_b, cols_p, unknown = [], [], []
        tri = {(lo, hi): k for k, (lo, hi) in enumerate(zip(*np.triu_indices(r)))}
        families = _block_factors(modes, d.omega, rigid_stiffness_test)
        for f, F in enumerate(families):
            for a in range(r):
                for e in range(r):
                    if not np.any(F[:, a, e]):  # a rigid family's F is diagonal
                        continue
                    for b in range(r):
                        cols_b.append(ns + a)
                        cols_p.append((F[:, a, e, None] * q[:, :, ns + b]).reshape(-1))
                        unknown.append(ns + f * n_sym + tri[min(e, b), max(e, b)])
        Bt = np.hstack([Bt, basis[:, cols_b]])
        Pt = np.hstack([Pt, np.stack(cols_p, axis=1)])
        Tb = np.zeros((len(unknown), ns + len(families) * n_sym), dtype=complex)
        Tb[np.arange(len(unknown)), unknown] = 1.0
        T = np.vstack([np.hstack([T, np.zeros((ns, Tb.shape[1] - ns))]), Tb])
    Hkj = np.swapaxes(d.H, 1, 2).reshape(-1, n)  # (L n_in, n)
    w2 = (np.swapaxes(d.weight, 1, 2) ** 2).reshape(-1, n)
    nt = Bt.shape[1]

    # Right-hand side: sum_kj conj(Pt_kj,t) (Bt^H (w^2 o h_kj))_t
    rhs = np.sum(Pt.conj() * ((w2 * Hkj) @ Bt.conj()), axis=0)
    terms = _factor_weights(w2)
    if terms is not None:
        N = np.zeros((nt, nt), dtype=complex)
        for a, b in terms:
            N += (Bt.conj().T @ (b[:, None] * Bt)) * (Pt.conj().T @ (a[:, None] * Pt))
    else:
        N = np.zeros((nt, nt), dtype=complex)
        chunk = max(1, 2**20 // (n * nt))
        for s in range(0, Pt.shape[0], chunk):
            Y = Pt[s : s + chunk, None, :] * Bt[None, :, :]  # (c, n, nt)
            Yw = Y * np.sqrt(w2[s : s + chunk])[:, :, None]
            Y2 = Yw.reshape(-1, nt)
            N += Y2.conj().T @ Y2

    Nr = (T.conj().T @ N @ T).real
    br = (T.conj().T @ rhs).real
    s = np.sqrt(np.abs(np.diag(Nr)))
    if np.any(s == 0):
        raise IdentificationError(
            "a mode has no valid data to fix its scale (Eq. 3.23): widen the band or add lines"
        )
    v = np.linalg.lstsq(Nr / s[:, None] / s[None, :], br / s, rcond=None)[0] / s
    c = T @ v
    cost = None
    if with_cost:
        fitted = (Pt * c) @ Bt.T  # (L n_in, n)
        cost = float(np.sum(w2 * np.abs(Hkj - fitted) ** 2))
    G = np.zeros((r, r))
    G[np.triu_indices(r)] = v[ns : ns + n_sym]
    G = G + np.triu(G, 1).T
    return ScaleFactors(u=c[:ns], rigid_inv_mass=G, cost=cost)


def modal_scale_factors(d: Step1Data, modes: StateSpaceModes) -> np.ndarray:
    """``1/a~_r`` of Eq. 3.23 (:func:`fit_scale_factors`), (q,) complex, for modes without
    rigid-body shapes."""
    return fit_scale_factors(d, modes).u


def assemble_mck(
    modes: StateSpaceModes, u: np.ndarray, rigid_inv_mass: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Rebuild M, C, K from the modes and their scale factors (Eqs. 3.25-3.26, 3.15).

    Parameters
    ----------
    modes : StateSpaceModes
    u : (q,) complex
        ``1/a~_r`` of the roots ``modes.lam``.
    rigid_inv_mass : (r, r) float, optional
        For ``modes.rigid_shapes`` ``Phi0``: ``(Phi0^T M Phi0)^-1`` (:class:`ScaleFactors`).
        Needed for rigid-body and near-rigid shapes alike.

    Returns
    -------
    (M, C, K, info): ``info`` holds the relative imaginary residue of A_s, B_s and the relative
    disagreement between the three copies of M in A_s and B_s (both ~0 for a consistent fit);
    with rigid-body modes also ``rigid_damping_removed``, the relative part of C taken out to
    make ``C Phi0 = 0`` (of the order of that disagreement).

    Notes
    -----
    Rigid-body modes enter Eq. 3.26 as Jordan blocks: with ``V0 = [[Phi0, 0], [0, Phi0]]``
    (eigenvectors ``[Phi0; 0]``, principal vectors ``[0; Phi0]``) and ``Mr = Phi0^T M Phi0``,
    the structure of A_s, B_s (Eq. 3.15) with ``K Phi0 = 0``, ``C Phi0 = 0`` gives
    ``V0^T A_s V0 = [[0, Mr], [Mr, 0]]`` and ``V0^T B_s V0 = [[0, 0], [0, -Mr]]``, and both are
    orthogonal to the other modes. ``Theta = [theta, V0]`` then stays well conditioned where
    the eigenvectors of a (nearly) defective double root at 0 are (nearly) parallel.

    Near-rigid shapes (``modes.near_rigid_kc = (K^r, C^r)``) enter the same way with their
    stiffness and damping: ``V0^T A_s V0 = [[Cr, Mr], [Mr, 0]]``,
    ``V0^T B_s V0 = [[Kr, 0], [0, -Mr]]``, ``Kr = Mr K^r``, ``Cr = Mr C^r``. That holds where
    ``Phi0`` spans an invariant subspace of ``K^`` and ``C^`` (exactly for real shapes) and,
    for the roots near 0 the block is used for, to the accuracy step 1 gives them.
    """
    n = modes.n
    if np.any(u == 0) or not np.all(np.isfinite(u)):
        raise IdentificationError("a modal scale factor 1/a~_r is zero or not finite (Eq. 3.23)")
    a = 1.0 / u
    b = -modes.lam * a  # Eq. 3.25
    r = modes.n_block
    if r == 0:
        Ti = np.linalg.inv(modes.theta)
        As = Ti.T @ (a[:, None] * Ti)  # Eq. 3.26
        Bs = Ti.T @ (b[:, None] * Ti)
    else:
        G = np.asarray(rigid_inv_mass, dtype=float)
        if G.shape != (r, r) or not np.all(np.isfinite(G)) or np.linalg.cond(G) > 1e14:
            raise IdentificationError("the rigid-body modes' mass line is singular or not finite (Eq. 3.23)")
        Mr = np.linalg.inv((G + G.T) / 2)
        Kr = Cr = np.zeros((r, r))
        if modes.near_rigid_kc is not None:
            Kr, Cr = (Mr @ X for X in modes.near_rigid_kc)
            Kr, Cr = (Kr + Kr.T) / 2, (Cr + Cr.T) / 2
        Phi0, Z = modes.rigid_shapes, np.zeros((n, r))
        Ti = np.linalg.inv(np.hstack([modes.theta, np.block([[Phi0, Z], [Z, Phi0]])]))
        q = a.size
        Ablk = np.zeros((q + 2 * r, q + 2 * r), dtype=complex)
        Bblk = np.zeros_like(Ablk)
        Ablk[:q, :q] = np.diag(a)
        Bblk[:q, :q] = np.diag(b)
        Ablk[q : q + r, q + r :] = Mr
        Ablk[q + r :, q : q + r] = Mr
        Bblk[q + r :, q + r :] = -Mr
        Ablk[q : q + r, q : q + r] = Cr
        Bblk[q : q + r, q : q + r] = Kr
        As = Ti.T @ Ablk @ Ti
        Bs = Ti.T @ Bblk @ Ti
    M = -Bs[n:, n:].real
    C = As[:n, :n].real
    K = Bs[:n, :n].real
    scale = max(np.abs(As).max(), np.abs(Bs).max())
    extra = {}
    if modes.n_rigid:
        # K Phi0 = 0 holds exactly (B_s V0 has no column there); C Phi0 = 0 only as far as the
        # fit is one second-order system (as the copies of M agree). Projecting C onto the
        # motions M-orthogonal to Phi0 makes it hold and leaves the damping of those motions,
        # the elastic modes', as it was.
        C_full = C
        Pm = np.eye(n) - Phi0 @ np.linalg.solve(Phi0.T @ M @ Phi0, Phi0.T @ M)
        C = Pm.T @ C @ Pm
        extra["rigid_damping_removed"] = float(np.linalg.norm(C_full - C) / max(np.linalg.norm(C_full), 1e-300))
    info = {
        "imag_residue": float(max(np.abs(As.imag).max(), np.abs(Bs.imag).max()) / scale),
        "mass_copies_mismatch": float(
            max(np.abs(As[:n, n:].real - M).max(), np.abs(As[n:, :n].real - M).max())
            / max(np.abs(M).max(), 1e-300)
        ),
        **extra,
    }
    # A_s and B_s are symmetric by construction; remove rounding asymmetry only.
    return (M + M.T) / 2, (C + C.T) / 2, (K + K.T) / 2, info
