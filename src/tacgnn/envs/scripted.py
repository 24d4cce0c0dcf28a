"""Scripted controllers: they move the balls without learning, for demos and datasets.

`FingerWave` curls the fingers in a travelling wave (index, middle, ring out of phase),
which pushes the balls around the palm. Each env gets its own random phase, speed
and amplitude, so a batch produces varied contacts. It is open loop: it reads no
observation, only the step counter. `RandomMotion` moves every joint along its own smooth
random path around the initial pose: contacts no trained or scripted gait makes, for
perception data that covers what a hand may do.
"""

from __future__ import annotations

import numpy as np

from tacgnn.hand.allegro import NUM_JOINTS


class FingerWave:
    """Open-loop travelling wave of finger flexion, around the env's initial pose.

    Args:
        initial_action: (16,) action of the initial pose (``env.last_action[0]`` after reset).
        num_envs: batch size.
        seed: draws each env's phase, period and amplitude.
        period_steps: (low, high) control steps per wave cycle.
        amplitude: (low, high) flexion amplitude, in action units.
    """

    def __init__(self, initial_action: np.ndarray, num_envs: int, seed: int = 0,
                 period_steps: tuple[float, float] = (40.0, 80.0),
                 amplitude: tuple[float, float] = (0.05, 0.15)):
        rng = np.random.default_rng(seed)
        self.base = np.array(initial_action, dtype=np.float64)  # a copy: callers pass a row of the env's last actions
        self.phase = rng.uniform(0, 2 * np.pi, (num_envs, 1))
        self.omega = 2 * np.pi / rng.uniform(*period_steps, (num_envs, 1))
        self.amplitude = rng.uniform(*amplitude, (num_envs, 1))
        self.sign = rng.choice([-1.0, 1.0], (num_envs, 1))  # direction the wave travels
        self.t = 0

    def __call__(self, obs=None) -> np.ndarray:
        finger_lag = np.repeat(np.array([0.0, 1.0, 2.0, 0.0]) * (2 * np.pi / 3), 4)  # thumb: index phase
        flexing = np.tile([0.0, 1.0, 1.0, 0.6], 4) * (np.arange(NUM_JOINTS) < 12)
        angle = self.omega * self.t + self.phase + self.sign * finger_lag[None, :]
        self.t += 1
        return np.clip(self.base + self.amplitude * flexing * np.sin(angle), -1.0, 1.0)


class RandomMotion:
    """Open-loop smooth random motion: each joint's action follows its own Ornstein-Uhlenbeck path
    around the initial pose (mean-reverting, so the hand does not drift to a joint limit). Each env
    draws its own amplitude and pace, from small slow shifts to quick wide ones.

    Args:
        initial_action: (16,) action of the initial pose.
        num_envs: batch size.
        seed: draws each env's amplitude and pace, then the paths.
        amplitude: (low, high) stationary standard deviation of each joint's action (action units).
        correlation_steps: (low, high) control steps over which a path forgets its value (1/e).
    """

    def __init__(self, initial_action: np.ndarray, num_envs: int, seed: int = 0,
                 amplitude: tuple[float, float] = (0.05, 0.3), correlation_steps: tuple[float, float] = (5.0, 40.0)):
        self.rng = np.random.default_rng(seed)
        self.base = np.array(initial_action, dtype=np.float64)  # a copy: callers pass a row of the env's last actions
        spread = self.rng.uniform(*amplitude, (num_envs, 1))
        self.keep = np.exp(-1.0 / self.rng.uniform(*correlation_steps, (num_envs, 1)))
        self.step_std = spread * np.sqrt(1.0 - self.keep ** 2)
        self.offset = spread * self.rng.standard_normal((num_envs, NUM_JOINTS))

    def __call__(self, obs=None) -> np.ndarray:
        self.offset = self.keep * self.offset + self.step_std * self.rng.standard_normal(self.offset.shape)
        return np.clip(self.base + self.offset, -1.0, 1.0)
