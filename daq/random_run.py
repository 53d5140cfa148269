"""Random excitation: continuous, periodic (pseudo-) and burst random; H1, H2, Hv.

Kinds (``[random] kind``):

* ``random``: the generators' Gaussian noise (NOIS) on every shaker at once, uncorrelated
  between shakers (MIMO); a continuous record cut into Welch blocks (``window``,
  ``overlap``) after ``settle_blocks`` blocks.
* ``periodic``: per average, each shaker gets its own new random-phase multisine (flat
  spectrum over the band, one period = ``block_size`` samples at the DAQ rate) through the
  generator's arbitrary waveform; once the steady state is checked (at least
  ``settle_blocks`` periods, :func:`periodic_transient`) one period is analysed with a
  rectangular window - no leakage, so noise-free FRFs are exact.
* ``burst``: per average, a new random burst (``burst_fraction`` of the block, then zeros)
  as arbitrary waveform. Analysed in the first block, the burst's ring is cut at the block's
  end and the last average's ringing enters at its start, wherever the modes outlast the
  block (on the 14-DOF example, 2048-sample blocks: FRFs up to 25 % off with coherence
  0.96). The generator repeats its waveform, so the repeated burst is analysed as periodic
  random is: one period in checked steady state, and a response that outlasts the block
  does no harm.

Every average adds to the spectral sums (``Gxx``, ``Gyx``, ``Gyy``), which are written to
the run file and committed with the FRF view; resume continues the averaging (periodic and
burst realisations are seeded by their index, so a resumed run uses the same signals).
A limit exceeded during random excitation stops the run (the drive is ramped to zero): the
drive level of a random test is fixed, so the next average would exceed it again. Peak
limits are checked on each piece's largest sample, RMS limits on each channel's RMS over
the last ``daq.rms_limit.RMS_WINDOW_S`` of record (:class:`~daq.rms_limit.SlidingRms`). A DAQ
over-range rejects the average it fell in (a clipped sample is not data), which is
measured again (periodic and burst: the same realisation; continuous: a new record, the
blocks before the clip kept); ``MAX_OVER_RANGE_IN_ROW`` in a row stop the run.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from drivers.errors import SensorOverload
from ssid.frf import FRFData

from .control import RunControl, RunEvents, hold_if_paused, raise_if_interrupted
from .coupling import coupling_response, undo_coupling
from .estimate import SpectralSums, coarse_peaks, frf_from_spectra, frf_quality, spectra_of_blocks, window_mu2
from .rig import Rig
from .rms_limit import SlidingRms
from .safety import (
    MAX_OVER_RANGE_IN_ROW,
    RANDOM_LIMIT_STOP,
    RunStopped,
    check_limits,
    limit_usage,
    over_range_in_row,
)
from .setup import TestSetup
from .steady_state import periodic_transient, record_noise_floor
from .storage import RunFile

__all__ = ["LIMIT_CHECK_S", "RandomRun", "noise_bandwidth_hz", "random_bins"]

#: The longest stretch of drive (s) acquired before the limits are checked again.
LIMIT_CHECK_S = 0.1


def random_bins(setup: TestSetup) -> np.ndarray:
    r = setup.random
    f = np.fft.rfftfreq(r.block_size, 1.0 / setup.daq.sample_rate_hz)
    return f[(f >= r.f_min_hz) & (f <= r.f_max_hz)]


def _sums_group(n_avg: int) -> str:
    """Where the spectral sums of ``n_avg`` averages are kept: two sets, by the count's
    parity, so that an average overwrites the set before the last one. Overwritten in place,
    the last set was torn by a ``kill -9`` inside the flush (some sums with the new average,
    some without, and its count ahead of the commit counter), and the resume started again
    from no averages."""
    return f"random_{n_avg % 2}"


#: What the spectral sums in the run file are: read as a force PSD in N^2/Hz, Gxx would be off
#: by the window's noise bandwidth and the number of averages.
_SPECTRUM = ("X = rfft(w x) / sum(w) per block (w the window), an amplitude-normalised linear spectrum "
             "of the channels as read (an AC/IEPE input's high-pass not divided out) in their SI units "
             "(N, m/s^2), not a density; summed, not averaged, over n_avg blocks")
SUMS_DESCRIPTION = {
    "Gxx": f"sum of F F^H over the blocks, (n_bins, n_in, n_in), F the force channels' spectra; {_SPECTRUM}",
    "Gyx": f"sum of Y F^H over the blocks, (n_bins, n_y, n_in), Y the responses then reactions; {_SPECTRUM}",
    "Gyy": f"sum of |Y|^2 over the blocks, (n_bins, n_y); {_SPECTRUM}",
}


def _bin_mask(setup: TestSetup) -> np.ndarray:
    r = setup.random
    f = np.fft.rfftfreq(r.block_size, 1.0 / setup.daq.sample_rate_hz)
    return (f >= r.f_min_hz) & (f <= r.f_max_hz)


def noise_bandwidth_hz(setup: TestSetup) -> float:
    """The generators' noise bandwidth for continuous random: a quarter above the band, so
    the band is flat, and below the DAQ's Nyquist frequency. Drive power above the band
    would only excite what the analysis discards (and, past Nyquist, what the front end's
    anti-alias filter has to remove)."""
    return min(1.25 * setup.random.f_max_hz, 0.5 * setup.daq.sample_rate_hz)


def multisine(n: int, band: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One period of a random-phase multisine with flat amplitude on the bins ``band``."""
    spec = np.zeros(n // 2 + 1, complex)
    spec[band] = np.exp(2j * np.pi * rng.random(int(band.sum())))
    x = np.fft.irfft(spec, n)
    return x / np.max(np.abs(x))


class RandomRun:
    """One random run (new or resumed) on ``rig``, stored in ``runfile``."""

    def __init__(self, setup: TestSetup, rig: Rig, runfile: RunFile, echo: Callable[[str], None] = print,
                 control: RunControl | None = None, events: RunEvents | None = None) -> None:
        self.setup, self.rig, self.rf, self.echo = setup, rig, runfile, echo
        self.control, self.events = control, events or RunEvents()
        self.peaks: np.ndarray | None = None  # largest |sample| per channel since the last commit
        # The RMS limits' estimate (daq.rms_limit.RMS_WINDOW_S says why its window), and its
        # largest value per channel since the last commit, for the limit_use event.
        self.rms_window = SlidingRms(len(setup.channels), setup.daq.sample_rate_hz)
        self.rms_max: np.ndarray | None = None
        self.spec = setup.random
        roles = setup.roles()
        self.fi = roles["force"]
        self.yi = roles["response"] + roles["reaction"]
        self.n_out = len(roles["response"])
        self.roles = roles
        self.mask = _bin_mask(setup)
        self.freq = random_bins(setup)
        self.coupling = coupling_response(setup, self.freq)  # (n_bins, n_ch)
        n_in, n_y = len(self.fi), len(self.yi)
        # The sums after the last committed average: in the set of its parity (files from
        # before the two sets: in /acq/random).
        saved = runfile.read_arrays(_sums_group(runfile.n_done)) or runfile.read_arrays("random")
        # Periodic or burst averages in the sums analysed before their transient had died
        # out; stored with the sums, so a resumed run's summary counts the whole run.
        self.unsettled = 0
        self.over_range_in_row = 0  # averages rejected for a DAQ over-range, one after another
        if saved and int(saved["n_avg"]) == runfile.n_done and runfile.n_done > 0:
            self.S = SpectralSums(saved["Gxx"], saved["Gyx"], saved["Gyy"], None, int(saved["n_avg"]))
            self.unsettled = int(saved.get("unsettled_averages", 0))
            echo(f"resuming: {self.S.n_avg} averages on file")
        else:
            self.S = SpectralSums.empty(self.freq.size, n_in, n_y)
        self.test_time_s = float(saved.get("test_time_s", 0.0)) if saved else 0.0
        self.noise_var: np.ndarray | None = None

    # ------------------------------------------------------------------ acquisition
    def _acquire(self, n: int) -> np.ndarray:
        """``n`` scans of one unbroken record, read in pieces of at most
        :data:`LIMIT_CHECK_S` with the limits checked on each: taken whole, a settling record
        of two 8192-sample blocks drove the structure 4 s, 1.8 times over an acceleration limit
        for the last 3.9 of them, before the check saw it."""
        self.rig.line_check()
        step = max(1, int(LIMIT_CHECK_S * self.rig.fs_hz))
        return np.hstack([self._acquire_checked(min(step, n - k)) for k in range(0, n, step)])

    def _acquire_checked(self, n: int) -> np.ndarray:
        raise_if_interrupted()
        try:
            data = self.rig.acquire(n)
        finally:
            self.test_time_s += n / self.rig.fs_hz  # clipped scans were test time too
        peaks = np.max(np.abs(data), axis=1)
        self.peaks = peaks if self.peaks is None else np.maximum(self.peaks, peaks)
        rms = self.rms_window.add(data)
        self.rms_max = rms if self.rms_max is None else np.maximum(self.rms_max, rms)
        reason = check_limits(self.setup.limits, peaks, self.roles, self.spec.drive_vpp, self.rig.names, rms=rms)
        if reason:
            for j in range(len(self.fi)):
                self.rig.drive_off(j)
            raise RunStopped(f"{RANDOM_LIMIT_STOP}: {reason}")
        return data

    def _settle_periodic(self, n: int) -> np.ndarray:
        """Periods of the new multisine until the last one is in steady state; returns its
        spectrum (n_ch, n_band_bins), rect window.

        At least ``settle_blocks`` periods before it; then, with ``accuracy`` > 0, periods
        until :func:`periodic_transient` finds the transient below the accuracy asked (or
        the noise), for at most ``max_settle_s``. A fixed count cannot suit every structure:
        on the payload on its stand the 1-6 Hz suspension modes ring for seconds after each
        change, and two periods of 0.5 s left FRFs up to 16 % off at 60-100 Hz.
        """
        r = self.spec
        if r.accuracy <= 0:
            return self._spectra([self._acquire((r.settle_blocks + 1) * n)[:, -n:]], "rect")[0]
        if r.settle_blocks > 2:
            self._acquire((r.settle_blocks - 2) * n)
        groups = [g for g in (self.fi, self.roles["response"], self.roles["reaction"]) if g]
        spectra, t_start = [], self.test_time_s
        while True:
            spectra = [*spectra[-3:], self._spectra([self._acquire(n)], "rect")[0]]
            # Half the accuracy to each group: a line's FRF is a ratio of response to force
            # and carries both their errors.
            left = periodic_transient(spectra, n, self.noise_var, groups, r.accuracy / 2)
            if left <= 1.0:
                return spectra[-1]
            if self.test_time_s - t_start >= r.max_settle_s:
                self.unsettled += 1
                self.echo(f"  average {self.S.n_avg + 1}: not in steady state after {r.max_settle_s:g} s "
                          f"(transient {left:.3g} times what the accuracy allows; raise max_settle_s)")
                return spectra[-1]

    def _unclipped(self, acquire: Callable[[], np.ndarray]) -> np.ndarray | None:
        """``acquire()``'s data, or None when it met a DAQ over-range: the average is then
        measured again, unless too many in a row (raised). The one place that counts them."""
        try:
            data = acquire()
        except SensorOverload as fault:
            self.over_range_in_row += 1
            if self.over_range_in_row >= MAX_OVER_RANGE_IN_ROW:
                raise over_range_in_row(fault, self.over_range_in_row, "averages")
            self.echo(f"  average {self.S.n_avg + 1}: {fault}: rejected, measured again")
            return None
        self.over_range_in_row = 0
        return data

    def _spectra(self, blocks: list[np.ndarray], window: str) -> np.ndarray:
        """Spectra of ``blocks`` at the band's bins, (n_blocks, n_ch, n_band_bins)."""
        return spectra_of_blocks(blocks, window)[:, :, self.mask]

    def _add(self, X: np.ndarray) -> None:
        """Add spectra (n_blocks, n_ch, n_band_bins) to the sums and commit."""
        self.S.add(X[:, self.fi], X[:, self.yi])
        self._commit()

    def _commit(self) -> None:
        d = self.result()
        self.rf.write_arrays(_sums_group(self.S.n_avg), {"Gxx": self.S.Gxx, "Gyx": self.S.Gyx, "Gyy": self.S.Gyy,
                                        "n_avg": np.int64(self.S.n_avg), "test_time_s": self.test_time_s,
                                        "unsettled_averages": np.int64(self.unsettled)}, SUMS_DESCRIPTION)
        self.rf.write_view(d["H"], d["var"], d["coherence"], d["valid"], d.get("Hr"), d.get("Hr_var"),
                           n_avg=self.S.n_avg)
        self.rf.commit(self.S.n_avg)
        # With no more averages than shakers the coherence is 1 whatever the data.
        coh = (f"min coherence {np.min(d['coherence']):.3f}" if self.S.n_avg > len(self.fi)
               else f"coherence after {len(self.fi) + 1} averages")
        self.echo(f"  average {self.S.n_avg}/{self.spec.averages}  {coh}  [{self.test_time_s:.1f} s test time]")
        if self.events:
            self._spectrum_event(d)
        self.peaks = self.rms_max = None

    #: At most this many bins go into a ``spectrum`` event (a terminal plot has fewer columns).
    EVENT_BINS = 400

    def _spectrum_event(self, d: dict) -> None:
        step = max(1, int(np.ceil(self.freq.size / self.EVENT_BINS)))
        lim = {} if self.peaks is None else limit_usage(self.setup.limits, self.peaks, self.roles,
                                                        self.spec.drive_vpp, rms=self.rms_max)
        self.events.emit("spectrum", n_avg=int(self.S.n_avg), averages=int(self.spec.averages),
                         freq_hz=self.freq[::step], H_abs=np.where(d["valid"], np.abs(d["H"]), np.nan)[::step],
                         coherence=d["coherence"][::step], limit_use=lim, test_time_s=self.test_time_s,
                         instruments=self.rig.status())

    def _hold(self) -> bool:
        """Pause point between averages (see :mod:`daq.control`); True if the run was held."""
        return hold_if_paused(self.control, self.rig, self.rf, self.echo, self.events,
                              f"after average {self.S.n_avg}/{self.spec.averages}")

    def run(self) -> dict:
        r, n = self.spec, self.spec.block_size
        n_sh = len(self.fi)
        if r.kind == "random":
            hop = max(1, int(round(n * (1 - r.overlap))))

            def settled_first_block() -> np.ndarray:
                if r.settle_blocks:
                    self._acquire(r.settle_blocks * n)
                return self._acquire(n)

            def start() -> tuple[np.ndarray, list[np.ndarray]]:
                # Drive on, settle, first block: at the start, after a pause and after an
                # over-range (the overlapped blocks must come from one unbroken record).
                while True:
                    for j in range(n_sh):
                        self.rig.noise(j, r.drive_vpp, noise_bandwidth_hz(self.setup))
                    first = self._unclipped(settled_first_block)
                    if first is not None:
                        return first, [first]

            self._hold()
            buf, blocks = start()
            while self.S.n_avg + len(blocks) < r.averages:
                new = self._unclipped(lambda: self._acquire(hop))
                if new is None:
                    if blocks:  # from before the clip
                        self._add(self._spectra(blocks, r.window))
                    buf, blocks = start()
                    continue
                buf = np.hstack([buf, new])[:, -n:]
                blocks.append(buf)
                if len(blocks) >= 4:  # commit in small groups: few flushes, little at risk
                    self._add(self._spectra(blocks, r.window))
                    blocks = []
                    if self.S.n_avg < r.averages and self._hold():
                        buf, blocks = start()
            if blocks:
                self._add(self._spectra(blocks, r.window))
        else:
            if r.accuracy > 0:
                # What a period's difference may hold without being transient.
                self.noise_var, took_s = record_noise_floor(self.rig, self.setup.channels, self.rf)
                self.test_time_s += took_s
            while self.S.n_avg < r.averages:
                self._hold()
                a = self.S.n_avg
                for j in range(n_sh):
                    rng = np.random.default_rng([r.seed, a, j])
                    if r.kind == "periodic":
                        x = multisine(n, self.mask, rng)
                    else:
                        x = np.zeros(n)
                        nb = int(r.burst_fraction * n)
                        x[:nb] = rng.standard_normal(nb)
                    self.rig.arb(j, x, r.drive_vpp)
                X = self._unclipped(lambda: self._settle_periodic(n))
                if X is None:
                    continue
                self._add(X[None])
        for j in range(n_sh):
            self.rig.drive_off(j)
        return self.summary()

    # ------------------------------------------------------------------ results
    def result(self) -> dict:
        est = self.spec.estimator
        # Continuous random leaks (its resolution bias is stated in var); periodic and burst
        # random are analysed in steady state, periodic in the block, and do not.
        mu2 = window_mu2(self.spec.window, self.spec.block_size) if self.spec.kind == "random" else 0.0
        d = frf_from_spectra(self.S, est, mu2=mu2)
        # The sums hold the channels as read; the AC/IEPE high-pass is divided out here.
        d["H"], d["var"] = undo_coupling(d["H"], d["var"], self.coupling[:, self.yi], self.coupling[:, self.fi])
        no = self.n_out
        # Blanked below min_coherence in coherence, and in quality as a stepped-sine value is:
        # with several shakers a good multiple coherence can hide a value its variance says is
        # poor (forces alike at a line leave Gxx nearly singular; the 3-DOF QA system's
        # H(3+Z,1+Z) at 114 Hz was kept 75-190 % off at coherence 0.97). With one shaker the
        # quality is never below the coherence (H1), so nothing more is blanked there.
        min_coh = self.setup.min_coherence
        valid = (d["coherence"][:, :no] >= min_coh) & np.isfinite(d["H"][:, :no])
        valid &= frf_quality(d["H"][:, :no], d["var"][:, :no]) >= min_coh
        valid &= self.S.n_avg > len(self.fi)
        out = {"H": d["H"][:, :no], "var": d["var"][:, :no], "coherence": d["coherence"][:, :no], "valid": valid}
        # Peaks of continuous random narrower than ~3.5 lines: their first-order bias in var
        # understates the resolution bias (the run's summary says so).
        out["coarse_hz"] = (self.freq[coarse_peaks(d["H"][:, :no], d["var_random"][:, :no])]
                            if mu2 > 0 and self.S.n_avg > len(self.fi) else self.freq[:0])
        if self.roles["reaction"]:
            out["Hr"] = d["H"][:, no:]
            out["Hr_var"] = d["var"][:, no:]
        return out

    def frf(self) -> FRFData:
        d = self.result()
        s = self.setup
        frf = FRFData(freq_hz=self.freq, H=np.where(d["valid"], d["H"], np.nan), outputs=s.outputs,
                      inputs=s.inputs, coherence=np.clip(d["coherence"], 0, 1), valid=d["valid"],
                      H_var=np.nan_to_num(d["var"]), n_avg=int(self.S.n_avg))
        if s.reactions:
            frf.H_reaction = np.nan_to_num(d["Hr"])
            frf.H_reaction_var = np.nan_to_num(d["Hr_var"])
            frf.reactions = s.reactions
        return frf

    def summary(self) -> dict:
        d = self.result()
        if d["coarse_hz"].size:
            self.echo(f"warning: mode peak(s) at {', '.join(f'{f:g}' for f in d['coarse_hz'])} Hz narrower than "
                      f"~3.5 lines ({self.freq[1] - self.freq[0]:g} Hz): the {self.spec.window} window's resolution "
                      f"bias there is stated in H_var only to first order; a longer block_size resolves them")
        return {"excitation": f"random ({self.spec.kind}, {self.spec.estimator})", "n_lines": int(self.freq.size),
                "n_avg": int(self.S.n_avg), "n_values_blanked": int(np.count_nonzero(~d["valid"])),
                "n_values": int(d["valid"].size),
                "test_time_s": self.test_time_s, "min_coherence": float(np.min(d["coherence"])),
                **({"unsettled_averages": self.unsettled} if self.spec.kind != "random" else {}),
                **({"coarse_resolution_peaks_hz": [float(f) for f in d["coarse_hz"]]} if d["coarse_hz"].size else {})}
