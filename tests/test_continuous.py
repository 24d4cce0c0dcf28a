"""The continuous Baoding task: turn as far as possible in 10 s; a fall ends the episode."""

from dataclasses import replace

import numpy as np
import pytest

from tacgnn.config import ConfigError
from tacgnn.envs.baoding import BaodingConfig, BaodingEnv, RewardConfig
from tacgnn.envs.baoding_terms import reward_terms
from tacgnn.envs.observation import BALL_COLUMNS, canonical_ball_order
from tacgnn.learning.evaluate import _turns


def test_episode_lasts_ten_seconds_without_success_or_timeout_penalty():
    env = BaodingEnv(BaodingConfig(num_envs=1, task="continuous", continuous_seconds=0.4,
                                   success_angle_deg=1e-3))
    assert env.episode_limit == 20
    env.reset(seed=0)
    hold = np.tile(env.ctrl_to_action(env.initial_ctrl), (1, 1))
    for step in range(1, 21):
        _, _, terminated, truncated, info = env.step(hold)
        assert not info["success"][0], "the continuous task has no success"
        if info["fall"][0]:
            pytest.skip("a ball fell while the hand held still")
        assert truncated[0] == (step == 20) and not terminated[0]
    assert info["reward_terms"]["timeout"][0] == 0.0


@pytest.mark.parametrize("seconds", [0.0, -1.0, 10.01])
def test_episode_length_must_be_whole_control_steps(seconds):
    with pytest.raises(ConfigError, match="continuous_seconds"):
        BaodingConfig(task="continuous", continuous_seconds=seconds)


def test_direction_must_be_plus_or_minus_one():
    with pytest.raises(ConfigError, match="direction"):
        BaodingConfig(task="continuous", direction=2)


def test_continuous_task_has_no_kicks_unless_asked():
    quiet = BaodingEnv(BaodingConfig(num_envs=2, task="continuous"))
    kicked = BaodingEnv(BaodingConfig(num_envs=2, task="continuous", continuous_disturbances=True))
    for env in (quiet, kicked):
        env.reset(seed=0)
        for _ in range(10):
            env.step(np.zeros((2, 16)))
    quiet.episode_steps[:] = kicked.episode_steps[:] = 10
    quiet._apply_disturbances()
    kicked._apply_disturbances()
    assert not quiet.sim.xfrc_applied.any() and kicked.sim.xfrc_applied.any()


def test_turns_are_reported_with_an_interval():
    out = _turns(np.array([1.0, 2.0, 3.0, 4.0]))
    assert out["rotations_mean"] == 2.5 and out["rotations_max"] == 4.0
    lo, hi = out["rotations_ci95"]
    assert lo < 2.5 < hi


def _swap_balls(env: BaodingEnv) -> None:
    """Exchange the two balls' places (positions and velocities) in every env."""
    q, v = env.ball_qpos_adr, env.ball_dof_adr
    qpos, qvel = env.sim.qpos, env.sim.qvel
    a, b = qpos[:, q[0]:q[0] + 7].copy(), qpos[:, q[1]:q[1] + 7].copy()
    qpos[:, q[0]:q[0] + 7], qpos[:, q[1]:q[1] + 7] = b, a
    a, b = qvel[:, v[0]:v[0] + 6].copy(), qvel[:, v[1]:v[1] + 6].copy()
    qvel[:, v[0]:v[0] + 6], qvel[:, v[1]:v[1] + 6] = b, a
    env.sim.forward(np.arange(env.num_envs))


@pytest.mark.parametrize("direction", [1, -1])
def test_canonical_order_does_not_depend_on_which_ball_is_which(direction):
    env = BaodingEnv(BaodingConfig(num_envs=8, task="continuous", ball_order="canonical", direction=direction,
                                   tactile=False))
    env.reset(seed=3)
    before = env._observe(slice(None), None, None)
    _swap_balls(env)
    after = env._observe(slice(None), None, None)
    np.testing.assert_array_equal(after, before)
    np.testing.assert_array_equal(env.groundtruth_obs(), before)  # the critic sees the same order


def test_default_order_keeps_ball_zero_first():
    env = BaodingEnv(BaodingConfig(num_envs=4, task="continuous", tactile=False))
    obs, _ = env.reset(seed=3)
    _swap_balls(env)
    swapped = env._observe(slice(None), None, None)
    np.testing.assert_allclose(swapped[:, 32:35], obs[:, 35:38], atol=1e-6)
    np.testing.assert_allclose(swapped[:, BALL_COLUMNS], env.ball_positions().reshape(4, 6), atol=1e-6)


def test_canonical_order_puts_the_pair_in_one_half_turn():
    rng = np.random.default_rng(0)
    balls = rng.normal(size=(500, 6))
    plane = np.eye(3)[:, :2]
    for direction in (1, -1):
        ordered = canonical_ball_order(balls, plane, 0.3, direction)
        v = ordered[:, 3:5] - ordered[:, 0:2]
        progress = (direction * (np.arctan2(v[:, 1], v[:, 0]) - 0.3)) % (2 * np.pi)
        assert (progress < np.pi).all()
        np.testing.assert_array_equal(canonical_ball_order(balls[:, [3, 4, 5, 0, 1, 2]], plane, 0.3, direction),
                                      ordered)
        assert {tuple(r) for r in np.sort(ordered.reshape(-1, 2, 3), axis=1).reshape(-1, 6)} == \
            {tuple(r) for r in np.sort(balls.reshape(-1, 2, 3), axis=1).reshape(-1, 6)}


def test_alive_and_capped_rotation_terms():
    cfg = BaodingConfig(num_envs=3, task="continuous", tactile=False,
                        reward=RewardConfig(alive=0.2, rotation_cap_deg=4.0))
    d_angle = np.deg2rad(np.array([2.0, 10.0, -10.0]))
    fall = np.array([False, False, True])
    none = np.zeros(3, bool)
    still = np.zeros((3, 16))
    terms = reward_terms(cfg, d_angle, still, still, still, none, fall, none, np.zeros((3, 8)), still)
    np.testing.assert_allclose(terms["alive"], [0.2, 0.2, 0.0])
    np.testing.assert_allclose(terms["rotation"], [1.0, 2.0, -5.0])  # 0.5 per degree, forward capped at 4
    assert terms["fall"][2] == -100.0
    plain = reward_terms(replace(cfg, reward=RewardConfig()), d_angle, still, still, still, none, fall, none,
                         np.zeros((3, 8)), still)
    np.testing.assert_allclose(plain["rotation"], [1.0, 5.0, -5.0])
    assert not plain["alive"].any()


@pytest.mark.parametrize("change", [{"ball_order": "sorted"}, {"reward": {"alive": -1.0}},
                                    {"reward": {"rotation_cap_deg": -2.0}}])
def test_bad_order_and_reward_settings_are_named(change):
    key = next(iter(change))
    value = change[key]
    with pytest.raises(ConfigError, match=key if key == "ball_order" else next(iter(value))):
        if key == "reward":
            BaodingConfig(reward=RewardConfig(**value))
        else:
            BaodingConfig(**change)


def test_ball_velocity_shows_each_balls_change_over_the_step_in_the_shown_order():
    """`ball_velocity`: after the positions, (shown now - shown one step before) / control_dt, with
    the balls in the order the positions take (canonical order swaps both), zero at reset; the
    privileged critic's observation carries the true ones."""
    cfg = BaodingConfig(num_envs=4, task="continuous", ball_order="canonical", ball_velocity=True, tactile=False)
    env = BaodingEnv(cfg)
    obs, _ = env.reset(seed=0)
    velocity = slice(BALL_COLUMNS.stop, BALL_COLUMNS.stop + 6)
    assert obs.shape == (4, 60) and env.single_observation_space.shape == (60,)
    assert not obs[:, velocity].any()  # an episode's first frame: no motion yet
    rng = np.random.default_rng(0)
    before = env.ball_positions().reshape(4, 6)
    swapped_seen = False
    for _ in range(30):
        obs, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, (4, 16)))
        now = env.ball_positions().reshape(4, 6)
        going = ~(terminated | truncated)
        expected = (now - before) / cfg.control_dt
        shown = obs[:, BALL_COLUMNS]
        swap = ~np.all(np.isclose(shown, now, atol=1e-6), axis=1)
        swapped_seen |= bool(swap[going].any())
        expected = np.where(swap[:, None], expected[:, [3, 4, 5, 0, 1, 2]], expected)
        np.testing.assert_allclose(obs[going][:, velocity], expected[going], rtol=1e-5, atol=1e-5)
        np.testing.assert_array_equal(env.groundtruth_obs()[going], obs[going])  # ground truth: the same
        before = now
    assert np.abs(obs[:, velocity]).max() > 0.01  # the balls do move (m/s)
    assert swapped_seen, "no step showed the balls swapped: the test did not check the order"


@pytest.mark.parametrize("mode", ["no_perception", "finger_torque", "noise_2"])
def test_ball_velocity_only_with_shown_balls(mode):
    with pytest.raises(ConfigError, match="ball_velocity"):
        BaodingConfig(obs_mode=mode, ball_velocity=True)
