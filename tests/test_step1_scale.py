"""Step 1 on accelerances of any magnitude the readers accept (``ssid.identify.identify_step1``).

``ssidlab bands`` on a record whose |H| was ~1e-90 warned "overflow encountered in square" (the
output error of a start, squared weighted residuals) and found 14 of the 15 modes it finds on
the same record at |H| ~ 1: the report's TLS start is not invariant to the scale of H beside
the unit columns of D. Step 1 now fits data far from 1 divided by a power of two near their
largest |H|, and scales ``M^-1 D`` back. Each case takes a record whose largest |H| is within
a factor sqrt(2) of 1 (divided by a power of two, exactly) and the same record times 2^+-300.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
from conftest import chain_frf

from ssid.bands import band_layout, process_bands
from ssid.frf import FRFData
from ssid.identify import identify_mck
from ssid.noise import report_noise_frf
from ssid.solvers import power_of_two_near


def _times(frf: FRFData, factor: float) -> FRFData:
    """``frf`` with H multiplied by ``factor`` (its variances by ``factor**2``)."""
    var = None if frf.H_var is None else frf.H_var * factor**2
    return dataclasses.replace(frf, H=frf.H * factor, H_var=var)


def _near_one(frf: FRFData) -> FRFData:
    return _times(frf, 1.0 / power_of_two_near(float(np.nanmax(np.abs(frf.H)))))


@pytest.mark.parametrize("exponent", [-300, 300])
def test_identify_far_from_unit_scale_is_identify_at_unit_scale_exactly(exponent):
    """The 3-DOF chain under the report's noise (seed 1): step 1 fits the same numbers, so the
    roots are the same to the last bit, and M, C, K are those at unit scale divided by
    2^exponent to 1e-10 (measured 3.7e-12: step 2 and the damping choice work on the data as
    they are, where sums of squares near float64's ends round differently). It held before
    the scaling too: it guards that the scaling keeps ``identify`` exact."""
    near = _near_one(report_noise_frf(chain_frf(), seed=1))
    factor = 2.0**exponent
    with np.errstate(over="raise", invalid="raise"):
        far = identify_mck(_times(near, factor))
    ref = identify_mck(near)
    np.testing.assert_array_equal(far.natural_freq_hz, ref.natural_freq_hz)
    np.testing.assert_array_equal(far.damping_ratio, ref.damping_ratio)
    for name in ("M", "C", "K"):
        np.testing.assert_allclose(getattr(far, name) * factor, getattr(ref, name), rtol=1e-10, err_msg=name)


def test_band_processing_at_1e_minus_90_finds_the_mode_found_at_unit_scale():
    """The demo's bundled example (14 DOF, 3 shakers, the report's noise model) in the two
    bands that hold its 381.6 Hz mode: at |H| ~ 1e-90 (2^-300) that mode was lost, with an
    overflow warning. It is found at 2^-300 as at unit scale, without a floating-point warning,
    its frequency within 1e-5 (measured 7.8e-7: a band's own largest |H| sets its power of
    two, so a band is fitted at a scale a power of two off the unit-scale run's, and the TLS
    start moves by rounding)."""
    from ssidlab.demo import example_frf

    near = _near_one(example_frf()[0])
    bands = [b for b in band_layout(near, None, 0.5)[0] if b[0] < 381.6 < b[1]]
    assert len(bands) == 2
    ref = [r.freq_hz for r in process_bands(near, bands).representatives()]
    assert len(ref) == 1 and ref[0] == pytest.approx(381.6, abs=0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with np.errstate(over="raise", invalid="raise"):
            far = [r.freq_hz for r in process_bands(_times(near, 2.0**-300), bands).representatives()]
    assert len(far) == 1 and far[0] == pytest.approx(ref[0], rel=1e-5)
