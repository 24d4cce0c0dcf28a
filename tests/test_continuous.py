"""The continuous Baoding task: turn as far as possible in 10 s; a fall ends the episode."""

import numpy as np
import pytest

from tacgnn.config import ConfigError
from tacgnn.envs.baoding import BaodingConfig, BaodingEnv
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
