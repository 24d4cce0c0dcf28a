"""One control tick of a trained blind Baoding policy on a real hand.

`BlindController` turns what the hand measures (joint angles and velocities, calibrated
skin readings) into the 16 joint position targets the policy commands. The observation,
the ball-identity tracking and the action-to-target mapping are those of
`tacgnn.envs.observation`, the same functions `tacgnn.envs.baoding.BaodingEnv` uses:

    [ joint angles scaled to [-1, 1] by the joint ranges (16),
      0.2 x joint velocities (16),
      ball positions perceived from the skin, identities tracked (6),
      last action (16) ]

The ball positions come from the policy file's perception model, fed with the skin
readings and the taxel positions of `TaxelKinematics` at the measured angles.

Safety on a real hand (all off by default, so the targets are the simulator's): targets
within `max_step_rad` of the measured angles, target changes at most `max_target_rate`,
and always inside the joint ranges. Each limit logs one line when it starts acting and
one when it stops (with the number of ticks it acted).
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from tacgnn.config import check
from tacgnn.envs import observation
from tacgnn.envs.baoding import ordered_balls
from tacgnn.hand.allegro import JOINT_NAMES, NUM_JOINTS
from tacgnn.learning.policy import SHIPPED_POLICY
from tacgnn.real.kinematics import TaxelKinematics
from tacgnn.real.safety_log import SafetyLog

BLIND_MODES = ("perceived", "no_perception")
log = logging.getLogger("tacgnn.real")


@dataclass(frozen=True)
class BlindControllerConfig:
    policy: str = str(SHIPPED_POLICY)
    """A policy file (exported or training checkpoint) of a 'perceived' or 'no_perception' policy."""
    torch_threads: int = 1
    """Threads for the policy and perception networks (one tick is small; 1 keeps latency steady)."""
    max_step_rad: float = 0.0
    """If > 0, targets stay within this distance of the measured angles (a safety limit for first
    trials); 0 commands exactly what the policy does in simulation. A policy trained with a band
    (`target_band_rad`) always keeps it; this can only narrow it."""
    max_target_rate: float = 0.0
    """If > 0, a target moves at most this fast (rad/s) from the last commanded target (the first
    tick of an episode: from the measured angles); 0: no limit."""

    def __post_init__(self) -> None:
        check(self.torch_threads >= 1, "torch_threads", "must be >= 1")
        check(self.max_step_rad >= 0, "max_step_rad", f"must be >= 0, got {self.max_step_rad}")
        check(self.max_target_rate >= 0, "max_target_rate", f"must be >= 0, got {self.max_target_rate}")


class OneHand:
    """The env a perception with memory reads (`TemporalOnlinePerception.bind_env`), for the one
    hand a controller drives: its episode's step count (0 until the first frame after `reset`)
    and the action last commanded, as the env has them when it observes."""

    num_envs = 1

    def __init__(self, controller: BlindController):
        self._controller = controller
        self.episode_steps = np.zeros(1, np.int64)

    @property
    def last_action(self) -> np.ndarray:
        action = self._controller.last_action
        assert action is not None  # the controller resets before it perceives
        return action[None]


class BlindController:
    """(joint_pos rad, joint_vel rad/s, skin (T,)) -> (16,) joint targets in rad, every 1 / 50 s.

    Call `reset(joint_pos)` when an episode starts: like the env at reset, the last action
    is then the current pose and ball tracking starts from the spawn points. A first
    `step` without `reset` does it implicitly.
    """

    def __init__(self, config: BlindControllerConfig | None = None):
        from tacgnn.learning.policy import load_perception, load_policy

        self.config = cfg = config or BlindControllerConfig()
        torch.set_num_threads(cfg.torch_threads)
        self.policy, self.env_config = load_policy(cfg.policy)
        mode = self.env_config.obs_mode
        if mode not in BLIND_MODES:
            raise ValueError(f"policy {cfg.policy} observes '{mode}', which a blind hand cannot provide; "
                             f"use a policy trained with obs_mode in {list(BLIND_MODES)}")
        perception = load_perception(cfg.policy) if mode == "perceived" else None
        if mode == "perceived" and perception is None:
            raise ValueError(f"policy {cfg.policy} is a 'perceived' policy but holds no perception model")
        self.perception: Callable[..., np.ndarray] | None = perception
        self.hand = OneHand(self)
        bind = getattr(perception, "bind_env", None)
        if bind is not None:  # a perception with memory: its state follows this hand's episode
            bind(self.hand)
        hand = self.env_config.hand
        self.kinematics = TaxelKinematics(hand, self.env_config.skin, self.env_config.sim)
        self.joint_low, self.joint_high = np.asarray(hand.joint_ranges, dtype=np.float64).T
        self.target_ranges = np.asarray(hand.joint_target_ranges(), dtype=np.float64)
        self.num_taxels = self.kinematics.num_taxels
        self.control_dt = self.env_config.control_dt
        self.track_balls = bool(self.env_config.track_balls)
        self.spawn_balls = np.asarray(self.env_config.spawn_offsets, np.float64).reshape(1, observation.BALL_VALUES)
        self.safety = SafetyLog()
        self.last_action: np.ndarray | None = None
        self.last_target: np.ndarray | None = None
        self.balls = self.spawn_balls.copy()
        """(1, 6) the ball positions of the last observation (after tracking)."""

    # --- the env's mappings -----------------------------------------------------------
    def action_to_target(self, action: np.ndarray) -> np.ndarray:
        return observation.action_to_target(action, self.joint_low, self.joint_high, self.target_ranges)

    def target_to_action(self, target: np.ndarray) -> np.ndarray:
        return observation.target_to_action(target, self.joint_low, self.joint_high)

    # --- control ----------------------------------------------------------------------
    def reset(self, joint_pos: np.ndarray) -> None:
        """Start an episode at the measured pose (the last action becomes that pose)."""
        q = self._check("joint_pos", joint_pos, (NUM_JOINTS,))
        self.last_action = self.target_to_action(np.clip(q, self.joint_low, self.joint_high))
        self.last_target = None
        self.balls = self.spawn_balls.copy()
        self.hand.episode_steps[0] = 0  # a perception with memory starts afresh

    def perceive(self, joint_pos: np.ndarray, skin: np.ndarray, skin_joint_pos: np.ndarray | None = None) -> np.ndarray:
        """(6,) ball positions (m, world frame) from the skin, identities tracked as in the env;
        zeros for a 'no_perception' policy. Updates the tracking state."""
        if self.perception is None:
            return np.zeros(observation.BALL_VALUES)
        torch.get_num_threads()  # this thread's torch threads set up before its first op (`act`)
        kin_q = joint_pos if skin_joint_pos is None else skin_joint_pos
        taxel_pos = self.kinematics.positions(kin_q)[None]
        previous = self.balls if self.track_balls else None
        self.balls = observation.perceive_balls(self.perception, skin[None], taxel_pos, joint_pos[None], previous)
        self.hand.episode_steps[0] += 1
        return self.balls[0]

    def observation(self, joint_pos: np.ndarray, joint_vel: np.ndarray, skin: np.ndarray,
                    skin_joint_pos: np.ndarray | None = None) -> np.ndarray:
        """The (54,) float32 observation the env builds from this state ((60,) for a policy that
        also sees the balls' velocities, `ball_velocity`); updates the ball tracking.

        `skin_joint_pos`: the joint angles at the instant of the skin frame, for the taxel
        positions (default: `joint_pos`).
        """
        q = self._check("joint_pos", joint_pos, (NUM_JOINTS,))
        qd = self._check("joint_vel", joint_vel, (NUM_JOINTS,))
        s = self._check("skin", skin, (self.num_taxels,))
        if skin_joint_pos is not None:
            skin_joint_pos = self._check("skin_joint_pos", skin_joint_pos, (NUM_JOINTS,))
        if (s < 0).any():
            raise ValueError("skin readings must be >= 0 (calibrated readings from SkinProcessor, not raw values); "
                             f"negative at taxels {np.flatnonzero(s < 0)[:5].tolist()}")
        if self.last_action is None:
            self.reset(q)
        fresh, before = self.hand.episode_steps == 0, self.balls
        balls = self.perceive(q, s.astype(np.float32), skin_joint_pos)[None]
        velocity = None
        if self.env_config.ball_velocity:
            velocity = observation.ball_velocity(balls, before, fresh, self.control_dt)
        shown = ordered_balls(balls, self.env_config, velocity)
        assert self.last_action is not None  # reset() set it
        return observation.assemble(q[None], qd[None], shown, self.last_action[None], self.joint_low,
                                    self.joint_high)[0]

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The policy's (16,) action in [-1, 1] for one observation; becomes the last action."""
        # The ROS loop ticks on the threads that receive messages. Torch sets a thread's
        # OpenMP threads lazily, on its first parallel op; a first matmul before that ran on
        # more threads and rounded differently (a few ulps, carried on in the controller's
        # state). Asking for the thread count does the set-up.
        torch.get_num_threads()
        action = np.asarray(self.policy(obs[None]), np.float64)[0]
        if not np.isfinite(action).all():
            raise FloatingPointError("the policy returned non-finite actions")
        self.last_action = np.clip(action, -1.0, 1.0)
        return self.last_action

    def step(self, joint_pos: np.ndarray, joint_vel: np.ndarray, skin: np.ndarray,
             skin_joint_pos: np.ndarray | None = None) -> np.ndarray:
        """(16,) joint position targets (rad) for this tick, within the joint ranges."""
        obs = self.observation(joint_pos, joint_vel, skin, skin_joint_pos)
        return self.limit(self.action_to_target(self.act(obs)), np.asarray(joint_pos, np.float64))

    __call__ = step

    def warm_up(self, joint_pos: np.ndarray, joint_vel: np.ndarray, skin: np.ndarray, ticks: int = 3) -> None:
        """Run the networks on a state without changing the controller's state: the first calls
        pay for lazy initialisation (hundreds of ms), which must not fall on a control tick."""
        saved = (self.last_action, self.last_target, self.balls.copy(), self.safety.active.copy())
        memory = self.hand.episode_steps.copy(), copy.deepcopy(getattr(self.perception, "state", None))
        touched = np.zeros(self.num_taxels)
        touched[::10] = 0.1  # contacts all over the skin: the graph code compiles on its first contacts
        for frame in (skin, touched, np.zeros(self.num_taxels)):
            for _ in range(ticks):
                self.act(self.observation(joint_pos, joint_vel, frame))
        self.last_action, self.last_target, self.balls, self.safety.active = saved
        self.hand.episode_steps[:] = memory[0]
        if memory[1] is not None:
            self.perception.state = memory[1]  # type: ignore[union-attr]

    def limit(self, target: np.ndarray, joint_pos: np.ndarray) -> np.ndarray:
        """The safety rules on a target: step limit, rate limit, joint ranges (in that order)."""
        cfg = self.config
        out = target.copy()
        out = observation.keep_near(out, joint_pos, self.env_config.target_band_rad)  # the policy's: no safety event
        near = observation.keep_near(out, joint_pos, cfg.max_step_rad)
        self.safety.note("max_step_rad", bool((near != out).any()),
                         f"max_step_rad: targets kept within {cfg.max_step_rad} rad of the measured angles")
        out = near
        if cfg.max_target_rate > 0:
            ref = joint_pos if self.last_target is None else self.last_target
            reach = cfg.max_target_rate * self.control_dt
            slow = np.clip(out, ref - reach, ref + reach)
        else:
            slow = out
        self.safety.note("max_target_rate", bool((slow != out).any()),
                         f"max_target_rate: target changes limited to {cfg.max_target_rate} rad/s")
        out = slow
        inside = np.clip(out, self.target_ranges[:, 0], self.target_ranges[:, 1])
        self.safety.note("joint_ranges", bool((np.abs(inside - out) > 1e-9).any()),  # not float round-off
                         "joint_ranges: targets clipped to the policy's joint (or target) ranges")
        self.last_target = inside
        return inside

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
