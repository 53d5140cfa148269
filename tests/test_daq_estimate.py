"""Estimators: harmonic fit, multi-input solve, spectral H1/H2/Hv and coherence, transient monitor."""

from __future__ import annotations

import numpy as np

from daq.estimate import SineFit, SpectralSums, frf_from_spectra, multi_input_frf
from daq.schedule import frequency_grid, sweep_plan
from daq.steady_state import TransientMonitor, geometric_tail_gain, multipole_transient


def test_sine_fit_amplitude_harmonics_drift_and_start():
    fs, f, n = 4096.0, 37.3, 3000
    t = (500 + np.arange(n)) / fs  # the record starts 500 samples after the line's origin
    X = np.array([1.5 - 0.5j, 0.02 + 0.3j])
    x = np.real(X[:, None] * np.exp(2j * np.pi * f * t)) + 0.1 + 0.05 * t  # offset and drift
    x[0] += 0.01 * np.cos(2 * 2 * np.pi * f * t)  # 2nd harmonic on channel 0
    est = SineFit(f, fs, n).fit(x, start=500)
    np.testing.assert_allclose(est.X, X, rtol=1e-9, atol=1e-12)
    assert abs(est.thd[0] - 0.01 / abs(X[0])) < 1e-9
    noise = np.random.default_rng(0).normal(0, 0.01, (2000, 2, n))
    Xs = np.array([SineFit(f, fs, n).fit(x + e, start=500).X for e in noise[:200]])
    var_pred = SineFit(f, fs, n).fit(x + noise[0], start=500, noise_var=np.full(2, 1e-4)).var
    np.testing.assert_allclose(np.mean(np.abs(Xs - X) ** 2, axis=0), var_pred, rtol=0.25)


def test_sine_fit_counts_only_harmonics_inside_the_daq_passband():
    """A line at 700 Hz at 4096 S/s: its 2nd harmonic (1400 Hz) lies inside a 0.45 fs
    passband (1843 Hz), its 3rd (2100 Hz) beyond Nyquist. With the passband at 0.3 fs
    (1229 Hz) the 2nd is beyond it too, where a front end's filter would have attenuated it,
    so it is not fitted and the distortion reads zero rather than a wrong value."""
    fs, f, n = 4096.0, 700.0, 4096
    t = np.arange(n) / fs
    x = (np.cos(2 * np.pi * f * t) + 0.02 * np.cos(2 * np.pi * 2 * f * t))[None, :]
    assert SineFit(f, fs, n, band_hz=0.45 * fs).h == [1, 2]
    assert abs(SineFit(f, fs, n, band_hz=0.45 * fs).fit(x, start=0).thd[0] - 0.02) < 1e-9
    fit = SineFit(f, fs, n, band_hz=0.3 * fs)
    assert fit.h == [1] and fit.fit(x, start=0).thd[0] == 0.0


def test_multi_input_frf_exact_and_variance():
    rng = np.random.default_rng(1)
    H = rng.normal(size=(5, 2)) + 1j * rng.normal(size=(5, 2))
    XF = rng.normal(size=(2, 2)) + 1j * rng.normal(size=(2, 2))  # arbitrary phase per pattern
    Hs, var = multi_input_frf(H @ XF, XF, np.zeros((5, 2)), np.zeros((2, 2)))
    np.testing.assert_allclose(Hs, H, rtol=1e-12)
    assert np.all(var == 0)
    s = 1e-3
    draws = [multi_input_frf(H @ XF + s * (rng.normal(size=(5, 2)) + 1j * rng.normal(size=(5, 2))) / np.sqrt(2),
                             XF, np.full((5, 2), s**2), np.zeros((2, 2))) for _ in range(3000)]
    emp = np.mean([np.abs(d[0] - H) ** 2 for d in draws], axis=0)
    np.testing.assert_allclose(emp, draws[0][1], rtol=0.15)


def test_h1_h2_hv_and_coherence_mimo():
    rng = np.random.default_rng(2)
    nf, na, n_in, n_y = 4, 4000, 2, 3
    H = rng.normal(size=(nf, n_y, n_in)) + 1j * rng.normal(size=(nf, n_y, n_in))
    Xf = rng.normal(size=(na, n_in, nf)) + 1j * rng.normal(size=(na, n_in, nf))
    Xy = np.einsum("fyi,aif->ayf", H, Xf)
    S = SpectralSums.empty(nf, n_in, n_y)
    S.add(Xf, Xy)
    for est in ("H1", "Hv"):
        d = frf_from_spectra(S, est)
        np.testing.assert_allclose(d["H"], H, rtol=1e-8)
        np.testing.assert_allclose(d["coherence"], 1.0, atol=1e-9)
    noise = 0.3 * (rng.normal(size=Xy.shape) + 1j * rng.normal(size=Xy.shape))
    S2 = SpectralSums.empty(nf, n_in, n_y)
    S2.add(Xf, Xy + noise)
    d = frf_from_spectra(S2, "H1")
    err2 = np.abs(d["H"] - H) ** 2
    assert 0.6 < np.mean(err2 / d["var"]) < 1.6  # the variance the averages predict
    assert np.all(d["coherence"] < 1) and np.all(d["coherence"] > 0.8)
    S1 = SpectralSums.empty(nf, 1, n_y)
    S1.add(Xf[:, :1], np.einsum("fy,af->ayf", H[:, :, 0], Xf[:, 0]))
    np.testing.assert_allclose(frf_from_spectra(S1, "H2")["H"][:, :, 0], H[:, :, 0], rtol=1e-8)


def test_transient_monitor_stops_when_the_geometric_tail_is_small():
    rng = np.random.default_rng(3)
    y_true = rng.normal(size=8) + 1j * rng.normal(size=8)
    e0 = 0.5 * (rng.normal(size=8) + 1j * rng.normal(size=8))
    q = 0.9 * np.exp(0.3j)
    mon = TransientMonitor(1e-3, floor=0.5, prior=0.5)
    k = 0
    while True:
        mon.update(y_true + e0 * q**k, noise=0.0)
        if mon.settled():
            break
        k += 1
    err = np.linalg.norm(e0 * q**k) / np.linalg.norm(y_true)
    assert err <= 1e-3  # stopped only once the true error is below the accuracy
    assert err > 1e-4  # but not much later (about one step per factor 0.9)


def test_multipole_fit_reads_the_error_of_three_close_modes_ringing_together():
    """Three lightly damped modes ringing at once (poles 0.97-0.985, turning 0.05-0.4 rad a
    window step: close modes just off the drive) each with its own shape over 12 channels.
    One decay rate for them all gets their sum's remaining error wrong; the shared-pole fit
    gives it per channel. Noise-free, the fit of order 3 is exact, so the estimate (the
    largest over spans and orders) is at least the truth on every channel; the fits of
    lower order, which cannot hold three modes, raise some channels (here the norm by 6 %).
    With noise alone (std 1e-6 per entry) nothing is read as a transient."""
    rng = np.random.default_rng(5)
    n = 12
    z = np.array([0.985 * np.exp(0.05j), 0.97 * np.exp(-0.2j), 0.98 * np.exp(0.4j)])
    c = rng.normal(size=(3, n)) + 1j * rng.normal(size=(3, n))
    y_inf = rng.normal(size=n) + 1j * rng.normal(size=n)
    k = np.arange(41)
    ys = y_inf + np.einsum("km,mn->kn", z[None, :] ** k[:, None], c)
    true = np.abs(ys[-1] - y_inf)
    est = multipole_transient(ys, d_noise=1e-9)
    assert np.all(est >= true * (1 - 1e-9))
    assert np.linalg.norm(est) < 1.1 * np.linalg.norm(true)
    noise = 1e-6 * (rng.normal(size=(41, n)) + 1j * rng.normal(size=(41, n))) / np.sqrt(2)
    est_noise = multipole_transient(y_inf + noise, d_noise=1e-6 * np.sqrt(2 * n))
    assert est_noise is not None and np.linalg.norm(est_noise) < 1e-6 * np.sqrt(n)
    assert multipole_transient(ys[:3], d_noise=0.0) is None  # two differences: no fit
    ys[7, 2] = np.inf  # a force of exactly zero in one window
    assert multipole_transient(ys, d_noise=0.0) is None


#: Settling windows recorded in the simulated lab (responses per unit force, one scale, 3
#: accelerometers): a 3-DOF structure with a 0.5 %-damped mode at 50 Hz, driven at 50.000 Hz
#: by one shaker at 4096 samples/s; y_0 and the 16 differences D_k = y_k - y_(k-1), 4 digits.
RESONANCE_Y0 = np.array([0.015090 + 0.660378j, -0.010343 - 0.150980j, -0.041765 - 0.734184j])
RESONANCE_D = np.array([
    [0.03993+0.4603j, -0.00894-0.1042j, -0.04374-0.508j],
    [0.001573+0.354j, -0.0003515-0.08007j, -0.001718-0.3905j],
    [-0.02418+0.1859j, 0.005474-0.04204j, 0.02669-0.2051j],
    [-0.02147+0.07771j, 0.004857-0.01757j, 0.02369-0.08571j],
    [-0.01229+0.02905j, 0.00278-0.00657j, 0.01356-0.03204j],
    [-0.005933+0.01032j, 0.001341-0.002334j, 0.006544-0.01138j],
    [-0.002639+0.003553j, 0.0005966-0.0008036j, 0.00291-0.003921j],
    [-0.001117+0.001194j, 0.0002531-0.0002701j, 0.001232-0.001318j],
    [-0.0004674+0.0004057j, 0.0001059-9.191e-05j, 0.0005154-0.0004473j],
    [-0.0001888+0.0001325j, 4.17e-05-3.019e-05j, 0.0002089-0.0001458j],
    [-6.612e-05+2.971e-05j, 1.456e-05-6.858e-06j, 7.369e-05-3.311e-05j],
    [-1.654e-05+2.629e-06j, 4.011e-06-1.36e-07j, 1.788e-05-3.949e-06j],
    [1.31e-06+2.517e-07j, -3.584e-07+5.126e-08j, -2.902e-06+1.498e-07j],
    [-1.304e-05-6.934e-06j, 2.963e-06+1.009e-06j, 1.46e-05+8.586e-06j],
    [-2.705e-05+2.686e-07j, 6.261e-06-3.102e-07j, 3.076e-05-8.631e-07j],
    [-8.849e-06+1.595e-05j, 2.129e-06-3.908e-06j, 9.64e-06-1.764e-05j],
])
RESONANCE_D_NOISE = 1.632e-5  # the noise of one difference (TransientMonitor.d_noise)
#: decay per window step of the lightest damping expected there (damping_guess 0.01)
RESONANCE_FLOOR = 0.882


def _resonance_monitor(y0, D, d_noise) -> TransientMonitor:
    mon = TransientMonitor(1e-3, floor=RESONANCE_FLOOR, prior=RESONANCE_FLOOR)
    for y in y0 + np.vstack([np.zeros(len(y0)), np.cumsum(D, axis=0)]):
        mon.update(y, d_noise / np.sqrt(2.0 / 4))  # (TransientMonitor's d_noise from the noise)
    assert mon.settled()
    return mon


def test_a_fit_predicting_a_tail_the_windows_do_not_show_is_not_used():
    """At resonance the differences shrink by about 0.37 a window step into the noise (the
    last three at 0.1-1.7 of it). A single pole fitted to 16 of them is held at 0.65 by the
    large early ones and predicts a latest difference of 1e-3, which the windows do not
    show; extrapolated, it put the remaining error at 120 times the noise of a difference.
    The line's error against the exact accelerance was 1.2e-5 of its size: about 2 of those
    noises. Fits that do not account for the latest differences are not used."""
    ys = RESONANCE_Y0 + np.vstack([np.zeros(3), np.cumsum(RESONANCE_D, axis=0)])
    e = multipole_transient(ys, RESONANCE_D_NOISE)
    assert np.linalg.norm(e) < 3 * RESONANCE_D_NOISE, np.linalg.norm(e) / RESONANCE_D_NOISE
    stated = _resonance_monitor(RESONANCE_Y0, RESONANCE_D, RESONANCE_D_NOISE).stated_error()
    assert 2 * RESONANCE_D_NOISE < stated < 10 * RESONANCE_D_NOISE, stated / RESONANCE_D_NOISE


def test_a_transient_decayed_into_the_noise_is_stated_as_what_the_noise_can_hide():
    """The same 50 Hz line, measured with a second shaker attached (its differences shrink by
    0.15 a step; the last two at the noise). No fit sees a pole above the noise any more, and
    the single-decay bound, which carries the slowest decay believed back to the last visible
    difference, stood at 88 times the noise of a difference. What is stated is what a mode of
    that slowest decay could still hide below the noise: the noise times its tail gain."""
    y0 = np.array([0.043475 - 0.620286j, -0.078321 + 0.141677j, -0.335448 + 0.68893j])
    D = np.array([
        [-0.007264 - 0.03098j, 0.0001332 + 0.007624j, 0.002605 + 0.03663j],
        [-0.001124 - 0.004593j, 2.192e-05 + 0.001138j, 0.0003834 + 0.005479j],
        [-0.0001733 - 0.0006517j, 4.086e-06 + 0.0001594j, 7.301e-05 + 0.0007843j],
        [-2.226e-05 - 9.758e-05j, -7.049e-07 + 1.578e-05j, 1.208e-05 + 0.0001143j],
        [-5.281e-07 - 1.867e-05j, -5.666e-07 + 4.372e-06j, 2.898e-06 + 2.15e-05j],
        [-1.21e-07 - 2.726e-06j, -4.874e-07 + 4.258e-06j, -1.167e-06 + 6.718e-06j],
        [-1.463e-06 + 2.197e-06j, -2.236e-06 - 1.47e-06j, -3.671e-06 - 2.735e-08j]])
    d_noise = 7.90e-6
    mon = _resonance_monitor(y0, D, d_noise)
    assert mon.ehat > 50 * d_noise  # the settling bound
    hidden = d_noise * geometric_tail_gain(RESONANCE_FLOOR, 0.0)
    np.testing.assert_allclose(mon.stated_error(), hidden, rtol=1e-9)


def test_a_transient_sunk_into_the_noise_is_still_stated():
    """Two modes ringing (poles 0.85 and 0.93, turning) decay into noise that is larger than
    the accuracy asked (a noise-limited line; windows overlap by 3/4, so their noise is
    correlated). When the line stops, the last differences are noise: the multi-pole fit sees
    no pole, and the transient left (up to twice the noise level here) must still be stated
    from the single-decay bound, not as zero."""
    rng = np.random.default_rng(1)
    n, sig = 20, 1e-4
    ratios = []
    for _ in range(40):
        y_inf = 0.05 * (rng.normal(size=n) + 1j * rng.normal(size=n))
        c = 0.05 * (rng.normal(size=(2, n)) + 1j * rng.normal(size=(2, n)))
        q = np.array([0.85 * np.exp(0.7j), 0.93 * np.exp(-0.3j)])
        w = sig / np.sqrt(2) * (rng.normal(size=(400, n)) + 1j * rng.normal(size=(400, n)))
        mon = TransientMonitor(1e-3, floor=0.8, prior=0.8)
        for k in range(396):
            tr = (q[:, None] ** k * c).sum(axis=0)
            mon.update(y_inf + tr + w[k:k + 4].sum(axis=0) / 2, sig * np.sqrt(n))
            if mon.settled():
                break
        ratios.append(mon.stated_error() / np.linalg.norm(tr))
    assert np.median(ratios) > 1, np.median(ratios)


def test_schedule_refines_near_a_resonance_and_covers_every_shaker():
    grid = frequency_grid(10, 100, 10, "log", 8)
    assert grid.size == 73 and np.all(np.diff(grid) > 0)
    fr = 31.0

    def measure(p, k):
        f = grid[k]
        h = 1 / (fr**2 - f**2 + 2j * 0.01 * fr * f)
        return np.array([h, 0.5 * h + 1e-4 * (1 + p)])

    done = sweep_plan(measure, 2, grid.size, 8, 0.25)
    lines0 = sorted(done[0])
    assert set(done[0]) == set(done[1])  # every line has a sub-line per shaker
    near = [k for k in lines0 if abs(grid[k] / fr - 1) < 0.05]
    steps = np.diff(lines0)
    assert len(near) >= 3 and steps[np.searchsorted(lines0, near[0])] == 1  # every grid line at the peak
    assert steps[0] == 8 and max(steps[-4:]) >= 3 and len(lines0) < grid.size / 2  # coarse far from it


def test_what_the_noise_can_hide_decays_as_slowly_as_the_transient_seen():
    """A transient decaying 0.95 a window step (a mode lighter than the ``damping_guess``,
    whose decay would be 0.6) until its differences sink below the noise: what is left is
    about 19 times the last difference. Stated as what a mode of the guessed decay could hide
    (1.5 times the noise of a difference), it was 10 times low (z 3.9 on the QA's weak system
    with a guess of 5 %); the decay the bound assumes (the envelope's, here 0.95) is used."""
    rng = np.random.default_rng(3)
    y_inf = rng.normal(size=4) + 1j * rng.normal(size=4)
    c = 1e-3 * (rng.normal(size=4) + 1j * rng.normal(size=4))
    q = 0.95
    k_stop = int(np.ceil(np.log(0.8 * 1e-5 / (np.linalg.norm(c) * (1 - q))) / np.log(q)))
    noise = 1e-5 / np.sqrt(2.0 / 4)  # the noise of a window; a difference's is 1e-5
    mon = TransientMonitor(1e-3, floor=0.6, prior=0.6)
    for k in range(k_stop + 1):
        mon.update(y_inf + c * q**k, noise)
    mon.conclude()
    last_d = np.linalg.norm(c) * q ** (k_stop - 1) * (1 - q)
    assert last_d < mon.d_noise  # sunk into the noise
    left = np.linalg.norm(c) * q**k_stop
    assert mon.stated_error() >= 0.9 * left, (mon.stated_error() / left, mon.r)


def test_a_slow_decay_one_entry_shows_overrides_a_heavy_damping_guess():
    """A line between two modes of 0.5 % damping measured with ``damping_guess`` 0.05 (decay
    0.53 a step where the lighter mode's is 0.95): the transient of the farther mode (0.27 a
    step, turning half a cycle) fills the norm of y, the slower one shows in the entry near a
    node of the forced response (the QA's weak 3-DOF system at 63.75 Hz, H(2+Z,1+Z) at
    0.027 of the line's largest). Its differences there shrink by 0.7 a step, not 0.27; read
    by the norm alone, the line stopped after 3 differences and stated that entry's error 7
    to 13 times low (z 5.8 in the simulated run). A decay one entry shows above the noise
    keeps the line until the multi-pole fit separates the two."""
    ratios = []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        y_inf = np.array([0.242 + 0.005j, 0.0027 + 0.0004j, 0.099 + 0.0015j])
        fast = 1.6e-3 * np.array([1.0, 0.04, 0.33]) * np.exp(1j * rng.uniform(0, 2 * np.pi, 3))
        slow = np.array([0, 1.3e-5, 0]) * np.exp(1j * rng.uniform(0, 2 * np.pi))
        q_fast, q_slow = 0.27 * np.exp(3.1j), 0.95 * np.exp(2.7j)
        sig = 2e-6  # window noise per entry (windows overlap by 3/4)
        w = sig / np.sqrt(2) * (rng.normal(size=(200, 3)) + 1j * rng.normal(size=(200, 3)))
        mon = TransientMonitor(1e-3, floor=0.532, prior=0.532)
        for k in range(196):
            tr = fast * q_fast**k + slow * q_slow**k
            mon.update(y_inf + tr + w[k:k + 4].sum(axis=0) / 2, sig * np.sqrt(3))
            if mon.settled():
                break
        ratios.append(abs(tr[1]) / (mon.stated_error() * np.sqrt(mon.shape[1])))
    assert max(ratios) < 1.5, np.round(ratios, 2)


# ---------------------------------------------------------------------------------------------
# Random: what H_var states (resolution bias of continuous random; H2 and Hv variances)
# ---------------------------------------------------------------------------------------------

def _resonators(modes, n_block, navg, seed, window="hann", noise=1e-3):
    """Welch sums of white force through digital two-pole resonators (known FRF, exact by
    ``freqz``), block ``n_block``, 50 % overlap, output noise ``noise`` (white, std per sample);
    ``modes``: (line, half-power bandwidth in lines). Returns the sums and the exact FRF."""
    from scipy.signal import freqz, lfilter

    from daq.estimate import spectra_of_blocks, welch_blocks
    rng = np.random.default_rng(seed)
    hop, warm = n_block // 2, 20 * n_block  # warm-up: no start transient
    x = rng.standard_normal(n_block + (navg - 1) * hop + warm)
    w = 2 * np.pi * np.arange(n_block // 2 + 1) / n_block
    y, He = np.zeros_like(x), np.zeros(w.size, complex)
    for k, B in modes:
        r, th = np.exp(-np.pi * B / n_block), 2 * np.pi * k / n_block  # pole: B lines wide
        a = [1.0, -2 * r * np.cos(th), r * r]
        y += lfilter([1.0], a, x)
        He += freqz([1.0], a, worN=w)[1]
    rec = np.vstack([x, y + noise * rng.standard_normal(y.size)])[:, warm:]
    X = spectra_of_blocks(welch_blocks(rec, n_block, 0.5)[:navg], window)
    S = SpectralSums.empty(w.size, 1, 1)
    S.add(X[:, :1], X[:, 1:])
    return S, He


def test_continuous_random_var_states_the_hann_resolution_bias():
    """Modes 2, 3 and 4 lines wide (half-power), Hann, 64 averages, low output noise. The
    random part of H_var alone left the lines beside the modes with z = |H - H_exact| /
    sqrt(var) at a 95th percentile of 2.8 (the QA's F1: bias fixed, random error shrinking
    with averages). With the first-order bias ``(mu2/2) H''`` in var: below 2.1 (complex
    Gaussian 1.73; the measured H's curvature understates the narrowest peak's), while the
    values far from the modes stay calibrated and periodic analysis (mu2 = 0) gets no term."""
    from daq.estimate import coarse_peaks, window_mu2
    assert abs(window_mu2("hann", 512) - 1 / 3) < 0.01  # analytically 1/3
    modes = [(60.3, 2.0), (140.6, 3.0), (200.2, 4.0)]
    mu2 = window_mu2("hann", 512)
    near_z, far_z = [], []
    for seed in range(3):
        S, He = _resonators(modes, 512, 64, seed)
        d = frf_from_spectra(S, "H1", mu2=mu2)
        z = np.abs(d["H"][:, 0, 0] - He) / np.sqrt(d["var"][:, 0, 0])
        dist = np.min([np.abs(np.arange(He.size) - k) for k, _ in modes], axis=0)
        near_z.append(z[dist < 8])
        far_z.append(z[(dist > 20) & (np.arange(He.size) > 5) & (np.arange(He.size) < He.size - 5)])
        lines = np.flatnonzero(coarse_peaks(d["H"], d["var_random"]))
        assert set(lines) & {60, 61} and not set(lines) & set(range(185, 215)), lines  # 2 lines: warned; 4: not
        np.testing.assert_array_equal(frf_from_spectra(S, "H1")["var"], d["var_random"])  # mu2 = 0: random only
    near, far = np.concatenate(near_z), np.concatenate(far_z)
    assert np.percentile(near, 95) < 2.1 and np.median(near) < 1.0, (np.median(near), np.percentile(near, 95))
    assert 0.7 < np.median(far) < 0.95, np.median(far)  # not conservative away from the modes


def _one_input_sums(snr_in, snr_out, n_avg=64, n_f=400, seed=0):
    """Frequency-domain averages of one input: force u (unit power), response H u; white
    complex noise of power 1/snr_in on the force channel and |H|^2/snr_out on the response."""
    rng = np.random.default_rng(seed)
    H = (1 + rng.random(n_f)) * np.exp(2j * np.pi * rng.random(n_f))

    def cn(*shape):
        return (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / np.sqrt(2)

    U = cn(n_avg, 1, n_f)
    X = U + cn(n_avg, 1, n_f) / np.sqrt(snr_in) if snr_in else U
    Y = H * U + (np.abs(H) * cn(n_avg, 1, n_f) / np.sqrt(snr_out) if snr_out else 0)
    S = SpectralSums.empty(n_f, 1, 1)
    S.add(X, Y)
    return S, H


def test_h2_variance_is_its_own_under_input_noise():
    """Force noise only (force SNR 4: gamma^2 = 0.8). H2 is unbiased; with H1's variance
    its E|dH|^2 / var was 1 / gamma^4 = 1.56 (QA F4: z 25 % high). Its own first-order
    variance ``|H2|^2 (1 - gamma^2) / (gamma^2 (n - 1))`` gives 1."""
    ratios = []
    for seed in range(4):
        S, H = _one_input_sums(4.0, 0, seed=seed)
        d = frf_from_spectra(S, "H2")
        ratios.append(np.abs(d["H"][:, 0, 0] - H) ** 2 / d["var"][:, 0, 0])
    r = np.mean(ratios)
    assert 0.85 < r < 1.15, r


def test_hv_with_one_input_is_h1_over_gamma_with_its_own_variance():
    """The scaled Hv is H1/gamma (|Hv| = sqrt(Gyy/Gxx), H1's phase): unbiased only where the
    noise-to-signal ratios of force and response are alike (here both 1/2: gamma^2 = 0.44).
    Its variance ``|Hv|^2 (1 - gamma^4) / (2 gamma^2 (n - 1))`` gives E|dH|^2 / var = 1; with
    H1's, (1 + gamma^2) / (2 gamma^2) = 1.6."""
    ratios = []
    for seed in range(4):
        S, H = _one_input_sums(2.0, 2.0, seed=seed)
        d, d1 = frf_from_spectra(S, "Hv"), frf_from_spectra(S, "H1")
        np.testing.assert_allclose(d["H"], d1["H"] / np.sqrt(d1["coherence"]), rtol=1e-9)
        ratios.append(np.abs(d["H"][:, 0, 0] - H) ** 2 / d["var"][:, 0, 0])
    r = np.mean(ratios)
    assert 0.85 < r < 1.15, r
