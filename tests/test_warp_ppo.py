"""PPO (rsl_rl) learns through the MuJoCo Warp physics, on a small problem, on the CPU.

The problem: the Baoding hand on the Warp backend, rewarded for holding its four thumb
joints at 0.8 of their range (in the policy's action units, as the observation gives
them). The joints move only through the engine (position actuators, torque limits,
contacts with the balls), so the reward rises only if the physics and the env's
observations carry the policy's actions through. About 20 s after the kernels are cached.
"""

from dataclasses import replace

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco_warp")

from rsl_rl.env import VecEnv  # noqa: E402
from rsl_rl.runners import OnPolicyRunner  # noqa: E402
from tensordict import TensorDict  # noqa: E402

from tacgnn.envs.baoding import BaodingConfig, BaodingEnv  # noqa: E402

THUMB = slice(12, 16)  # joint columns of the thumb in the observation (scaled joint positions first)
TARGET = 0.8
ITERATIONS, STEPS = 15, 8


class ThumbPose(VecEnv):
    """reward = -mean |q_thumb - 0.8| (action units), 10-step episodes, on BaodingEnv with sim.backend: warp."""

    def __init__(self, num_envs: int):
        cfg = BaodingConfig(num_envs=num_envs, tactile=False, max_episode_steps=10)
        self.env = BaodingEnv(replace(cfg, sim=replace(cfg.sim, backend="warp")))
        self.num_envs, self.num_actions, self.max_episode_length = num_envs, 16, 10
        self.device, self.cfg = "cpu", {}
        self.obs, _ = self.env.reset(seed=0)
        self.mean_rewards: list[float] = []

    @property
    def episode_length_buf(self) -> torch.Tensor:
        return torch.from_numpy(self.env.episode_steps)

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor) -> None:
        self.env.episode_steps[:] = value.numpy()

    def get_observations(self) -> TensorDict:
        return TensorDict({"policy": torch.from_numpy(self.obs)}, batch_size=[self.num_envs])

    def step(self, actions: torch.Tensor):
        obs, _, terminated, truncated, info = self.env.step(actions.detach().numpy().astype(np.float64))
        ended = info.get("_final_obs", np.zeros(self.num_envs, bool))
        last = np.where(ended[:, None], info["final_obs"], obs) if ended.any() else obs  # before any reset
        reward = -np.abs(last[:, THUMB] - TARGET).mean(1)
        self.mean_rewards.append(float(reward.mean()))
        self.obs = obs
        done = torch.from_numpy((terminated | truncated).astype(np.int64))
        return self.get_observations(), torch.from_numpy(reward.astype(np.float32)), done, \
            {"time_outs": torch.from_numpy(truncated)}


def _model(stochastic: bool) -> dict:
    cfg = {"class_name": "rsl_rl.models:MLPModel", "hidden_dims": [32, 32], "activation": "elu",
           "obs_normalization": True}
    if stochastic:
        cfg["distribution_cfg"] = {"class_name": "rsl_rl.modules:GaussianDistribution", "init_std": 0.5,
                                   "std_type": "scalar"}
    return cfg


RSL_RL_CFG = {
    "run_name": "warp_thumb", "num_steps_per_env": STEPS, "save_interval": 10_000,
    "obs_groups": {"actor": ["policy"], "critic": ["policy"]}, "logger": "tensorboard", "check_for_nan": True,
    "algorithm": {"class_name": "rsl_rl.algorithms:PPO", "num_learning_epochs": 5, "num_mini_batches": 4,
                  "clip_param": 0.2, "gamma": 0.9, "lam": 0.95, "value_loss_coef": 1.0, "entropy_coef": 0.0,
                  "learning_rate": 3e-3, "max_grad_norm": 1.0, "use_clipped_value_loss": True,
                  "schedule": "fixed", "desired_kl": 0.01},
    "actor": _model(True), "critic": _model(False),
}


def test_ppo_learns_through_the_warp_physics():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        torch.manual_seed(0)
        env = ThumbPose(32)
        runner = OnPolicyRunner(env, RSL_RL_CFG, log_dir=None, device="cpu")
        runner.logger.git_status_repos = []
        runner.learn(ITERATIONS)
    finally:
        torch.set_num_threads(threads)
    per_iteration = np.array(env.mean_rewards).reshape(ITERATIONS, STEPS).mean(1)
    first, last = per_iteration[:3].mean(), per_iteration[-3:].mean()
    assert first < -0.6  # a random thumb is far from 0.8
    assert last > first + 0.25, per_iteration.round(3)
