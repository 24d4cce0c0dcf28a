"""The Baoding env seen through rsl_rl's `VecEnv` contract: torch tensors in and out.

rsl_rl's runner calls ``step(actions)`` and expects, for N envs:

* observations: a TensorDict of groups: ``"policy"`` (N, obs_dim) float32, read by the
  actor (and the critic), and with ``privileged_critic`` ``"critic"`` (N, 54), the
  ground-truth observation, read by the critic only;
* rewards (N,) float32: the env's reward times `reward_scale` (the authors use 0.01);
* dones (N,) int64: 1 where an episode ended in this step (terminated or truncated);
* extras: ``"time_outs"`` (N,) bool, the truncated envs, on which PPO bootstraps
  r + gamma V(s) instead of treating the end as terminal; ``"log"``, per-episode
  statistics of the episodes that ended in this step, which rsl_rl's logger averages
  over every episode that ended in the iteration.

BaodingEnv resets ended envs in the same step, so the observation returned for them is
already the first one of the next episode, which is what rsl_rl wants.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from tacgnn.config import to_dict
from tacgnn.envs.baoding import BaodingConfig, BaodingEnv


class RslBaodingEnv(VecEnv):
    """`BaodingEnv` as an rsl_rl `VecEnv` on the CPU.

    Attributes:
        env: the wrapped numpy `BaodingEnv`.
        cfg: the env config as a plain dict (rsl_rl hands it to its log writers).
        num_envs: N, number of parallel envs.
        num_actions: 16, absolute joint targets in [-1, 1].
        num_obs: obs_dim, size of the flat observation (54; 64 for 'finger_torque').
        max_episode_length: steps after which an episode is truncated (config's max_episode_steps).
        episode_length_buf: (N,) int64, steps taken in each env's current episode; a live
            view of ``env.episode_steps`` (assigning to it writes into the env).
        device: "cpu"; the env is numpy, tensors share its memory where they can.
        reward_scale: factor applied to the env's rewards.
        bootstrap_time_outs: whether ``extras["time_outs"]`` is reported (else every end
            of episode is terminal for PPO, as in the authors' rl_games setup).
    """

    def __init__(self, config: BaodingConfig, reward_scale: float = 0.01, bootstrap_time_outs: bool = True,
                 perception: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
                 privileged_critic: bool = False):
        if config.obs_mode == "tactile":
            raise ValueError("obs_mode 'tactile' gives a dict of raw skin arrays, which an MLP policy cannot "
                             "read; use 'perceived' with a perception model, or another obs_mode")
        self.env = BaodingEnv(config, perception=perception)
        self.on_step: Callable[[dict], None] | None = None
        self.cfg = to_dict(config)
        self.num_envs = config.num_envs
        action_shape, obs_shape = self.env.single_action_space.shape, self.env.single_observation_space.shape
        assert action_shape is not None and obs_shape is not None  # both are Boxes in these obs modes
        self.num_actions = int(action_shape[0])
        self.num_obs = int(obs_shape[0])
        self.max_episode_length = self.env.episode_limit
        self.device = "cpu"
        self.reward_scale = reward_scale
        self.bootstrap_time_outs = bootstrap_time_outs
        self.privileged_critic = privileged_critic
        obs, _ = self.env.reset(seed=config.seed)
        _check_finite(obs, np.zeros(self.num_envs))
        self._obs = self._wrap(obs)
        # Running sums of each reward term over the current episode, (N,) per term (env units).
        self._episode_terms: dict[str, np.ndarray] = {}

    # --- the VecEnv contract -------------------------------------------------------------
    @property
    def episode_length_buf(self) -> torch.Tensor:
        return torch.from_numpy(self.env.episode_steps)

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor) -> None:
        # rsl_rl assigns a new tensor here (init_at_random_ep_len); keep the env the owner.
        self.env.episode_steps[:] = value.detach().cpu().numpy()

    def get_observations(self) -> TensorDict:
        """The observations of the last step (or of the reset)."""
        return self._obs

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        obs, reward, terminated, truncated, info = self.env.step(actions.detach().cpu().numpy())
        if self.on_step is not None:  # e.g. the online perception records the skin frames
            self.on_step(info)
        done = terminated | truncated
        _check_finite(obs, reward)
        self._obs = self._wrap(obs)
        rewards = torch.from_numpy(reward * np.float32(self.reward_scale))
        extras: dict[str, Any] = {"log": self._episode_log(info, done)}
        if self.bootstrap_time_outs:
            extras["time_outs"] = torch.from_numpy(truncated.copy())
        return self._obs, rewards, torch.from_numpy(done.astype(np.int64)), extras

    def _wrap(self, obs: np.ndarray, critic_obs: np.ndarray | None = None) -> TensorDict:
        groups = {"policy": torch.from_numpy(obs)}
        if self.privileged_critic:
            groups["critic"] = torch.from_numpy(self.env.groundtruth_obs() if critic_obs is None else critic_obs)
        return TensorDict(groups, batch_size=[self.num_envs])

    def _episode_log(self, info: dict, done: np.ndarray) -> dict[str, torch.Tensor]:
        """Statistics of the episodes that ended in this step, one value per episode.

        rsl_rl concatenates these over the steps of an iteration before averaging, so
        each logged number is a mean over the episodes that ended in that iteration.
        """
        for name, value in info["reward_terms"].items():
            self._episode_terms.setdefault(name, np.zeros(self.num_envs))
            self._episode_terms[name] += value
        if not done.any():
            return {}
        ids = np.flatnonzero(done)
        log = {
            "Episode/success_rate": info["success"][ids],
            "Episode/fall_rate": info["fall"][ids],
            "Episode/timeout_rate": info["timeout"][ids],
            "Episode/diverged_rate": info["diverged"][ids],
            "Episode/final_angle_deg": info["angle_deg"][ids],
            "Episode/length": info["episode_steps"][ids],
        }
        for name, total in self._episode_terms.items():
            log[f"Episode/return_{name}"] = total[ids].copy()
            total[ids] = 0.0
        return {key: torch.as_tensor(value, dtype=torch.float32) for key, value in log.items()}

    # --- exact resume ------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Everything a resumed run needs to continue this env bit for bit (tensors, plain data):
        the env's own state (`BaodingEnv.state_dict`), the last observations, the episode sums."""
        return {
            **_to_torch(self.env.state_dict()),
            "obs": self._obs["policy"].clone(),
            **({"critic_obs": self._obs["critic"].clone()} if self.privileged_critic else {}),
            "episode_terms": {k: torch.from_numpy(v.copy()) for k, v in self._episode_terms.items()},
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what `state_dict` saved, into an env built from the same config."""
        if self.privileged_critic and "critic_obs" not in state:
            raise ValueError("saved env state has no critic observations: it was trained without a privileged critic")
        env_keys = ("sim_state", "model_fields", "buffers", "rng", "hand_io", "skin_signal", "skin_history")
        self.env.load_state_dict(_to_numpy({k: state[k] for k in env_keys}))
        critic = state["critic_obs"].numpy().copy() if self.privileged_critic else None
        self._obs = self._wrap(state["obs"].numpy().copy(), critic)
        self._episode_terms = {k: v.numpy().copy() for k, v in state["episode_terms"].items()}


def _to_torch(tree: Any) -> Any:
    """numpy arrays -> tensors in a nest of dicts (a checkpoint holds tensors, not numpy arrays)."""
    if isinstance(tree, dict):
        return {k: _to_torch(v) for k, v in tree.items()}
    return torch.from_numpy(tree) if isinstance(tree, np.ndarray) else tree


def _to_numpy(tree: Any) -> Any:
    if isinstance(tree, dict):
        return {k: _to_numpy(v) for k, v in tree.items()}
    return tree.numpy() if isinstance(tree, torch.Tensor) else tree


def _check_finite(obs: np.ndarray, reward: np.ndarray) -> None:
    """Stop before a NaN or Inf reaches the normalisers and the rollout buffer.

    The env keeps its own state finite (diverged envs are reset), but an observation can
    still carry a perception model's output; rsl_rl's own check sees NaN, not Inf.
    """
    bad_obs, bad_reward = ~np.isfinite(obs).all(1), ~np.isfinite(reward)
    if bad_obs.any() or bad_reward.any():
        envs = np.flatnonzero(bad_obs | bad_reward).tolist()
        columns = np.flatnonzero(~np.isfinite(obs).all(0)).tolist()
        raise FloatingPointError(f"non-finite {'observation' if bad_obs.any() else 'reward'} in envs {envs} "
                                 f"(observation columns {columns}); the policy was not updated with it")
