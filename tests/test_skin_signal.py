"""The real skin's signal chain: known answers for each of its effects, its calibration, bad input."""

from dataclasses import replace

import numpy as np
import pytest

from tacgnn.config import ConfigError, override
from tacgnn.envs.baoding import BaodingConfig, BaodingEnv
from tacgnn.hand.skin_layout import default_skin
from tacgnn.sim.skin_signal import SkinSignal, SkinSignalConfig, calibrated, neighbour_table, track_baseline

LAYOUT = default_skin()
T = LAYOUT.num_taxels
# every effect off: the chain must then read the ideal forces back exactly (above the threshold)
PLAIN = SkinSignalConfig(noise_floor=0.0, offset=(0.2, 0.2), drift_rate=0.0, calibration_age=(0.0, 0.0),
                         gain_spread=0.0, patch_gain_spread=0.0, patch_gain_error=0.0, relaxation=0.0, crosstalk=0.0,
                         saturation=100.0, quantisation=0.0, dead_fraction=(0.0, 0.0), stuck_fraction=(0.0, 0.0))


def skin(config, n=2, seed=0):
    signal = SkinSignal(config, LAYOUT, n, frame_dt=0.02)
    signal.reset(np.arange(n), [np.random.default_rng(seed + i) for i in range(n)])
    return signal


def test_the_ideal_preset_passes_the_forces_through_and_draws_nothing():
    forces = np.random.default_rng(0).uniform(0, 1, (3, T)).astype(np.float32)
    signal = SkinSignal(SkinSignalConfig(preset="ideal"), LAYOUT, 3, 0.02)
    rngs = [np.random.default_rng(1) for _ in range(3)]
    signal.reset(np.arange(3), rngs)
    assert all(g.random() == np.random.default_rng(1).random() for g in rngs)  # no draw taken
    assert signal(forces, slice(None), np.random.default_rng(0)) is forces


def test_with_every_effect_off_the_calibrated_skin_reads_the_force():
    forces = np.zeros((2, T), np.float32)
    forces[0, 5], forces[1, 300] = 0.7, 2.5
    out = skin(PLAIN)(forces, slice(None), np.random.default_rng(0))
    np.testing.assert_allclose(out, forces, atol=1e-6)


def test_a_real_skin_at_rest_reads_zero_but_for_its_stuck_taxels():
    """The noise floor is on every taxel, yet the calibration's threshold (4 rest stds, at least
    0.05 N) keeps the rest at 0; stuck taxels are the phantom presses a real skin shows."""
    config = replace(SkinSignalConfig(), stuck_fraction=(0.01, 0.01), calibration_age=(0.0, 0.0))
    signal = skin(config, n=8)
    rng = np.random.default_rng(0)
    for _ in range(20):
        out = signal(np.zeros((8, T), np.float32), slice(None), rng)
    stuck = signal.stuck > 0
    assert stuck.sum() > 8  # about 1 % of 8 x 653
    assert (out[stuck] > 0).all()
    assert (out[~stuck] > 0).mean() < 1e-3


def test_an_old_fixed_calibration_lets_drift_through_as_phantom_touches():
    rest = np.zeros((8, T), np.float32)
    fixed = replace(SkinSignalConfig(), stuck_fraction=(0.0, 0.0), baseline_tracking=0.0)
    fresh = skin(replace(fixed, calibration_age=(0.0, 0.0)), n=8)
    stale = skin(replace(fixed, calibration_age=(3600.0, 3600.0), drift_rate=0.01), n=8)
    rng = np.random.default_rng(0)
    assert (fresh(rest, slice(None), rng) > 0).mean() < (stale(rest, slice(None), rng) > 0).mean()


def test_saturation_caps_a_taxel_and_dead_taxels_read_zero():
    forces = np.full((2, T), 5.0, np.float32)
    out = skin(replace(PLAIN, saturation=3.0))(forces, slice(None), None)
    np.testing.assert_allclose(out, 3.0, atol=1e-6)
    half_dead = skin(replace(PLAIN, dead_fraction=(0.5, 0.5)))
    out = half_dead(forces, slice(None), None)
    assert 0.4 < (out == 0).mean() < 0.6 and np.array_equal(out == 0, half_dead.dead)


def test_relaxation_creeps_towards_a_held_load_and_lingers_after_release():
    """y = (1 - h) f + h m, m low-passing f with time constant tau: under a step load the reading
    starts at (1 - h) f and creeps up; after release it reads h m, decaying as exp(-t / tau)."""
    h, tau, dt = 0.2, 0.5, 0.02
    signal = skin(replace(PLAIN, relaxation=h, relaxation_time=tau, min_threshold=1e-4))
    load = np.zeros((2, T), np.float32)
    load[:, 10] = 1.0
    first = signal(load, slice(None), None)[0, 10]
    m = dt / tau  # the memory after one frame
    assert first == pytest.approx((1 - h) + h * m, rel=1e-5)
    for _ in range(200):
        held = signal(load, slice(None), None)[0, 10]
    assert held == pytest.approx(1.0, abs=1e-3)
    released = signal(np.zeros_like(load), slice(None), None)[0, 10]
    assert released == pytest.approx(h * (1 - m), rel=1e-3)


def test_crosstalk_gives_each_neighbour_its_share_of_a_press():
    neighbours = neighbour_table(LAYOUT)
    taxel = 200
    near = neighbours[taxel][neighbours[taxel] < T]
    assert 2 <= len(near) <= 8
    forces = np.zeros((2, T), np.float32)
    forces[:, taxel] = 2.0
    out = skin(replace(PLAIN, crosstalk=0.1, min_threshold=1e-4))(forces, slice(None), None)
    count = (neighbours[near] < T).sum(1)
    np.testing.assert_allclose(out[0, near], 0.1 * 2.0 / count, rtol=1e-5)
    others = np.setdiff1d(np.arange(T), [taxel, *near])
    assert not out[0, others].any()


def test_the_calibration_maths_is_the_real_paths():
    from tacgnn.real.skin import SkinProcessor, calibrate

    rng = np.random.default_rng(0)
    rest = 100 + rng.normal(0, 1, (30, T))
    cal = calibrate(rest)
    raw = rest[0] + np.where(rng.random(T) < 0.1, 20.0, 0.0)
    expected = calibrated(raw, cal.baseline, cal.threshold, cal.gain, cal.dead)
    np.testing.assert_array_equal(SkinProcessor(cal).process_raw(raw), expected)


def test_the_env_reads_the_real_skin_by_default_and_the_ideal_one_when_asked():
    def settled(preset):
        env = BaodingEnv(override(BaodingConfig(num_envs=4, obs_mode="tactile"), {"skin_signal.preset": preset}))
        env.reset(seed=0)
        for _ in range(10):  # the balls land in the palm
            obs, *_ = env.step(env.last_action.copy())
        return obs["tactile"]

    real, ideal = settled("real"), settled("ideal")
    assert BaodingConfig().skin_signal.preset == "real"
    assert not np.array_equal(real, ideal)
    assert (ideal > 0).any() and (real > 0).any()  # the balls press both


@pytest.mark.parametrize("key,value", [("skin_signal.noise_floor", -0.01), ("skin_signal.saturation", 0.01),
                                       ("skin_signal.dead_fraction", [0.2, 0.1]),
                                       ("skin_signal.relaxation", 1.5), ("skin_signal.preset", "perfect")])
def test_bad_skin_values_name_their_key(key, value):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        override(BaodingConfig(), {key: value})


def test_the_compiled_chain_is_the_numpy_chain_to_the_bit():
    """The env runs the compiled chain; the numpy one (`use_compiled = False`) is its reference:
    readings, raw values and the skins' states agree exactly, for all envs and for some."""
    config = replace(SkinSignalConfig(), stuck_fraction=(0.02, 0.02), dead_fraction=(0.05, 0.05))
    compiled, reference = skin(config, n=6), skin(config, n=6)
    reference.use_compiled = False
    g = np.random.default_rng(1)
    for step in range(12):
        forces = (g.random((6, T)) * (g.random((6, T)) < 0.05) * 2).astype(np.float32)
        ids = slice(None) if step % 2 else np.array([1, 4])
        rows = forces if step % 2 else forces[[1, 4]]
        rng = np.random.default_rng(step) if step % 3 else None
        out = compiled(rows, ids, rng)
        ref = reference(rows, ids, None if rng is None else np.random.default_rng(step))
        np.testing.assert_array_equal(out, ref)
        np.testing.assert_array_equal(compiled.last_raw, reference.last_raw)
    for name in SkinSignal.STATE:
        np.testing.assert_array_equal(getattr(compiled, name), getattr(reference, name))


@pytest.mark.parametrize("config", [SkinSignalConfig(), replace(SkinSignalConfig(), noise_floor=0.5, quantisation=0.0,
                                                                    dead_fraction=(0.2, 0.5), baseline_tracking=0.0)])
def test_the_compiled_calibration_is_the_numpy_one_to_the_bit(config):
    """A reset's draws and rest frames run compiled in the env; the numpy path is their reference: every
    skin's state and every stream agree exactly."""
    compiled, reference = SkinSignal(config, LAYOUT, 9, 0.02), SkinSignal(config, LAYOUT, 9, 0.02)
    reference.use_compiled = False
    for ids in (np.arange(9), np.array([2]), np.array([0, 5, 7])):
        streams = [[np.random.default_rng(10 * len(ids) + i) for i in ids] for _ in range(2)]
        compiled.reset(ids, streams[0])
        reference.reset(ids, streams[1])
        assert [g.random() for g in streams[0]] == [g.random() for g in streams[1]]
    for name in SkinSignal.STATE:
        np.testing.assert_array_equal(getattr(compiled, name), getattr(reference, name))


def test_a_tracking_baseline_keeps_a_drifting_skin_at_zero_for_minutes_and_a_press_whole():
    """Five minutes of drift at rest: the fixed baseline reads a growing share of the taxels as
    touched, the tracking one none; a press held for 2 s keeps its reading (pressed taxels keep
    their baseline)."""
    config = replace(SkinSignalConfig(), stuck_fraction=(0.0, 0.0), calibration_age=(0.0, 0.0))
    fixed, tracking = skin(replace(config, baseline_tracking=0.0), n=4), skin(config, n=4)
    rng = np.random.default_rng(0)
    rest = np.zeros((4, T), np.float32)
    for _ in range(15_000):  # 300 s at 50 Hz
        phantom_fixed = fixed(rest, slice(None), rng)
        phantom_tracking = tracking(rest, slice(None), rng)
    assert (phantom_fixed > 0).mean() > 0.05 and (phantom_tracking > 0).mean() < 1e-3
    press = rest.copy()
    press[:, 100] = 1.0
    first = tracking(press, slice(None), rng)[:, 100]
    for _ in range(100):  # 2 s
        held = tracking(press, slice(None), rng)[:, 100]
    assert (first > 0.5).all() and (held > first * 0.95).all()


def test_the_real_path_tracks_the_baseline_as_the_simulated_skin_does():
    from tacgnn.real.skin import SkinProcessor, calibrate

    rng = np.random.default_rng(0)
    rest = 100 + rng.normal(0, 1, (30, T))
    cal = calibrate(rest)
    processor = SkinProcessor(cal, tracking_rate=0.1)
    baseline = cal.baseline.copy()
    for k in range(50):  # a slow drift of every taxel, and one pressed taxel
        raw = rest[k % 30] + 0.05 * k + np.where(np.arange(T) == 7, 30.0, 0.0)
        out = processor.process_raw(raw)
        np.testing.assert_array_equal(out, calibrated(raw, baseline, cal.threshold, cal.gain, cal.dead))
        track_baseline(raw, baseline, cal.threshold, 0.1)
    assert out[7] > 20 and (out[np.arange(T) != 7] == 0).mean() > 0.99
    before = processor.baseline.copy()
    processor.process_raw(raw + 0.01, track=False)  # a look (checking a message) moves nothing
    np.testing.assert_array_equal(processor.baseline, before)
    np.testing.assert_array_equal(SkinProcessor(cal).process_raw(raw), calibrated(raw, cal.baseline, cal.threshold,
                                                                                  cal.gain, cal.dead))
