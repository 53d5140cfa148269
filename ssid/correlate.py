"""Mode-shape correlation: MAC, orthogonality, cross-orthogonality, pairing, frequency errors.

Criteria (report section 2.x and 6.5; NASA-STD-5002 practice): test modes normalised to unit
modal mass with the TAM mass should be orthogonal, off-diagonal terms of
``Phi_test^T M_tam Phi_test`` below 0.1; in cross-orthogonality ``Phi_test^T M_tam Phi_fem``
the paired (diagonal) terms should be above 0.9 in magnitude and the others below 0.1.
MAC is scale-free and needs no mass matrix, but it is "not a true orthogonality check"
(section 6.2.3): two modes may be mass-orthogonal and still have a large MAC.

Modes are columns; ``(n, m)`` arrays, real or complex.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from .errors import InputError

__all__ = [
    "CROSS_ORTHOGONALITY_DIAG_MIN",
    "MAX_PAIR_FREQ_RATIO",
    "ORTHOGONALITY_OFFDIAG_MAX",
    "PAIR_REST_RTOL",
    "ModePair",
    "OrthogonalityCheck",
    "auto_mac",
    "check_orthogonality",
    "cross_orthogonality",
    "frequency_error_percent",
    "frequency_ratio",
    "modal_assurance",
    "modes_at_rest",
    "normalize_modal_mass",
    "orthogonality",
    "pair_modes_by_mac",
    "pair_modes_by_mac_and_frequency",
    "real_mode_from_complex",
]

#: Largest acceptable magnitude of an off-diagonal (orthogonality or cross-orthogonality) term.
ORTHOGONALITY_OFFDIAG_MAX = 0.1
#: Smallest acceptable magnitude of a paired (diagonal) cross-orthogonality term.
CROSS_ORTHOGONALITY_DIAG_MIN = 0.9


def modal_assurance(phi_a: np.ndarray, phi_b: np.ndarray) -> np.ndarray:
    """Modal assurance criterion between two sets of shapes.

    ``MAC_jk = |phi_a,j^H phi_b,k|^2 / ((phi_a,j^H phi_a,j) (phi_b,k^H phi_b,k))``

    Parameters
    ----------
    phi_a : (n, m_a) or (n,), phi_b : (n, m_b) or (n,)
        Shapes over the same DOFs, real or complex, any scaling; a 1-D array is one shape.

    Returns
    -------
    (m_a, m_b) float in [0, 1]; unchanged when any shape is multiplied by any nonzero
    (complex) number. A zero shape gives a zero row or column: a mode at rest at every DOF
    compared (a mode of another direction of a model whose directions do not couple, whose
    shape is exactly zero there) correlates with nothing, and is no error.

    Raises
    ------
    InputError
        NaN or Inf in a shape (its MAC would be 0 with every shape, silently), shapes over
        different numbers of DOFs, or an array of more than two dimensions.
    """
    a = _mode_columns(phi_a, "phi_a")
    b = _mode_columns(phi_b, "phi_b")
    if a.shape[0] != b.shape[0]:
        raise InputError(f"MAC: the shapes have {a.shape[0]} and {b.shape[0]} DOFs")
    # Each shape to unit length first: the squares of the products below overflow or
    # underflow for shapes far from unit scale (1e+-100: a model in odd units), which
    # the MAC, a ratio, does not depend on.
    a, b = _unit_columns(a), _unit_columns(b)
    num = np.abs(a.conj().T @ b) ** 2
    na = np.real(np.einsum("ij,ij->j", a.conj(), a))
    nb = np.real(np.einsum("ij,ij->j", b.conj(), b))
    den = np.outer(na, nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        mac = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    return np.clip(mac, 0.0, 1.0)


def _mode_columns(phi: np.ndarray, name: str) -> np.ndarray:
    """Shapes as an (n_dof, n_modes) array; a 1-D array is one shape (a column).

    ``np.atleast_2d`` would make a 1-D shape a row: n modes of one DOF each, whose MACs are all
    1 or 0 whatever the shapes.
    """
    a = np.asarray(phi)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2 or a.dtype.kind not in "biufc":
        raise InputError(f"{name} must be a numeric shape vector or (n_dof, n_modes) array, got "
                         f"{a.dtype} of shape {a.shape}")
    bad = ~np.isfinite(a)
    if bad.any():
        dof, mode = np.argwhere(bad)[0]
        raise InputError(f"{name} holds NaN or Inf in {int(bad.sum())} value(s), first at DOF {dof + 1} "
                         f"of mode {mode + 1}")
    return a


def _unit_columns(phi: np.ndarray) -> np.ndarray:
    """``phi`` with each nonzero column scaled to unit 2-norm (zero columns left zero)."""
    phi = np.asarray(phi)
    big = np.max(np.abs(phi), axis=0) if phi.size else np.zeros(phi.shape[1])
    phi = phi / np.where(big > 0, big, 1.0)  # largest entry 1 first: the norm's squares stay finite
    norm = np.linalg.norm(phi, axis=0)
    return phi / np.where(norm > 0, norm, 1.0)


def auto_mac(phi: np.ndarray) -> np.ndarray:
    """MAC of a set of shapes with itself, (m, m): off-diagonal terms show spatial aliasing
    (too few or badly placed sensors make distinct modes look alike)."""
    return modal_assurance(phi, phi)


def real_mode_from_complex(phi: np.ndarray) -> np.ndarray:
    """Real shapes closest to complex ones, (n, m).

    Each column is rotated in the complex plane so that its real part carries the most
    energy (the principal direction of the points ``(Re, Im)``), then the real part is kept.
    For a normal mode (MPC = 1) this is exact up to scale. A 1-D array is one shape, returned
    as one column.
    """
    phi = _mode_columns(phi, "phi")
    if not np.iscomplexobj(phi):
        return phi.astype(float)
    # The angle maximising sum(Re(e^{-j a} phi)^2) is half the angle of sum(phi^2).
    ang = 0.5 * np.angle(np.sum(phi**2, axis=0))
    return np.real(phi * np.exp(-1j * ang))


def normalize_modal_mass(phi: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Shapes scaled to unit modal mass ``phi^T M phi = 1`` (real shapes), (n, m).

    A shape with zero or negative modal mass (M not definite on it) is returned unscaled.
    """
    phi = np.asarray(phi, dtype=float)
    m = np.einsum("ij,ik,kj->j", phi, np.asarray(M, dtype=float), phi)
    scale = np.where(m > 0, 1.0 / np.sqrt(np.where(m > 0, m, 1.0)), 1.0)
    return phi * scale


def orthogonality(phi: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Test-mode orthogonality ``Phi^T M Phi`` with unit-modal-mass shapes, (m, m).

    Parameters
    ----------
    phi : (n, m)
        Real shapes (test modes) at the TAM's DOFs, any scaling.
    M : (n, n)
        TAM mass matrix.

    Returns
    -------
    Diagonal 1; for well-measured modes and a good TAM the off-diagonal terms are < 0.1.
    """
    p = normalize_modal_mass(phi, M)
    O = p.T @ np.asarray(M, dtype=float) @ p
    return (O + O.T) / 2


def cross_orthogonality(phi_test: np.ndarray, phi_analysis: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Cross-orthogonality ``Phi_test^T M Phi_analysis``, both at unit modal mass in ``M``.

    Parameters
    ----------
    phi_test : (n, m_t), phi_analysis : (n, m_a)
        Real shapes at the TAM's DOFs, any scaling.
    M : (n, n)
        TAM mass matrix.

    Returns
    -------
    (m_t, m_a)
        Signed; a model's modes against themselves give the identity.
    """
    M = np.asarray(M, dtype=float)
    return normalize_modal_mass(phi_test, M).T @ M @ normalize_modal_mass(phi_analysis, M)


@dataclass
class OrthogonalityCheck:
    """Summary of an orthogonality or cross-orthogonality matrix against the criteria.

    For an empty matrix (no mode paired) there is nothing to summarise: ``min_diag`` and
    ``max_offdiag`` are NaN, ``worst_offdiag`` None (null in JSON), and the check fails.
    """

    min_diag: float
    max_offdiag: float
    worst_offdiag: tuple[int, int] | None
    passed: bool

    def to_dict(self) -> dict:
        def number(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None

        return {
            "min_abs_diag": number(self.min_diag),
            "max_abs_offdiag": number(self.max_offdiag),
            "worst_offdiag": (None if self.worst_offdiag is None else
                              [int(self.worst_offdiag[0]) + 1, int(self.worst_offdiag[1]) + 1]),
            "pass": bool(self.passed),
        }


def check_orthogonality(
    O: np.ndarray,
    diag_min: float = CROSS_ORTHOGONALITY_DIAG_MIN,
    offdiag_max: float = ORTHOGONALITY_OFFDIAG_MAX,
) -> OrthogonalityCheck:
    """Check a square (paired) orthogonality matrix: ``|diag| >= diag_min``,
    ``|offdiag| < offdiag_max``. ``worst_offdiag`` is 0-based (row, column). An empty matrix
    fails, with NaN and None for its numbers: no pair is no evidence of orthogonality, and a
    minimum of 1 and maximum of 0 there would be placeholders read as values."""
    A = np.abs(np.asarray(O, dtype=float))
    if A.size == 0:
        return OrthogonalityCheck(float("nan"), float("nan"), None, False)
    m = min(A.shape)
    d = np.diagonal(A)[:m]
    off = A.copy()
    off[np.arange(m), np.arange(m)] = 0.0
    worst = np.unravel_index(np.argmax(off), off.shape) if off.size else (0, 0)
    max_off = float(off.max()) if off.size else 0.0
    min_d = float(d.min()) if d.size else 1.0
    return OrthogonalityCheck(min_d, max_off, (int(worst[0]), int(worst[1])),
                              bool(min_d >= diag_min and max_off < offdiag_max))


@dataclass
class ModePair:
    """A test mode paired with an analysis mode (0-based indices)."""

    test: int
    analysis: int
    mac: float


def pair_modes_by_mac(mac: np.ndarray, min_mac: float = 0.5) -> list[ModePair]:
    """One-to-one pairing of test modes (rows) with analysis modes (columns) by MAC.

    The assignment maximising the sum of MAC (Hungarian algorithm) rather than each row's
    largest MAC, so that two test modes never claim the same analysis mode. Only MACs of at
    least ``min_mac`` count in that sum: otherwise a weak correlation elsewhere (0.4, no
    pair) could buy a wrong pair (0.9) the place of a right one (1.0).

    Returns
    -------
    list of ModePair, in ascending test-mode order.
    """
    mac = np.asarray(mac, dtype=float)
    if mac.size == 0:
        return []
    rows, cols = linear_sum_assignment(np.where(mac >= min_mac, mac, 0.0), maximize=True)
    pairs = [ModePair(int(i), int(j), float(mac[i, j])) for i, j in zip(rows, cols)]
    return sorted((p for p in pairs if p.mac >= min_mac), key=lambda p: p.test)


#: Modes further apart in frequency than this factor are not paired, however alike their
#: shapes at the sensors (:func:`pair_modes_by_mac_and_frequency`, and ``ssidlab correlate``).
MAX_PAIR_FREQ_RATIO = 2.0


def frequency_ratio(f_a_hz: np.ndarray, f_b_hz: np.ndarray) -> np.ndarray:
    """``min(|f_a|, |f_b|) / max(|f_a|, |f_b|)`` of every pair, (n_a, n_b): 1 for equal
    frequencies, 0 against 0 Hz (and for two at 0 Hz)."""
    fa = np.abs(np.asarray(f_a_hz, dtype=float))[:, None]
    fb = np.abs(np.asarray(f_b_hz, dtype=float))[None, :]
    return np.minimum(fa, fb) / np.maximum(np.maximum(fa, fb), 1e-300)


def pair_modes_by_mac_and_frequency(
    mac: np.ndarray, f_test_hz: np.ndarray, f_ref_hz: np.ndarray, min_mac: float = 0.5,
    max_freq_ratio: float = MAX_PAIR_FREQ_RATIO,
) -> list[ModePair]:
    """One-to-one pairing on ``MAC x min(f_t, f_r) / max(f_t, f_r)``; a pair needs
    ``MAC >= min_mac`` and frequencies within a factor ``max_freq_ratio``.

    MAC alone cannot tell apart modes that look alike at few sensors (spatial aliasing: at 16
    Z sensors a 1.3 Hz rigid-body mode and an 800 Hz rotation-dominated mode can have MAC
    0.6); their frequencies can. Without the frequency bound, a reference mode whose
    counterpart is missing would take whatever test mode is left over. ``ModePair.mac``
    holds the MAC, not the score.

    Parameters
    ----------
    mac : (n_test, n_ref) MAC matrix.
    f_test_hz : (n_test,), f_ref_hz : (n_ref,) natural frequencies, Hz.
    """
    mac = np.asarray(mac, dtype=float)
    ratio = frequency_ratio(f_test_hz, f_ref_hz)
    ok = (mac >= min_mac) & (ratio * max_freq_ratio >= 1.0)
    score = np.where(ok, mac * ratio, 0.0)
    return [ModePair(p.test, p.analysis, float(mac[p.test, p.analysis]))
            for p in pair_modes_by_mac(score, 0.0) if ok[p.test, p.analysis]]


#: A mode with |omega^2| at most this fraction of its set's largest is at rest (a rigid-body
#: mode): looser than an FE model's round-off (``ssid.tam.RIGID_ROUNDOFF_RTOL``), as an
#: identified model's rigid-body mode comes out at omega^2 of -0.04 (rad/s)^2 beside 4e5; a
#: suspension mode of a free-free test below 1e-3 of its band in frequency is at rest too. A
#: mode at rest pairs by the MAC alone only with a mode at rest in the other set, or with an
#: elastic mode no elastic mode of its own set can claim (:func:`ssid.correlate_pairs.pair_rule`).
PAIR_REST_RTOL = 1e-6


def modes_at_rest(f_hz: np.ndarray, rtol: float = PAIR_REST_RTOL) -> np.ndarray:
    """Which modes of one set are at rest (rigid-body modes), (n,) bool.

    ``|omega^2| <= rtol * max |omega^2|`` over the same set, with ``f_hz`` signed (a negative
    frequency for omega^2 < 0, as :func:`ssid.tam.natural_frequencies_hz` gives). With
    ``ssid.tam.RIGID_ROUNDOFF_RTOL`` (1e-8): at 0 Hz to an FE model's round-off.
    """
    w2 = (2 * np.pi * np.asarray(f_hz, dtype=float)) ** 2
    return w2 <= rtol * (np.max(w2) if w2.size else 0.0)


def frequency_error_percent(f_test_hz: np.ndarray, f_ref_hz: np.ndarray) -> np.ndarray:
    """``100 (f_test - f_ref) / f_ref``, element-wise (signed: positive = test above)."""
    f_test = np.asarray(f_test_hz, dtype=float)
    f_ref = np.asarray(f_ref_hz, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(f_ref != 0, 100.0 * (f_test - f_ref) / np.where(f_ref != 0, f_ref, 1.0), np.nan)
