"""The Baoding policy's observation and action, defined once for the env and the real hand.

`tacgnn.envs.baoding.BaodingEnv` and `tacgnn.real.controller.BlindController` both build
what the policy sees with these functions, so the simulated and the real hand cannot
drift apart:

    observation (54) = [ joint angles scaled to [-1, 1] by the joint ranges (16),
                         JOINT_VEL_SCALE x joint velocities, rad/s (16),
                         ball positions, m, world frame (6),
                         last action (16) ]

    with `ball_velocity` (60): the balls' velocities, m/s (6), after their positions.

    action (16): absolute joint targets, [-1, 1] mapped linearly onto each joint's range.

Ball positions perceived from the skin go through `perceive_balls`: the perception
model, then (optionally) `track_ball_identities`, which keeps ball 0 ball 0 from one
step to the next.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from tacgnn.hand.allegro import NUM_JOINTS

JOINT_VEL_SCALE = 0.2
"""The paper's scale of the joint velocities in the observation."""
PROPRIO_COLUMNS = slice(0, 2 * NUM_JOINTS)
"""Where the observation holds the scaled joint angles, then the scaled joint velocities."""
BALL_VALUES = 6
"""Two balls, (x, y, z) each."""
BALL_COLUMNS = slice(PROPRIO_COLUMNS.stop, PROPRIO_COLUMNS.stop + BALL_VALUES)
"""Where the observation holds the balls: after the 16 joint angles and the 16 joint velocities."""


def action_to_target(action: np.ndarray, low: np.ndarray, high: np.ndarray,
                     target_ranges: np.ndarray | None = None) -> np.ndarray:
    """Joint targets (rad) from actions, clipped to [-1, 1] first: -1 -> low, +1 -> high; then
    clipped to `target_ranges` ((16, 2) rad, `HandConfig.target_ranges`) when given."""
    a = np.clip(action, -1.0, 1.0)
    target = low + 0.5 * (a + 1.0) * (high - low)
    return target if target_ranges is None else np.clip(target, target_ranges[:, 0], target_ranges[:, 1])


def keep_near(target: np.ndarray, measured: np.ndarray, band: float) -> np.ndarray:
    """`target` kept within `band` rad of the `measured` joint angles (0: unchanged): the target band
    a policy may be trained with (`target_band_rad`), applied alike in the env and on the real hand."""
    return np.clip(target, measured - band, measured + band) if band > 0 else target


def target_to_action(target: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The inverse of `action_to_target` (not clipped): joint angles scaled to [-1, 1] by the ranges."""
    return 2.0 * (target - low) / (high - low) - 1.0


def proprioception(joint_pos: np.ndarray, joint_vel: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """(N, 32): scaled joint angles, then scaled joint velocities."""
    return np.concatenate([target_to_action(joint_pos, low, high), JOINT_VEL_SCALE * joint_vel], axis=-1)


def assemble(joint_pos: np.ndarray, joint_vel: np.ndarray, objects: np.ndarray, last_action: np.ndarray,
             low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """(N, 32 + K + 16) float32 observation; `objects` (N, K) is what the mode shows of the balls
    (K = 6 ball positions; 16 actuator torques in the 'finger_torque' ablation)."""
    return np.concatenate([proprioception(joint_pos, joint_vel, low, high), objects, last_action],
                          axis=-1).astype(np.float32)


def perceive_balls(perception: Callable[..., np.ndarray], tactile: Any, taxel_pos: Any,
                   joint_pos: np.ndarray, previous: np.ndarray | None) -> np.ndarray:
    """(N, 6) ball positions a perception model reads off the skin, identities tracked.

    Args:
        perception: ``f(tactile, taxel_pos)``, or ``f(tactile, taxel_pos, joint_pos)`` for a
            model with a ``joint_inputs`` attribute (it also reads the hand's pose).
        tactile: (N, T) taxel readings (N): numpy, or a torch tensor on the device of the Warp
            engine's skin, which the perception takes as it is (no copy to the host).
        taxel_pos: (N, T, 3) taxel positions (m) at the instant of the readings; the same kind.
        joint_pos: (N, 16) joint angles (rad), for models that read them.
        previous: (N, 6) the positions given one step before (after tracking), or None to
            take the model's order as it is.
    """
    if not isinstance(tactile, torch.Tensor):
        tactile = np.asarray(tactile, dtype=np.float32)
    if not isinstance(taxel_pos, torch.Tensor):
        taxel_pos = np.asarray(taxel_pos, dtype=np.float32)
    if getattr(perception, "joint_inputs", 0):
        pred = perception(tactile, taxel_pos, joint_pos)
    else:
        pred = perception(tactile, taxel_pos)
    pred = np.asarray(pred, dtype=np.float64).reshape(-1, BALL_VALUES)
    return pred if previous is None else track_ball_identities(pred, previous)


def track_ball_identities(pred: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """(N, 6) predicted ball pairs, swapped where that puts each ball nearer its previous position.

    The balls look alike, so a skin model can only say where two balls are, not which is
    which. At 50 Hz a ball moves a few millimetres per step while the two are 5 cm apart,
    so the nearer assignment keeps each ball's identity through a whole rotation.
    """
    swapped = pred[:, [3, 4, 5, 0, 1, 2]]
    swap = ((swapped - previous) ** 2).sum(1) < ((pred - previous) ** 2).sum(1)
    return np.where(swap[:, None], swapped, pred)


def ball_velocity(balls: np.ndarray, previous: np.ndarray, fresh: np.ndarray, control_dt: float) -> np.ndarray:
    """(N, 6) the balls' velocities (m/s) a `ball_velocity` observation shows: their positions'
    change since `previous`, one control step of `control_dt` s before; zero where `fresh` (N,),
    an episode's first frame, which has no step before it."""
    return np.where(fresh[:, None], 0.0, (balls - previous) / control_dt)


def canonical_ball_order(balls: np.ndarray, plane: np.ndarray, reference: float, direction: int) -> np.ndarray:
    """(N, 6) ball pairs in the order that does not depend on which ball is which.

    The balls look alike, and the pair turned by 180 degrees is the start with the balls
    swapped: a policy that sees them in a fixed order sees a state it has never met after
    each half turn, so a 180-degree skill cannot repeat. Here the pair is ordered so that the
    angle of the vector from the first ball to the second, in the plane spanned by the
    columns of `plane` (3, 2) and counted from `reference` (rad) in `direction` (+1/-1),
    lies in [0, 180) degrees: the pair after each half turn looks like the start again.
    Swapping the two balls of the input leaves the output unchanged.
    """
    return swap_balls(balls, canonical_swap(balls, plane, reference, direction))


def canonical_swap(balls: np.ndarray, plane: np.ndarray, reference: float, direction: int) -> np.ndarray:
    """(N,) True where `canonical_ball_order` swaps the two balls of `balls` (N, 6)."""
    v = (balls[:, 3:6] - balls[:, 0:3]) @ plane
    progress = (direction * (np.arctan2(v[:, 1], v[:, 0]) - reference)) % (2 * np.pi)
    return progress >= np.pi


def swap_balls(values: np.ndarray, swap: np.ndarray) -> np.ndarray:
    """(N, 6) per-ball values (positions, velocities) with the two balls swapped where `swap` (N,)."""
    return np.where(swap[:, None], values[:, [3, 4, 5, 0, 1, 2]], values)
