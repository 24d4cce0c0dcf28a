"""The env's own work on a second thread (`tacgnn.sim.second_thread`) gives the serial order's results, bit for bit."""

from dataclasses import replace

import numpy as np
import pytest

from tacgnn.envs.baoding import BaodingEnv, training_env_config
from tacgnn.sim import second_thread


def _rollout(steps: int = 40) -> list:
    """Observations (the late skin's frames and positions), rewards, the skin and the episodes' last
    observations of the hand of training under random actions (balls fall: resets every few steps)."""
    env = BaodingEnv(replace(training_env_config(), obs_mode="tactile", num_envs=6, seed=3))
    obs, _ = env.reset(seed=3)
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, 6, 16))
    out = [obs]
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        out += [obs, reward, info["tactile"], info["taxel_pos"], info.get("final_obs")]
    assert sum(o is not None for o in out[5::5]) > 0, "no env reset: the copy beside the resets went untried"
    return out


def _equal(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    return (a is None and b is None) or np.array_equal(a, b)


def test_the_second_thread_changes_no_bit(monkeypatch):
    threaded = _rollout()
    monkeypatch.setattr(second_thread, "ENABLED", False)
    serial = _rollout()
    assert len(threaded) == len(serial)
    assert all(_equal(a, b) for a, b in zip(threaded, serial))


def test_an_error_on_the_second_thread_reaches_the_caller():
    def fails():
        raise ValueError("on the second thread")

    with pytest.raises(ValueError, match="on the second thread"):
        second_thread.beside(fails).result()
