"""One control tick of a trained blind Baoding policy on a real hand.

`BlindController` turns what the hand measures (joint angles and velocities, calibrated
skin readings) into the 16 joint position targets the policy commands, building the
observation exactly as `tacgnn.envs.baoding.BaodingEnv` does:

    [ joint angles scaled to [-1, 1] by the joint ranges (16),
      0.2 x joint velocities (16),
      ball positions perceived from the skin (6),
      last action (16) ]

The ball positions come from the policy file's perception model, fed with the skin
readings and the taxel positions of `TaxelKinematics` at the measured angles. The
action (clipped to [-1, 1]) maps onto the joint ranges of the policy's env config.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from tacgnn.config import check
from tacgnn.hand.allegro import JOINT_NAMES
from tacgnn.real.kinematics import TaxelKinematics

NUM_JOINTS = len(JOINT_NAMES)
SHIPPED_POLICY = Path(__file__).resolve().parent.parent / "assets" / "baoding_policy.pt"
BLIND_MODES = ("perceived", "no_perception")


@dataclass(frozen=True)
class BlindControllerConfig:
    policy: str = str(SHIPPED_POLICY)
    """A policy file (exported or training checkpoint) of a 'perceived' or 'no_perception' policy."""
    torch_threads: int = 1
    """Threads for the policy and perception networks (one tick is small; 1 keeps latency steady)."""
    max_step_rad: float = 0.0
    """If > 0, targets stay within this distance of the measured angles (a safety limit for first
    trials); 0 commands exactly what the policy does in simulation."""

    def __post_init__(self) -> None:
        check(self.torch_threads >= 1, "torch_threads", "must be >= 1")
        check(self.max_step_rad >= 0, "max_step_rad", f"must be >= 0, got {self.max_step_rad}")


class BlindController:
    """(joint_pos rad, joint_vel rad/s, skin (T,)) -> (16,) joint targets in rad, every 1 / 50 s.

    Call `reset(joint_pos)` when control starts: like the env at reset, the last action
    is then the current pose. A first `step` without `reset` does it implicitly.
    """

    def __init__(self, config: BlindControllerConfig | None = None):
        from tacgnn.learning.ppo import load_perception, load_policy

        self.config = cfg = config or BlindControllerConfig()
        torch.set_num_threads(cfg.torch_threads)
        self.policy, self.env_config = load_policy(cfg.policy)
        mode = self.env_config.obs_mode
        if mode not in BLIND_MODES:
            raise ValueError(f"policy {cfg.policy} observes '{mode}', which a blind hand cannot provide; "
                             f"use a policy trained with obs_mode in {list(BLIND_MODES)}")
        self.perception = load_perception(cfg.policy) if mode == "perceived" else None
        if mode == "perceived" and self.perception is None:
            raise ValueError(f"policy {cfg.policy} is a 'perceived' policy but holds no perception model")
        hand = self.env_config.hand
        self.kinematics = TaxelKinematics(hand, self.env_config.skin, self.env_config.sim)
        self.joint_low, self.joint_high = np.asarray(hand.joint_ranges, dtype=np.float64).T
        self.num_taxels = self.kinematics.num_taxels
        self.control_dt = self.env_config.control_dt
        self.last_action: np.ndarray | None = None

    # --- the env's mappings -----------------------------------------------------------
    def action_to_target(self, action: np.ndarray) -> np.ndarray:
        a = np.clip(action, -1.0, 1.0)
        return self.joint_low + 0.5 * (a + 1.0) * (self.joint_high - self.joint_low)

    def target_to_action(self, target: np.ndarray) -> np.ndarray:
        return 2.0 * (target - self.joint_low) / (self.joint_high - self.joint_low) - 1.0

    # --- control ----------------------------------------------------------------------
    def reset(self, joint_pos: np.ndarray) -> None:
        """Start an episode at the measured pose (the last action becomes that pose)."""
        q = self._check("joint_pos", joint_pos, (NUM_JOINTS,))
        self.last_action = self.target_to_action(np.clip(q, self.joint_low, self.joint_high))

    def perceive(self, joint_pos: np.ndarray, skin: np.ndarray) -> np.ndarray:
        """(6,) ball positions (m, world frame) from the skin; zeros for a 'no_perception' policy."""
        if self.perception is None:
            return np.zeros(6)
        taxel_pos = self.kinematics.positions(joint_pos)[None]
        readings = skin.astype(np.float32)[None]
        if getattr(self.perception, "joint_inputs", 0):
            return np.asarray(self.perception(readings, taxel_pos, joint_pos[None]), np.float64).reshape(6)
        return np.asarray(self.perception(readings, taxel_pos), np.float64).reshape(6)

    def observation(self, joint_pos: np.ndarray, joint_vel: np.ndarray, skin: np.ndarray) -> np.ndarray:
        """The (54,) float32 observation the env would build from this state."""
        q = self._check("joint_pos", joint_pos, (NUM_JOINTS,))
        qd = self._check("joint_vel", joint_vel, (NUM_JOINTS,))
        s = self._check("skin", skin, (self.num_taxels,))
        if (s < 0).any():
            raise ValueError("skin readings must be >= 0 (calibrated readings from SkinProcessor, not raw values); "
                             f"negative at taxels {np.flatnonzero(s < 0)[:5].tolist()}")
        if self.last_action is None:
            self.reset(q)
        return np.concatenate([self.target_to_action(q), 0.2 * qd, self.perceive(q, s),
                               self.last_action]).astype(np.float32)

    def step(self, joint_pos: np.ndarray, joint_vel: np.ndarray, skin: np.ndarray) -> np.ndarray:
        """(16,) joint position targets (rad) for this tick, within the joint ranges."""
        obs = self.observation(joint_pos, joint_vel, skin)
        action = np.asarray(self.policy(obs[None]), np.float64)[0]
        if not np.isfinite(action).all():
            raise FloatingPointError("the policy returned non-finite actions")
        action = np.clip(action, -1.0, 1.0)
        self.last_action = action
        target = np.clip(self.action_to_target(action), self.joint_low, self.joint_high)
        if self.config.max_step_rad > 0:
            q = np.asarray(joint_pos, np.float64)
            target = np.clip(target, q - self.config.max_step_rad, q + self.config.max_step_rad)
            target = np.clip(target, self.joint_low, self.joint_high)
        return target

    __call__ = step

    @staticmethod
    def _check(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
        arr = np.asarray(value, dtype=np.float64)
        if arr.shape != shape:
            raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
        bad = ~np.isfinite(arr)
        if bad.any():
            where = [JOINT_NAMES[i] for i in np.flatnonzero(bad)] if shape == (NUM_JOINTS,) \
                else np.flatnonzero(bad)[:5].tolist()
            raise ValueError(f"{name} holds non-finite values (NaN/Inf) at {where}")
        return arr
