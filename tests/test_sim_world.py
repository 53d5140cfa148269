"""The physics world: exact time integration against frequency-domain references, hidden
effects, shaker back-EMF, sensor overload and amplifier protection trips."""

from __future__ import annotations

import numpy as np
import pytest

from sim_devices.components import (
    AMP_FAULT_INTERLOCK,
    AMP_FAULT_OVER_TEMPERATURE,
    AMP_FAULT_OVER_TRAVEL,
    SensorSpec,
    ShakerSpec,
    StandSpec,
)
from sim_devices.effects import (
    AddedMass,
    AttachedOscillator,
    CouplingSpring,
    GroundedDamper,
    GroundedSpring,
    apply_effects,
)
from sim_devices.world import EffectError, World, WorldError
from ssid.frf import accelerance_from_model
from ssid.models import chain_model, example_system, frf_on_test_stand

FS = 5120.0


def _sine_ratio(world: World, freq_hz: float, rows: tuple[int, int], seconds: float = 6.0, vpp: float = 1.0):
    """Drive generator 0 channel 1 with a sine; Hann-windowed DFT ratio rows[1]/rows[0] at freq_hz."""
    ch = world.generators[0].channels[0]
    ch.function, ch.freq_hz, ch.vpp, ch.output_on = "SIN", freq_hz, vpp, True
    world.amplifiers[0].gain_v_per_v = 2.0
    assert world.amplifiers[0].request_enable() == 0
    n = int(seconds * FS)
    blk = world.advance(n)
    tail = int(2 * FS)
    idx = blk.first_index + np.arange(n - tail, n)
    x = blk.physical[:, -tail:] * np.hanning(tail)
    X = x @ np.exp(-2j * np.pi * freq_hz * idx / FS)
    return X[rows[1]] / X[rows[0]]


def test_time_integration_matches_frf_with_stand():
    M, C, K, dofs = example_system()
    sensors = [
        SensorSpec("F", "force", 0, 0.0225),
        SensorSpec("a3", "acceleration", "3+Z", 0.01),
        SensorSpec("r14", "reaction", "14+Z", 0.0225),
    ]
    world = World(M, C, K, dofs, shakers=[ShakerSpec("1+Z")], sensors=sensors,
                  stand=StandSpec(("14+Z",)), noise=False)
    ref = frf_on_test_stand(M, C, K, dofs, ["1+Z"], ["14+Z"], [40.0])
    # The world's own reference FRF is the lumped test-stand model.
    w = world.frf([40.0])
    np.testing.assert_allclose(w.H[0, 2, 0], ref.H[0, 2, 0], rtol=1e-10)
    np.testing.assert_allclose(w.H_reaction[0, 0, 0], ref.H_reaction[0, 0, 0], rtol=1e-10)
    # And the time-domain chain reproduces it through the force gauge.
    assert abs(_sine_ratio(world, 40.0, (0, 1)) / ref.H[0, 2, 0] - 1) < 1e-3
    world.reset_state()
    assert abs(_sine_ratio(world, 40.0, (0, 2)) / ref.H_reaction[0, 0, 0] - 1) < 1e-3


def test_hidden_effects_change_the_truth_not_the_nominal():
    M, C, K, dofs = chain_model([1.0, 2.0, 1.5], [1e4, 1e4], [1e4, 0, 0], [1, 1], [0, 0, 0])
    effects = [AddedMass("2+Z", 0.1), GroundedSpring("3+Z", 500.0), CouplingSpring("1+Z", "3+Z", -200.0),
               GroundedDamper("1+Z", 2.0), AttachedOscillator("3+Z", 0.2, 3e3, 1.0)]
    M2, C2, K2, d2 = apply_effects(M, C, K, dofs, effects)
    assert d2 == dofs + ["3+Z~osc1"]
    assert M2[1, 1] == pytest.approx(2.1) and M2[3, 3] == pytest.approx(0.2)
    assert K2[2, 2] == pytest.approx(K[2, 2] + 500 - 200 + 3e3) and K2[0, 2] == pytest.approx(200.0)
    assert C2[0, 0] == pytest.approx(C[0, 0] + 2.0) and K2[2, 3] == pytest.approx(-3e3)
    world = World(M, C, K, dofs, shakers=[ShakerSpec("1+Z")], effects=effects,
                  sensors=[SensorSpec("F", "force", 0, 0.02), SensorSpec("a2", "acceleration", "2+Z", 0.01)], noise=False)
    f = np.array([8.0, 15.0, 30.0])
    truth = accelerance_from_model(M2, C2, K2, d2, f, ["2+Z"], ["1+Z"]).H
    nominal = accelerance_from_model(M, C, K, dofs, f, ["2+Z"], ["1+Z"]).H
    np.testing.assert_allclose(world.frf(f, outputs=["2+Z"]).H, truth, rtol=1e-10)
    assert np.max(np.abs(truth / nominal - 1)) > 0.05
    with pytest.raises(ValueError, match="unknown DOF"):
        apply_effects(M, C, K, dofs, [AddedMass("9+Z", 1.0)])


def test_shaker_force_drops_at_structural_resonance():
    # Voltage drive, back-EMF: the force into the structure dips at the drive-point resonance.
    M, C, K, dofs = chain_model([1.0], [], [4e4], [], [2.0])  # one mode near 31.8 Hz
    world = World(M, C, K, dofs, shakers=[ShakerSpec("1+Z")], sensors=[SensorSpec("F", "force", 0, 0.02)], noise=False)
    f_res = np.sqrt(4e4 / 1.2) / (2 * np.pi)  # with the armature's mass riding along

    def force_amp(freq):
        world.reset_state()
        ch = world.generators[0].channels[0]
        ch.function, ch.freq_hz, ch.vpp, ch.output_on = "SIN", freq, 1.0, True
        world.amplifiers[0].request_enable()
        blk = world.advance(int(6 * FS))
        return np.std(blk.physical[0, -int(FS):])

    assert force_amp(f_res) < 0.5 * min(force_amp(0.5 * f_res), force_amp(1.6 * f_res))


def test_defective_system_is_refused_with_a_clear_message():
    # The second mass has no spring at all: a rigid-body motion with no path to ground.
    M = np.eye(2)
    K = np.zeros((2, 2))
    K[0, 0] = 1e4
    with pytest.raises(WorldError, match="rigid-body"):
        World(M, None, K, ["1+Z", "2+Z"], shakers=[ShakerSpec("1+Z")])


def test_sensor_overload_clips_and_flags():
    M, C, K, dofs = example_system()
    world = World(M, C, K, dofs, shakers=[ShakerSpec("1+Z")], noise=False,
                  sensors=[SensorSpec("a1", "acceleration", "1+Z", 0.01, range_volt=0.05)])
    ch = world.generators[0].channels[0]
    ch.function, ch.freq_hz, ch.vpp, ch.output_on = "SIN", 48.0, 2.0, True
    world.amplifiers[0].request_enable()
    blk = world.advance(2048)
    assert blk.overload[0] and np.max(np.abs(blk.volts)) == pytest.approx(0.05)


def test_amplifier_trips_on_over_travel_and_over_temperature():
    M, C, K, dofs = example_system()
    spec = ShakerSpec("1+Z", travel_limit_m=1e-6)
    world = World(M, C, K, dofs, shakers=[spec], noise=False)
    ch = world.generators[0].channels[0]
    ch.function, ch.freq_hz, ch.vpp, ch.output_on = "SIN", 10.0, 2.0, True
    amp = world.amplifiers[0]
    amp.request_enable()
    world.advance(4096)
    assert not amp.enabled and amp.fault_code == AMP_FAULT_OVER_TRAVEL
    assert amp.request_enable() == AMP_FAULT_OVER_TRAVEL  # latched until reset
    assert amp.reset_fault() and amp.request_enable() == 0
    # A hot coil: a very small thermal capacity heats up at once.
    world2 = World(M, C, K, dofs, shakers=[ShakerSpec("1+Z", thermal_capacity_j_per_k=1e-3, thermal_resistance_k_per_w=100.0)], noise=False)
    ch = world2.generators[0].channels[0]
    ch.function, ch.freq_hz, ch.vpp, ch.output_on = "SIN", 200.0, 2.0, True
    world2.amplifiers[0].gain_v_per_v = 10.0
    world2.amplifiers[0].request_enable()
    world2.advance(4096)
    assert world2.amplifiers[0].fault_code == AMP_FAULT_OVER_TEMPERATURE
    # Interlock: opening trips, enabling is refused until closed and reset.
    amp.set_interlock(False)
    assert not amp.enabled and amp.request_enable() == AMP_FAULT_INTERLOCK
    amp.set_interlock(True)
    assert amp.reset_fault() and amp.request_enable() == 0


def test_noise_and_generator_are_seeded():
    M, C, K, dofs = example_system()

    def run():
        w = World(M, C, K, dofs, shakers=[ShakerSpec("1+Z")], sensors=[SensorSpec("a", "acceleration", "2+Z", 0.01)], seed=3)
        ch = w.generators[0].channels[0]
        ch.function, ch.vpp, ch.output_on = "NOIS", 1.0, True
        w.amplifiers[0].request_enable()
        return w.advance(1000).volts

    np.testing.assert_array_equal(run(), run())


def test_payload_simulator_plugs_in():
    """The world takes any (M, C, K, dofs): here the 52-DOF payload simulator on a stand."""
    from ssid.models.payload import INTERFACE_DOFS, modal_damping, payload_simulator

    p = payload_simulator()
    world = World(p.M, modal_damping(p.M, p.K, 0.02), p.K, p.dofs, shakers=[ShakerSpec("1+Z")],
                  stand=StandSpec(tuple(INTERFACE_DOFS)), noise=False,
                  sensors=[SensorSpec("F", "force", 0, 0.0225), SensorSpec("a6", "acceleration", "6+Z", 0.01)])
    ref = world.frf([150.0], outputs=["6+Z"], inputs=["1+Z"])
    assert abs(_sine_ratio(world, 150.0, (0, 1), seconds=4.0) / ref.H[0, 0, 0] - 1) < 1e-3


@pytest.mark.parametrize("arb_rate_hz", [4096.0, 5120.0])
def test_generator_plays_an_arb_band_limited_between_its_points(arb_rate_hz):
    """An arb holding a multisine below half its sample rate comes out as that multisine at
    any instant, as through the 33500B's reconstruction filter: at 4 world steps per arb
    point (4096 S/s arb, resampled by FFT) and at 3.2 (5120 S/s, summed directly). A
    zero-order hold would be off by up to the full step between points."""
    from sim_devices.components import GeneratorModel

    n_pts, fs_world = 256, 4 * 4096.0
    lines = np.array([3, 17, 40, 90])  # periods per waveform, all below n_pts / 2
    phases = np.array([0.1, 1.3, 2.0, 4.4])

    def multisine(pos):
        return np.sin(2 * np.pi * np.outer(pos, lines) / n_pts + phases).sum(axis=1)

    x = multisine(np.arange(n_pts))
    gen = GeneratorModel()
    ch = gen.channels[0]
    ch.function, ch.arb, ch.arb_srate_hz, ch.vpp, ch.output_on = "ARB", x, arb_rate_hz, 2.0, True
    v = np.concatenate([gen.next_samples(1, 500, fs_world), gen.next_samples(1, 700, fs_world)])
    pos = arb_rate_hz / fs_world * np.arange(1, 1201)
    np.testing.assert_allclose(v, multisine(pos), atol=1e-9 * np.abs(x).max())


def test_generator_noise_keeps_its_rms_and_stays_within_its_bandwidth():
    """NOIS with a 500 Hz bandwidth at 16384 S/s: sigma stays Vpp / 6, one continuous
    record across calls, and the power above twice the bandwidth is what an 8th-order
    low-pass leaves there (below 1e-4 of the total) instead of 88 % of it (white)."""
    from scipy.signal import welch

    from sim_devices.components import GeneratorModel

    fs = 16384.0
    gen = GeneratorModel(seed=3)
    ch = gen.channels[0]
    ch.function, ch.vpp, ch.output_on, ch.noise_bw_hz = "NOIS", 6.0, True, 500.0
    v = np.concatenate([gen.next_samples(1, 3000, fs) for _ in range(40)])
    assert np.std(v) == pytest.approx(1.0, rel=0.03)  # sigma = Vpp / 6 = 1 V
    f, pxx = welch(v, fs=fs, nperseg=4096)
    assert pxx[f > 1000].sum() < 1e-4 * pxx.sum()
    # One record: the filter's state carries over, so 40 calls give what one call gives.
    one = GeneratorModel(seed=3)
    one.channels[0].function, one.channels[0].vpp, one.channels[0].output_on = "NOIS", 6.0, True
    one.channels[0].noise_bw_hz = 500.0
    np.testing.assert_allclose(v, one.next_samples(1, v.size, fs), rtol=0, atol=1e-12)


def _tone_through_front_end(freq_hz: float, passband: float | None) -> tuple[complex, complex, float]:
    """A sine into the 14-DOF example at four world steps per sample; after 4 s of settling,
    the Hann-windowed DFT at the frequency the samples show it at (``freq_hz`` or its alias
    ``FS - freq_hz``) of the force channel, volts / sensitivity and the true force."""
    M, C, K, dofs = example_system()
    world = World(M, C, K, dofs, shakers=[ShakerSpec("1+Z")], noise=False, oversample=4,
                  sensors=[SensorSpec("F", "force", 0, 0.0225)], sample_rate_hz=FS,
                  antialias_passband=passband)
    ch = world.generators[0].channels[0]
    ch.function, ch.freq_hz, ch.vpp, ch.output_on = "SIN", freq_hz, 1.0, True
    assert world.amplifiers[0].request_enable() == 0
    world.advance(int(4 * FS))
    n = int(FS)
    blk = world.advance(n)
    seen_hz = freq_hz if freq_hz < FS / 2 else FS - freq_hz
    kernel = np.hanning(n) * np.exp(-2j * np.pi * seen_hz * (blk.first_index + np.arange(n)) / FS)
    delay = world._antialias.delay_steps / 4 if world._antialias is not None else 0.0
    return blk.volts[0] / 0.0225 @ kernel, blk.physical[0] @ kernel, delay


def test_front_end_filter_passes_the_band_and_removes_what_would_alias():
    """Four world steps per sample: the DAQ's anti-alias filter (passband 0.45 fs) passes a
    tone at 0.3 fs to 1e-5 in magnitude, with its delay of (taps - 1) / 2 world steps as the
    only change, and takes a tone at 0.62 fs at least 100 dB down. Without the filter that
    tone is read at full amplitude at its alias 0.38 fs, as a bare sampler reads it."""
    v, p, delay = _tone_through_front_end(0.3 * FS, 0.45)
    assert abs(v / p - np.exp(-2j * np.pi * 0.3 * delay)) < 2e-5
    v, p, _ = _tone_through_front_end(0.62 * FS, 0.45)
    assert abs(p) > 0 and abs(v) < 1e-5 * abs(p)
    v, p, _ = _tone_through_front_end(0.62 * FS, None)
    assert abs(v / p - 1) < 1e-12


def test_an_effect_the_world_cannot_take_is_named_with_its_parameter():
    """A damper with negative damping is refused as it is; a negative mass larger than the
    structure's at its DOF is refused once it makes the system unstable, by its place in the
    list (the entry a setup names) and the parameter at fault."""
    M, C, K, dofs = chain_model([1.0, 2.0, 1.5], [1e4, 1e4], [1e4, 0, 0], [1, 1], [0, 0, 0])
    build = dict(shakers=[ShakerSpec("1+Z")], noise=False)
    with pytest.raises(EffectError) as e:
        World(M, C, K, dofs, effects=[AddedMass("2+Z", 0.1), GroundedDamper("1+Z", -2.0)], **build)
    assert (e.value.index, e.value.parameter) == (1, "damping_n_s_per_m") and "must be >= 0" in e.value.problem
    with pytest.raises(EffectError) as e:
        World(M, C, K, dofs, effects=[GroundedSpring("3+Z", 500.0), AddedMass("2+Z", -2.5)], **build)
    assert (e.value.index, e.value.parameter) == (1, "mass_kg")
    assert "the mass matrix is no longer positive definite" in str(e.value)
