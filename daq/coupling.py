"""The front end's AC/IEPE coupling, divided out of the FRF estimates.

An AC- or IEPE-coupled input passes the sensor's signal through a coupling capacitor: a
first-order high-pass, ``iw / (iw + w_c)`` in our ``e^{+iwt}`` convention, with its -3 dB
corner ``[daq] ac_corner_hz`` (0.5 Hz, the simulated front end's and a common spec). At
``f`` it leads by ``atan(f_c / f)`` and reads ``1 / sqrt(1 + (f_c / f)^2)`` of the
amplitude. An FRF between two channels of the same coupling does not see it (it cancels in
the ratio), but a DC force gauge against IEPE accelerometers did: H led by 0.72 deg at
40 Hz, 1e-2 relative, against a stated uncertainty of 7e-4, and ``ssidlab identify`` then
had M and K 7-8e-3 off. So every FRF estimate divides each channel's spectrum by its
coupling's response, which for a ratio ``H = Y X^-1`` comes to
``H_ij * r_in_j / r_out_i`` (and the variance by ``|r_in_j / r_out_i|^2``) - exact for the
stepped sine's multi-input solve and for H1, H2 and Hv alike, since each is equivariant
under a diagonal scaling of the channels. The records and spectral sums in the run file stay
as measured; the correction is applied where the FRFs are formed, so a resume forms them
the same way.

The correction is as good as the corner: a corner off by ``d f_c`` leaves ``d f_c / f``
relative at ``f`` (a 10 % error in a 0.5 Hz corner: 2.5e-3 at 20 Hz). The simulated DAQ
filters with the bilinear transform of this high-pass, which departs from it by at most
``(f_c / f) (1 - x / tan x)``, ``x = pi f / f_s``: 2e-5 at 200 Hz, 2e-4 at the 0.45 f_s
passband edge, for 0.5 Hz at 4096 S/s.
"""

from __future__ import annotations

import numpy as np

from .setup import TestSetup

__all__ = ["AC_COUPLINGS", "coupling_attrs", "coupling_response", "undo_coupling"]

#: The couplings that put the front end's high-pass in the signal path.
AC_COUPLINGS = ("AC", "IEPE")


def coupling_response(setup: TestSetup, freq_hz: np.ndarray) -> np.ndarray:
    """Each channel's coupling response at ``freq_hz``, ``(n_f, n_ch)`` complex: 1 for a DC
    channel, ``1 / (1 - i f_c / f)`` for an AC or IEPE one (channel order of the setup)."""
    f = np.atleast_1d(np.asarray(freq_hz, float))[:, None]
    ac = np.array([c.coupling in AC_COUPLINGS for c in setup.channels])[None, :]
    return np.where(ac, 1.0 / (1.0 - 1j * setup.daq.ac_corner_hz / f), 1.0 + 0j)


def undo_coupling(H: np.ndarray, var: np.ndarray, r_out: np.ndarray, r_in: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """``H`` and its variance as if every channel were DC-coupled.

    Parameters
    ----------
    H, var : (..., n_out, n_in)
        FRFs (output channel over input force) estimated from the channels as read, and their
        variances.
    r_out : (..., n_out) complex
        Coupling response of each output's channel (:func:`coupling_response`).
    r_in : (..., n_in) complex
        Coupling response of each input's force channel.

    Returns
    -------
    H, var : same shapes
        ``H * r_in / r_out`` and ``var * |r_in / r_out|^2``.
    """
    g = np.asarray(r_in)[..., None, :] / np.asarray(r_out)[..., :, None]
    return H * g, var * np.abs(g) ** 2


def coupling_attrs(setup: TestSetup) -> dict[str, object]:
    """The run file's record of the correction: root attributes ``ac_corner_hz`` and
    ``coupling_correction`` (which channels had the high-pass divided out, or none)."""
    ac = [c.name for c in setup.channels if c.coupling in AC_COUPLINGS]
    corner = setup.daq.ac_corner_hz
    what = (f"first-order high-pass at {corner:g} Hz divided out of the AC/IEPE channels "
            + ", ".join(repr(n) for n in ac)) if ac else "none: every channel DC-coupled"
    return {"ac_corner_hz": float(corner), "coupling_correction": what}
