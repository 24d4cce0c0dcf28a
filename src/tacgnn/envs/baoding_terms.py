"""The Baoding task's rules as terms: the ball-to-ball angle, falls, success, the kicks, the
reward terms, the spawn, and what the policy is shown.

Apart from the env (`envs/baoding.py`), in the shape of mjlab's terms: each rule is a small
function of the config and arrays (the observation, of the env), so it reads on its own and a
test can call it without a scene. The env owns the state the rules update (the angle, the hold
counter) and the random streams: it draws, then hands the draws to a rule, so the order of the
draws stays the env's.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from tacgnn.envs import observation
from tacgnn.envs.baoding_config import ABLATION_NOISE, ORDER_WINDOW_START_DEG, BaodingConfig, RewardConfig
from tacgnn.hand.allegro import NUM_JOINTS
from tacgnn.sim.backend import SkinArray
from tacgnn.sim.scene import palm_frame


# --- reset -------------------------------------------------------------------------------
def place_balls(qpos: np.ndarray, spawn: np.ndarray, ball_qpos_adr: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """`qpos` (changed in place) with the balls at rest, unrotated, at the `spawn` points (B, 3)
    moved by `shift` (B, 2) in x and y."""
    for b, adr in enumerate(ball_qpos_adr):
        qpos[adr:adr + 3] = spawn[b]
        qpos[adr:adr + 2] += shift[b]
        qpos[adr + 3:adr + 7] = (1.0, 0.0, 0.0, 0.0)
    return qpos


def spawn_overlaps(model: Any, scratch: Any, qpos: np.ndarray, ball_geom: np.ndarray, clearance: float) -> bool:
    """Whether a ball touches (within `clearance`, m) the other ball or a link at `qpos`, found
    by MuJoCo's collision detection on the `scratch` MjData."""
    m, d = model, scratch
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    mujoco.mj_collision(m, d)
    contact = d.contact
    near = contact.dist[:d.ncon] < clearance
    if not near.any():
        return False
    touching = contact.geom[:d.ncon][near]
    return bool((touching[..., None] == ball_geom).any())  # np.isin's answer, 5x faster on a few contacts


# --- the angle ---------------------------------------------------------------------------
def ball_vector_angle(balls: np.ndarray, palm_axes: np.ndarray) -> np.ndarray:
    """(N,) wrapped angle (rad) of the vector from ball 0 to ball 1 in the palm plane.

    Args:
        balls: (N, 2, 3) ball centres (world axes).
        palm_axes: (3, 3) the palm's frame, columns normal, across, along the fingers.
    """
    v = (balls[:, 1] - balls[:, 0]) @ palm_axes  # palm coordinates
    return np.arctan2(v[:, 2], v[:, 1])


def angle_change(new: np.ndarray, old: np.ndarray, direction: int) -> np.ndarray:
    """The change (rad) from the wrapped angle `old` to `new`, unwrapped to [-pi, pi) and signed
    by the task's `direction`: what the env adds to the turned angle each step."""
    delta = (new - old + np.pi) % (2 * np.pi) - np.pi
    delta *= direction
    return delta


# --- termination -------------------------------------------------------------------------
def fallen(balls: np.ndarray, palm_centre: np.ndarray, palm_axes: np.ndarray, cfg: BaodingConfig) -> np.ndarray:
    """(N,) whether a ball has left the hand: its height above the palm plane outside
    `cfg.fall_height`, or its distance from the palm centre along the palm above `cfg.fall_radius`.

    Args:
        balls: (N, 2, 3) ball centres (world axes).
    """
    rel = (balls - palm_centre) @ palm_axes  # (N, 2, 3) palm coordinates
    lo, hi = cfg.fall_height
    across = rel[..., 1] ** 2 + rel[..., 2] ** 2
    out = (rel[..., 0] < lo) | (rel[..., 0] > hi) | (across > cfg.fall_radius**2)
    return out.any(axis=1)


def reached(angle: np.ndarray, cfg: BaodingConfig) -> np.ndarray:
    """(N,) whether the turned angle (rad) has reached the task's `success_angle_deg`."""
    return angle >= np.deg2rad(cfg.success_angle_deg) - 1e-9  # float round-off


def success(reached: np.ndarray, fall: np.ndarray, hold_count: np.ndarray, cfg: BaodingConfig) -> np.ndarray:
    """(N,) success this step: the angle reached with both balls in the hand; on the 'hard' and
    'hold' tasks, then kept `hold_steps` / `long_hold_steps` more steps; never on 'continuous'.

    Advances `hold_count` (N,) in place: -1 until the angle is reached, then the steps held since.
    """
    if cfg.task == "continuous":
        return np.zeros_like(reached)
    if cfg.task not in ("hard", "hold"):
        return reached & ~fall
    holding = hold_count >= 0
    hold_count[holding] += 1
    hold_count[reached & ~holding] = 0
    steps = cfg.hold_steps if cfg.task == "hard" else cfg.long_hold_steps
    return (hold_count >= steps) & ~fall


def episode_limit(cfg: BaodingConfig) -> int:
    """Steps after which an episode is truncated: `max_episode_steps`, or the continuous task's
    `continuous_seconds` in control steps."""
    if cfg.task == "continuous":
        return int(round(cfg.continuous_seconds / cfg.control_dt))
    return cfg.max_episode_steps


# --- disturbances ------------------------------------------------------------------------
def disturbed(cfg: BaodingConfig) -> bool:
    """Whether the task kicks the balls: 'middle' and 'hard', and 'continuous' with
    `continuous_disturbances`."""
    return not (cfg.task in ("simple", "hold") or (cfg.task == "continuous" and not cfg.continuous_disturbances))


def kicked_envs(episode_steps: np.ndarray, cfg: BaodingConfig) -> np.ndarray:
    """Indices of the envs whose balls are kicked this step: every `disturbance_interval` steps
    of an episode, not at its start."""
    kick = (episode_steps % cfg.disturbance_interval == 0) & (episode_steps > 0)
    return np.flatnonzero(kick)


def kick_forces(draws: np.ndarray, cfg: BaodingConfig) -> np.ndarray:
    """(K, B, 3) forces (N) on the balls: a direction uniform on the sphere and a magnitude
    ~ N(0, `disturbance_std`), from (K, B, 4) standard normals (three for the direction, one
    for the magnitude, per ball)."""
    forces = np.empty(draws.shape[:2] + (3,))
    for b in range(draws.shape[1]):
        direction = draws[:, b, :3] / np.linalg.norm(draws[:, b, :3], axis=1, keepdims=True)
        forces[:, b] = direction * (cfg.disturbance_std * draws[:, b, 3:])
    return forces


# --- reward ------------------------------------------------------------------------------
def reward_terms(cfg: BaodingConfig, d_angle: np.ndarray, actions: np.ndarray, action_change: np.ndarray,
                 effort: np.ndarray, success: np.ndarray, fall: np.ndarray, timeout: np.ndarray,
                 ball_forces: np.ndarray, load: np.ndarray) -> dict[str, np.ndarray]:
    """The step's reward as named terms (N,) each, scaled by `cfg.reward`; the reward is their sum.

    Args:
        d_angle: (N,) the step's turn (rad, signed by the direction).
        actions, action_change: (N, 16) the actions and their change since the last step.
        effort: (N, 16) actuator torques over their nominal limits.
        success, fall, timeout: (N,) the step's outcome.
        ball_forces: (N, 2 x BALL_CONTACTS) normal forces (N) of the balls' strongest contacts.
        load: (N, 16) |torque| over each env's own torque limit.
    """
    w: RewardConfig = cfg.reward
    return {
        "rotation": w.rotation * _capped(np.rad2deg(d_angle), w.rotation_cap_deg),
        "action": w.action * np.sum(actions**2, axis=1),
        "action_rate": w.action_rate * np.sum(action_change**2, axis=1),
        "effort": w.effort * np.sum(effort**2, axis=1),
        "success": w.success * success,
        "fall": w.fall * fall,
        "timeout": (0.0 if cfg.task == "continuous" else w.timeout) * timeout,  # 10 s is the goal there
        "squeeze": w.squeeze * np.maximum(ball_forces - w.squeeze_free_force, 0.0).sum(axis=1),
        "squeeze_tail": w.squeeze_tail * np.maximum(ball_forces - w.squeeze_tail_force, 0.0).sum(axis=1),
        "alive": w.alive * ~fall,
        "saturation": w.saturation * np.maximum(load - w.saturation_knee, 0.0).sum(axis=1) / (1.0 - w.saturation_knee),
    }


def _capped(degrees: np.ndarray, cap: float) -> np.ndarray:
    """Per-step turn (deg) counted at most `cap` forward (0: no cap); turning back is never capped."""
    return np.minimum(degrees, cap) if cap > 0 else degrees


# --- what the policy is shown ------------------------------------------------------------
def observation_space(cfg: BaodingConfig, num_taxels: int) -> gym.Space:
    """One env's observation space: a dict of proprioception and skin for 'tactile', else a vector."""
    t = num_taxels
    if cfg.obs_mode == "tactile":
        return gym.spaces.Dict({
            "proprio": gym.spaces.Box(-np.inf, np.inf, (3 * NUM_JOINTS,), np.float32),
            "tactile": gym.spaces.Box(0.0, np.inf, (t,), np.float32),
            "taxel_pos": gym.spaces.Box(-np.inf, np.inf, (t, 3), np.float32),
        })
    dim = 4 * NUM_JOINTS if cfg.obs_mode == "finger_torque" else 3 * NUM_JOINTS + 6
    dim += observation.BALL_VALUES if cfg.ball_velocity else 0
    return gym.spaces.Box(-np.inf, np.inf, (dim,), np.float32)


def object_obs(env: Any, ids: Any, tactile: SkinArray | None, taxel_pos: SkinArray | None) -> np.ndarray:
    """The object part of the vector observation of `env`'s envs `ids`, by `obs_mode`: the balls
    (true, noisy, perceived by the skin model, or none) or the finger torques. 'perceived' updates
    the env's `perceived_balls`; the ablation noise draws from the env's batch stream."""
    mode = env.config.obs_mode
    balls = env.ball_positions()[ids].reshape(-1, 6)
    if mode == "groundtruth":
        return shown_balls(balls, env.config, env.true_velocity[ids])
    if mode == "no_perception":
        return np.zeros_like(balls)
    if mode == "finger_torque":
        return env.sim.actuator_force[ids]
    if mode in ABLATION_NOISE:
        return shown_balls(balls + env._rng.uniform(-1, 1, balls.shape) * ABLATION_NOISE[mode], env.config)
    if mode == "perceived":
        if env.perception is None:
            raise RuntimeError("obs_mode 'perceived' needs a perception model: BaodingEnv(perception=...)")
        joints = env.hand_io.readings(ids, env.joint_pos[ids], env.joint_vel[ids])[0]  # for models that read it
        previous = env.perceived_balls[ids] if env.config.track_balls else None
        assert tactile is not None and taxel_pos is not None  # the config turns the skin on for 'perceived'
        pred = observation.perceive_balls(env.perception, tactile, taxel_pos, joints, previous)
        velocity = None
        if env.config.ball_velocity:
            velocity = observation.ball_velocity(pred, env.perceived_balls[ids], env.episode_steps[ids] == 0,
                                                 env.config.control_dt)
        env.perceived_balls[ids] = pred
        return shown_balls(pred, env.config, velocity)
    raise AssertionError(mode)


def shown_balls(balls: np.ndarray, cfg: BaodingConfig, velocity: np.ndarray | None = None) -> np.ndarray:
    """(N, 6) ball positions in the config's `ball_order`; with `ball_velocity`, (N, 12): then
    the balls' `velocity` (N, 6) in the same order."""
    return ordered_balls(balls, cfg, velocity if cfg.ball_velocity else None)


def ordered_balls(balls: np.ndarray, cfg: BaodingConfig, velocity: np.ndarray | None = None) -> np.ndarray:
    """(N, 6) ball positions in `cfg.ball_order`, and after them the balls' `velocity` (N, 6) in the
    same order when given: the env and the real-hand controller both order the balls here, so a
    policy sees them alike on either."""
    if cfg.ball_order == "as_simulated":
        swap = np.zeros(len(balls), dtype=bool)
    else:
        axes = palm_frame(cfg.hand)  # columns: normal, across, along fingers
        spawn = np.subtract(*cfg.spawn_offsets[::-1]) @ axes
        start = np.arctan2(spawn[2], spawn[1]) + cfg.direction * np.deg2rad(ORDER_WINDOW_START_DEG)
        swap = observation.canonical_swap(balls, axes[:, 1:3], float(start), cfg.direction)
    shown = observation.swap_balls(balls, swap)
    return shown if velocity is None else np.concatenate([shown, observation.swap_balls(velocity, swap)], axis=1)


# --- batches of observations (arrays, or the 'tactile' mode's dicts) ----------------------
def obs_row(obs, i):
    return {k: v[i] for k, v in obs.items()} if isinstance(obs, dict) else obs[i]


def copy_obs(obs):
    """A copy of an observation (the 'tactile' mode's dict may hold the Warp skin's tensors)."""
    if isinstance(obs, dict):
        return {k: v.copy() if isinstance(v, np.ndarray) else v.clone() for k, v in obs.items()}
    return obs.copy()


def assign_obs(obs, ids, new) -> None:
    if isinstance(obs, dict):
        for k in obs:
            obs[k][ids] = new[k]
    else:
        obs[ids] = new
