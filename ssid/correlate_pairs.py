"""Mode-level correlation of two sets of shapes at the test DOFs: MAC, pairing, frequency
errors, orthogonality and cross-orthogonality (the ``paired_modes`` ... ``cross_orthogonality``
keys of ``ssidlab correlate``'s JSON, ``docs/correlation.md``).

Roles as in :mod:`ssid.correlate_models`: "test" shapes (identified model or CMIF peaks) in
rows, "analysis" shapes (the full model's modes at the test DOFs) in columns; ``M_tam`` is the
TAM mass at the test DOFs.
"""

from __future__ import annotations

import numpy as np

from .correlate import (
    CROSS_ORTHOGONALITY_DIAG_MIN,
    MAX_PAIR_FREQ_RATIO,
    ORTHOGONALITY_OFFDIAG_MAX,
    auto_mac,
    check_orthogonality,
    cross_orthogonality,
    frequency_error_percent,
    frequency_ratio,
    modal_assurance,
    modes_at_rest,
    orthogonality,
    pair_modes_by_mac,
    real_mode_from_complex,
)

__all__ = ["MIN_PAIR_MAC", "mode_correlation", "pair_rule"]

#: Pairs with a lower MAC are not paired (no counterpart).
MIN_PAIR_MAC = 0.5
# Nor are modes further apart in frequency than ssid.correlate.MAX_PAIR_FREQ_RATIO: at 16 Z
# sensors a 54.6 Hz test mode had MAC 0.54 with the 1.29 Hz analysis mode (4140 % off) and a
# mode of the test model's with omega^2 < 0 MAC 0.51 with a 2310 Hz one (QA).


def mode_correlation(phi_test: np.ndarray, f_test: np.ndarray, phi_an: np.ndarray,
                     f_an: np.ndarray, M_tam: np.ndarray) -> tuple[dict, np.ndarray, list]:
    """MAC, pairing, frequency errors, orthogonality and cross-orthogonality."""
    mac = modal_assurance(phi_test, phi_an)
    admissible, why_not = pair_rule(f_test, f_an)
    pairs = pair_modes_by_mac(np.where(admissible, mac, 0.0), MIN_PAIR_MAC)
    phi_test_r = real_mode_from_complex(phi_test)
    xo = cross_orthogonality(phi_test_r, phi_an, M_tam)
    ti = [p.test for p in pairs]
    ai = [p.analysis for p in pairs]
    xo_paired = xo[np.ix_(ti, ai)]
    ortho = orthogonality(phi_test_r, M_tam)
    ferr = frequency_error_percent(f_test[ti], f_an[ai]) if pairs else np.zeros(0)
    paired = [
        {
            "test_mode": p.test + 1,
            "analysis_mode": p.analysis + 1,
            "mac": p.mac,
            "test_freq_hz": float(f_test[p.test]),
            "analysis_freq_hz": float(f_an[p.analysis]),
            "freq_error_percent": float(e),
            "cross_orthogonality": float(xo[p.test, p.analysis]),
        }
        for p, e in zip(pairs, ferr)
    ]
    # A test mode left without a pair whose best MAC would have paired it by MAC alone: shown,
    # with the reason, so that the pair the rule refused is not silently missing.
    paired_tests = {p.test for p in pairs}
    not_paired = []
    for i in range(mac.shape[0]):
        j = int(np.argmax(mac[i])) if mac.shape[1] else 0
        if i in paired_tests or not mac.shape[1] or mac[i, j] < MIN_PAIR_MAC or admissible[i, j]:
            continue
        not_paired.append({"test_mode": i + 1, "analysis_mode": j + 1, "mac": float(mac[i, j]),
                           "test_freq_hz": float(f_test[i]), "analysis_freq_hz": float(f_an[j]),
                           "freq_error_percent": float(frequency_error_percent(f_test[i], f_an[j])),
                           "reason": why_not(i, j)})
    o_chk = check_orthogonality(ortho, diag_min=0.0)
    x_chk = check_orthogonality(xo_paired)
    if not pairs:  # nothing paired: the criterion cannot be met
        x_chk.passed = False
    summary = {
        "mac": mac,
        "auto_mac_test": auto_mac(phi_test),
        "auto_mac_analysis": auto_mac(phi_an),
        "paired_modes": paired,
        "pairing": {"min_mac": MIN_PAIR_MAC, "max_freq_ratio": MAX_PAIR_FREQ_RATIO},
        "not_paired": not_paired,
        "freq_error_percent": [float(e) for e in ferr],
        "orthogonality": {
            "matrix": ortho,
            **o_chk.to_dict(),
            "criterion": {"offdiag_max": ORTHOGONALITY_OFFDIAG_MAX},
        },
        "cross_orthogonality": {
            "matrix": xo,
            "paired_matrix": xo_paired,
            **x_chk.to_dict(),
            "criterion": {"diag_min": CROSS_ORTHOGONALITY_DIAG_MIN,
                          "offdiag_max": ORTHOGONALITY_OFFDIAG_MAX},
        },
    }
    return summary, mac, pairs


def pair_rule(f_test: np.ndarray, f_an: np.ndarray):
    """Which (test, analysis) modes may pair, and a function saying why a pair may not.

    A test mode with omega^2 < 0 (a negative frequency, :func:`ssid.correlate_models._modes`) is no mode of a
    structure and pairs with nothing, unless it is at rest to :data:`ssid.correlate.PAIR_REST_RTOL`
    (a rigid-body mode an identification put a little below zero). Two elastic modes pair only
    with frequencies within :data:`MAX_PAIR_FREQ_RATIO` of each other. A pair with a mode at
    rest on either side is decided by the MAC alone: a free-free model's rigid-body mode is
    measured as a suspension mode on soft supports (0.74 Hz on 60 N/m bungees, MAC 1.000),
    which no frequency ratio with 0 Hz admits.
    """
    rigid_t, rigid_a = modes_at_rest(f_test), modes_at_rest(f_an)
    negative = (np.asarray(f_test) < 0) & ~rigid_t
    ratio = frequency_ratio(f_test, f_an)
    ok = ~negative[:, None] & (rigid_t[:, None] | rigid_a[None, :] | (ratio * MAX_PAIR_FREQ_RATIO >= 1.0))

    def why_not(i: int, j: int) -> str:
        if negative[i]:
            return "the test mode has omega^2 < 0 (K not positive semi-definite): not a physical mode"
        return (f"frequencies a factor {1 / ratio[i, j]:.3g} apart (a pair needs {MAX_PAIR_FREQ_RATIO:g} or less): "
                "shapes alike at the sensors (spatial aliasing), not taken for the same mode")

    return ok, why_not
