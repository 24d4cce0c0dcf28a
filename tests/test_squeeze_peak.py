"""The squeeze penalty on the peak contact force over a control step's physics substeps."""

from dataclasses import replace

import mujoco
import numpy as np

from tacgnn.envs.baoding import BaodingConfig, BaodingEnv, RewardConfig
from tacgnn.envs.scripted import FingerWave


def _pair(num_envs: int = 3):
    cfg = BaodingConfig(num_envs=num_envs, tactile=False)
    return BaodingEnv(replace(cfg, reward=RewardConfig(squeeze_peak=True))), BaodingEnv(cfg)


def test_peak_term_sees_the_landing_impact_the_end_of_step_term_misses():
    """After a reset the balls drop onto the palm: the impact lies between control steps."""
    peak_env, end_env = _pair()
    peak_env.reset(seed=0)
    end_env.reset(seed=0)
    wave = FingerWave(end_env.last_action[0], end_env.num_envs, seed=0)
    missed, seen = 0, 0
    obs = None
    for _ in range(20):
        actions = wave(obs)
        obs, _, _, _, end_info = end_env.step(actions)
        _, _, _, _, peak_info = peak_env.step(actions)
        # the switch changes the reward only: stepping substep by substep is the same physics
        np.testing.assert_array_equal(peak_env.sim.qpos, end_env.sim.qpos)
        peak, end = peak_info["reward_terms"]["squeeze"], end_info["reward_terms"]["squeeze"]
        assert (peak <= end + 1e-12).all()  # a maximum over substeps that include the last
        missed += int(((end == 0) & (peak < -0.1)).sum())  # > 2 N above the free force, unseen at the end
        seen += int((peak < end - 1e-9).sum())
    assert missed >= 1
    assert seen >= 5


def test_peak_forces_are_the_largest_over_each_substep_of_plain_mujoco():
    env, _ = _pair(num_envs=2)
    env.reset(seed=0)
    actions = np.tile(env.last_action[0], (env.num_envs, 1))
    data = mujoco.MjData(env.model)
    w = env.config.reward
    charged = 0
    for _ in range(4):
        env.sim.batch.get_data(1, data)
        data.ctrl[:] = env.action_to_ctrl(actions)[1]
        forces = []
        for _ in range(env.substeps):
            mujoco.mj_step(env.model, data)
            forces.append(data.sensordata[env._ball_force_cols].copy())
        _, _, _, _, info = env.step(actions)
        want = w.squeeze * np.maximum(np.max(forces, axis=0) - w.squeeze_free_force, 0.0).sum()
        assert info["reward_terms"]["squeeze"][1] == want
        charged += want < 0
    assert charged >= 1
