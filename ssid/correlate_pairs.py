"""Mode-level correlation of two sets of shapes at the test DOFs: MAC, pairing, frequency
errors, orthogonality and cross-orthogonality (the ``paired_modes`` ... ``cross_orthogonality``
keys of ``ssidlab correlate``'s JSON, ``docs/correlation.md``).

Roles as in :mod:`ssid.correlate_models`: "test" shapes (identified model or CMIF peaks) in
rows, "analysis" shapes (the full model's modes at the test DOFs) in columns; ``M_tam`` is the
TAM mass at the test DOFs.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .correlate import (
    CROSS_ORTHOGONALITY_DIAG_MIN,
    MAX_PAIR_FREQ_RATIO,
    ORTHOGONALITY_OFFDIAG_MAX,
    auto_mac,
    cross_orthogonality,
    frequency_error_percent,
    frequency_ratio,
    modal_assurance,
    modes_at_rest,
    orthogonality,
    pair_modes_by_mac,
    real_mode_from_complex,
)
from .correlate_groups import compare_subspaces
from .correlate_scope import TAM_SPAN_MIN_SHARE, mass_check, mass_range, share_in_range
from .model_checks import RIGID_ROUNDOFF_RTOL

__all__ = ["MIN_PAIR_MAC", "mode_correlation", "pair_rule"]

#: Pairs with a lower MAC are not paired (no counterpart).
MIN_PAIR_MAC = 0.5
# Nor are modes further apart in frequency than ssid.correlate.MAX_PAIR_FREQ_RATIO: at 16 Z
# sensors a 54.6 Hz test mode had MAC 0.54 with the 1.29 Hz analysis mode (4140 % off) and a
# mode of the test model's with omega^2 < 0 MAC 0.51 with a 2310 Hz one (QA).


def mode_correlation(phi_test: np.ndarray, f_test: np.ndarray, phi_an: np.ndarray, f_an: np.ndarray,
                     M_tam: np.ndarray, test_groups: Sequence[Sequence[int]] | None = None,
                     warnings: list[str] | None = None) -> tuple[dict, np.ndarray, list]:
    """MAC, pairing, frequency errors, orthogonality and cross-orthogonality.

    Test modes that share a frequency, matched by analysis modes that also do, are first
    rotated within their span, and analysis modes that share a frequency, met by distinct
    test modes, within theirs (:func:`ssid.correlate_groups.compare_subspaces`); every
    measure is of the rotated shapes, and ``subspaces`` says which were rotated.

    Parameters
    ----------
    phi_test : (n, m_t)
        Test shapes at the test DOFs, real or complex.
    f_test : (m_t,)
        Their natural frequencies, Hz (signed: negative for omega^2 < 0).
    phi_an : (n, m_a), f_an : (m_a,)
        Analysis shapes at the test DOFs and frequencies, Hz.
    M_tam : (n, n)
        TAM mass.
    test_groups : sequence of sequences of int, optional
        0-based test modes known to share a frequency; default: by their frequencies
        (:func:`ssid.correlate_groups.frequency_groups`).
    warnings : list of str, optional
        Appended to: which mass-weighted checks are not applicable, and why
        (:mod:`ssid.correlate_scope`); those checks get ``status`` "not applicable" and
        ``pass`` None, their numbers kept.

    Returns
    -------
    summary : dict
        The JSON keys ``mac`` ... ``cross_orthogonality`` and ``subspaces``.
    mac : (m_t, m_a)
    pairs : list of ModePair
    """
    warnings = [] if warnings is None else warnings
    admissible, why_not = pair_rule(f_test, f_an)
    phi_test, phi_an, subspaces = compare_subspaces(phi_test, f_test, phi_an, f_an, M_tam, admissible,
                                                    MIN_PAIR_MAC, test_groups)
    mac = modal_assurance(phi_test, phi_an)
    pairs = pair_modes_by_mac(np.where(admissible, mac, 0.0), MIN_PAIR_MAC)
    phi_test_r = real_mode_from_complex(phi_test)
    xo = cross_orthogonality(phi_test_r, phi_an, M_tam)
    ti = [p.test for p in pairs]
    ai = [p.analysis for p in pairs]
    xo_paired = xo[np.ix_(ti, ai)]
    ortho = orthogonality(phi_test_r, M_tam)
    # No percentage against an analysis mode at 0 Hz to round-off (1e-8 of the largest omega^2,
    # an FE model's rigid-body modes: 4e-14 on a free beam). The looser rest bound of the pairing
    # would also take a payload's 1.29 Hz mode beside 2600 Hz (2.4e-7), whose error (-2.3 %
    # for a 1.26 Hz test mode) is a real one.
    rigid = modes_at_rest(f_an, RIGID_ROUNDOFF_RTOL)
    paired = [{"test_mode": p.test + 1, "analysis_mode": p.analysis + 1, "mac": p.mac,
               **_frequencies(f_test, f_an, rigid, p.test, p.analysis),
               "cross_orthogonality": float(xo[p.test, p.analysis])} for p in pairs]
    # Every test mode is paired or listed here with why: a mode that meets no analysis mode
    # (MAC below 0.5: a rigid-body mode compared in an arbitrary basis had 0.46) had vanished
    # from both lists.
    taken = {p.analysis: p for p in pairs}
    paired_tests = {p.test for p in pairs}
    not_paired = []
    for i in range(mac.shape[0]):
        if i in paired_tests:
            continue
        if not mac.shape[1]:
            not_paired.append({"test_mode": i + 1, "reason": "no analysis mode takes part"})
            continue
        j = int(np.argmax(mac[i]))
        if mac[i, j] < MIN_PAIR_MAC:
            why = f"no analysis mode has a MAC of {MIN_PAIR_MAC:g} or more with it (the best is this one)"
        elif not admissible[i, j]:
            why = why_not(i, j)
        else:
            other = taken[j]
            why = (f"analysis mode {j + 1} is paired with test mode {other.test + 1} (MAC {other.mac:.3f}): "
                   "pairs are one to one")
        not_paired.append({"test_mode": i + 1, "analysis_mode": j + 1, "mac": float(mac[i, j]),
                           **_frequencies(f_test, f_an, rigid, i, j), "reason": why})
    o_chk, x_chk = _mass_checks(phi_test_r, phi_an, M_tam, ortho, xo_paired, pairs, warnings)
    for rec, ok in zip(paired, x_chk.pop("applicable")):
        rec["cross_orthogonality_applicable"] = ok
    summary = {
        "mac": mac,
        "auto_mac_test": auto_mac(phi_test),
        "auto_mac_analysis": auto_mac(phi_an),
        "paired_modes": paired,
        "pairing": {"min_mac": MIN_PAIR_MAC, "max_freq_ratio": MAX_PAIR_FREQ_RATIO},
        "not_paired": not_paired,
        "subspaces": [s.to_dict() for s in subspaces],
        "freq_error_percent": [p["freq_error_percent"] for p in paired],
        "orthogonality": {
            "matrix": ortho,
            **o_chk,
            "criterion": {"offdiag_max": ORTHOGONALITY_OFFDIAG_MAX},
        },
        "cross_orthogonality": {
            "matrix": xo,
            "paired_matrix": xo_paired,
            **x_chk,
            "criterion": {"diag_min": CROSS_ORTHOGONALITY_DIAG_MIN,
                          "offdiag_max": ORTHOGONALITY_OFFDIAG_MAX},
        },
    }
    return summary, mac, pairs


def _mass_checks(phi_test: np.ndarray, phi_an: np.ndarray, M_tam: np.ndarray, ortho: np.ndarray,
                 xo_paired: np.ndarray, pairs: list, warnings: list[str]) -> tuple[dict, dict]:
    """The orthogonality and cross-orthogonality verdicts over the terms that apply
    (:mod:`ssid.correlate_scope`); notes of what does not apply are added to ``warnings``.
    The cross-orthogonality dict carries ``applicable``, one bool per pair, for the caller."""
    basis = mass_range(M_tam)
    rank, n_dof = basis.shape[1], np.shape(M_tam)[0]
    in_t = share_in_range(phi_test, basis) >= TAM_SPAN_MIN_SHARE
    in_a = share_in_range(phi_an, basis) >= TAM_SPAN_MIN_SHARE
    applicable = [bool(in_t[p.test] and in_a[p.analysis]) for p in pairs]
    out_t = np.flatnonzero(~in_t)
    out_a = sorted({p.analysis for p in pairs if not in_a[p.analysis]})
    if out_t.size or out_a:
        names = ([f"test mode{'s' if out_t.size > 1 else ''} {', '.join(str(k + 1) for k in out_t)}"]
                 if out_t.size else [])
        names += ([f"paired analysis mode{'s' if len(out_a) > 1 else ''} {', '.join(str(k + 1) for k in out_a)}"]
                  if out_a else [])
        warnings.append(f"the TAM mass has rank {rank} of {n_dof} (a SEREP TAM of fewer target modes than DOFs, or a "
                        "massless retained DOF?): "
                        f"{' and '.join(names)} lie mostly outside its range (less than "
                        f"{100 * TAM_SPAN_MIN_SHARE:g} % inside), where the mass sees only their projection: "
                        "their orthogonality and cross-orthogonality terms are not applicable")
    o_chk, o_note = mass_check(ortho, np.flatnonzero(in_t), rank, n_dof, "orthogonality", "test modes", 0.0)
    x_chk, x_note = mass_check(xo_paired, np.flatnonzero(applicable), rank, n_dof, "cross-orthogonality",
                               "paired modes", CROSS_ORTHOGONALITY_DIAG_MIN)
    warnings.extend(n for n in (o_note, x_note) if n)
    x_chk["applicable"] = [ok and x_note is None for ok in applicable]
    return o_chk, x_chk


def _frequencies(f_test: np.ndarray, f_an: np.ndarray, rigid: np.ndarray, i: int, j: int) -> dict:
    """The frequency fields of a (test i, analysis j) record. Against an analysis mode at 0 Hz
    (``rigid``) the error is in Hz only: a percentage of 0 Hz is round-off over round-off (-107 % and
    -88 % for two exact rigid-body modes at 1e-6 Hz), or infinite for a suspension mode."""
    err = float(frequency_error_percent(f_test[i], f_an[j]))
    return {"test_freq_hz": float(f_test[i]), "analysis_freq_hz": float(f_an[j]),
            "rigid": bool(rigid[j]), "freq_error_hz": float(f_test[i] - f_an[j]),
            "freq_error_percent": float("nan") if rigid[j] else err}


def pair_rule(f_test: np.ndarray, f_an: np.ndarray):
    """Which (test, analysis) modes may pair, and a function saying why a pair may not.

    A mode of either set is at rest when :func:`ssid.correlate.modes_at_rest` says so with the
    pairing's bound :data:`ssid.correlate.PAIR_REST_RTOL`, relative to its own set (a rigid-body
    mode, also one an identification put at +-noise, or a suspension mode far below the set's
    top). A test mode with omega^2 < 0 (a negative frequency, :func:`ssid.correlate_models._modes`)
    that is not at rest is no mode of a structure and pairs with nothing. Two modes at rest, one
    of each set, pair by the MAC alone: a free-free model's rigid-body mode is measured as a
    suspension mode on soft supports, which no frequency ratio with 0 Hz admits. So do a mode at
    rest in one set and a mode elastic in the other that lies below every elastic mode of the
    first set by more than :data:`MAX_PAIR_FREQ_RATIO` (no elastic mode of the first set can be
    its counterpart: a free-free chain's rigid-body mode against its 0.74 Hz suspension mode on
    bungees, 6e-5 of the test set's 96 Hz top in omega^2, the chain's first elastic mode at
    31 Hz). Every other pair needs frequencies within :data:`MAX_PAIR_FREQ_RATIO` of each other:
    a 0.47 Hz suspension mode in a 5.2 kHz band (at rest, 8e-9) does not pair with a constrained
    model's 800 Hz mode whose shape it resembles at the sensors, nor a model's rigid-body mode
    with an 800 Hz test mode, when the other set has elastic modes within the ratio of them
    (150 Hz).
    """
    rest_t, rest_a = modes_at_rest(f_test), modes_at_rest(f_an)
    negative = (np.asarray(f_test) < 0) & ~rest_t
    ratio = frequency_ratio(f_test, f_an)
    near = ratio * MAX_PAIR_FREQ_RATIO >= 1.0
    # A mode elastic in its set, against a mode at rest in the other: only when it lies below every
    # elastic mode of that other set by more than the ratio, which leaves it no other counterpart.
    f_t, f_a = np.abs(np.asarray(f_test, dtype=float)), np.abs(np.asarray(f_an, dtype=float))
    below_t = ~rest_t & (f_t * MAX_PAIR_FREQ_RATIO < np.min(f_a[~rest_a], initial=np.inf))
    below_a = ~rest_a & (f_a * MAX_PAIR_FREQ_RATIO < np.min(f_t[~rest_t], initial=np.inf))
    at_rest = (rest_t[:, None] | below_t[:, None]) & (rest_a[None, :] | below_a[None, :]) & ~(
        below_t[:, None] & below_a[None, :])
    ok = ~negative[:, None] & (at_rest | near)

    def why_not(i: int, j: int) -> str:
        if negative[i]:
            return "the test mode has omega^2 < 0 (K not positive semi-definite): not a physical mode"
        factor = "with one at 0 Hz" if ratio[i, j] == 0 else f"a factor {1 / ratio[i, j]:.3g} apart"
        apart = f"frequencies {factor} (a pair needs {MAX_PAIR_FREQ_RATIO:g} or less)"
        if rest_t[i] != rest_a[j]:
            still, other = ("test", "analysis") if rest_t[i] else ("analysis", "test")
            return (f"{apart}: the {still} mode is at rest, the {other} mode is not, and it is not below every "
                    f"elastic {still} mode by more than that ratio (a mode at rest pairs by the MAC alone only with "
                    "a mode at rest, or with one no elastic mode of its own set can claim)")
        return f"{apart}: shapes alike at the sensors (spatial aliasing), not taken for the same mode"

    return ok, why_not
