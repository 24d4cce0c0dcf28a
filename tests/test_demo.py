"""The shipped policy (what `make demo` runs) loads with this code and acts on a perceived env."""

from dataclasses import replace

import numpy as np

from tacgnn.envs.baoding import BaodingEnv
from tacgnn.learning.policy import SHIPPED_POLICY, load_perception, load_policy


def test_shipped_policy_loads_and_acts():
    assert SHIPPED_POLICY.is_file() and SHIPPED_POLICY.stat().st_size < 5_000_000
    policy, cfg = load_policy(SHIPPED_POLICY)
    perception = load_perception(SHIPPED_POLICY)
    assert cfg.obs_mode == "perceived" and perception is not None
    env = BaodingEnv(replace(cfg, num_envs=2), perception=perception)
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        actions = policy(obs)
        assert actions.shape == (2, 16) and np.isfinite(actions).all()
        obs, *_ = env.step(actions)
