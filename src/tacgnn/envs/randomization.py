"""A hand as uncertain as a real one: domain randomisation, and the hand's motors and encoders.

Two parts, both drawn per env at every reset from the env's own stream:

* the physics (`randomize_physics`): ball mass, friction, gravity, and per joint the drive's
  stiffness and damping (log-uniform: an identified value can be off by a factor of several),
  torque limit, joint friction (frictionloss) and armature;
* what lies between the policy and the joints (`HandIO`): action latency, action noise, and the
  encoders' latency, noise, bias and backlash. Skin latency is served by the env, which keeps
  the skin's frames.

Ranges default to at least the authors' released task config (damping x[0.3, 3], stiffness
x[0.75, 1.5], mass x[0.5, 1.5] of 0.15 kg, friction x[0.7, 1.3], observation noise 0.002 and
action noise 0.05) and the paper's gravity 7-12 m/s^2. `RandomizationConfig.nominal` gives the
ranges collapsed onto the nominal hand, from which the robustness table moves one at a time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from tacgnn.config import check
from tacgnn.envs.observation import keep_near
from tacgnn.hand.allegro import NUM_JOINTS
from tacgnn.sim.scene import sphere_inertia

Range = tuple[float, float]
#: Ranges drawn log-uniformly (factors); the others uniformly.
LOG_UNIFORM = ("stiffness_scale", "damping_scale", "armature_scale")
#: Latencies (s), each a whole number of physics steps.
LATENCIES = ("action_latency", "joint_latency", "skin_latency")
#: Per-joint ranges (16 draws each), in draw order after the per-env ones.
PER_JOINT = ("stiffness_scale", "damping_scale", "torque_limit_scale", "joint_friction", "armature_scale",
             "backlash", "joint_bias")
PER_ENV = ("ball_mass", "friction_scale", "gravity", *LATENCIES)
RANGES = (*PER_ENV, *PER_JOINT)
#: Uniforms each range takes per reset, in draw order: one per ball, per env or per joint.
WIDTHS = {"ball_mass": 2, **{name: 1 for name in PER_ENV[1:]}, **{name: NUM_JOINTS for name in PER_JOINT}}
MAX_FORCE_FACTOR = 1e3  # no factor on a physical value beyond this: the simulation would diverge


@dataclass(frozen=True)
class RandomizationConfig:
    """Per-env hand and world drawn at every reset. Off: the nominal hand (every range ignored)."""

    enabled: bool = False
    ball_mass: Range = (0.075, 0.225)
    """kg: x[0.5, 1.5] of the 0.15 kg ball (authors); the paper's 0.1-0.2 lies inside."""
    friction_scale: Range = (0.7, 1.3)
    gravity: Range = (7.0, 12.0)
    """m/s^2, the paper's range."""
    stiffness_scale: Range = (0.75, 1.5)
    """Per joint, log-uniform factor on the drive's stiffness (authors' config)."""
    damping_scale: Range = (0.3, 3.0)
    """Per joint, log-uniform factor on the joint damping (authors' config)."""
    torque_limit_scale: Range = (0.8, 1.2)
    """Per joint factor on `hand.torque_limit`: motors of one model differ."""
    joint_friction: Range = (0.0, 0.03)
    """Per joint dry friction (N m, MuJoCo's frictionloss); the authors' drive has 0.01."""
    armature_scale: Range = (0.5, 2.0)
    """Per joint, log-uniform factor on the rotor inertia `hand.armature`."""
    action_latency: Range = (0.0, 0.04)
    """s from a policy's action to the motors, a whole number of physics steps."""
    joint_latency: Range = (0.0, 0.02)
    """s by which the joint readings lag the joints (a whole number of physics steps)."""
    skin_latency: Range = (0.0, 0.02)
    """s by which a skin frame arrives late; the policy sees the newest frame that has arrived."""
    backlash: Range = (0.0, 0.02)
    """Per joint dead band (rad) of the joint reading: it moves only once the joint has moved
    half the band past it."""
    joint_bias: Range = (-0.01, 0.01)
    """Per joint encoder offset (rad), fixed for an episode."""
    joint_noise: float = 0.005
    """Std (rad) of the white noise on each joint reading (authors' observation noise 0.002 on
    scaled readings is ~0.003 rad)."""
    velocity_noise: float = 0.1
    """Std (rad/s) of the white noise on each joint velocity reading."""
    action_noise: float = 0.05
    """Std of the white noise on each action (in [-1, 1] units), the authors' value."""
    joint_common: float = 0.0
    """Share of hands whose log-uniform per-joint factors (stiffness, damping, armature) are each one
    draw common to all joints (motors, or an identification, off together, as the robustness table's
    rows); the other hands draw per joint. 0: every hand per joint, as the authors draw, where a
    whole hand at x3 damping never occurs."""

    def __post_init__(self) -> None:
        for name in RANGES:
            lo, hi = getattr(self, name)
            key = f"randomization.{name}"
            check(lo <= hi, key, f"needs low <= high, got ({lo}, {hi})")
            if name == "joint_bias":
                check(-1 <= lo and hi <= 1, key, f"must lie in [-1, 1] rad, got ({lo}, {hi})")
            elif name in LATENCIES:
                check(0 <= lo and hi <= 1, key, f"must lie in [0, 1] s, got ({lo}, {hi})")
            elif name in ("joint_friction", "backlash"):
                check(0 <= lo and hi <= 1, key, f"must lie in [0, 1], got ({lo}, {hi})")
            elif name == "gravity":
                check(0 < lo and hi <= 100, key, f"must lie in (0, 100] m/s^2, got ({lo}, {hi})")
            else:
                check(0 < lo and hi <= MAX_FORCE_FACTOR, key, f"needs 0 < low <= high <= {MAX_FORCE_FACTOR}, "
                      f"got ({lo}, {hi})")
        check(0 <= self.joint_common <= 1, "randomization.joint_common", f"must be in [0, 1], got {self.joint_common}")
        for name in ("joint_noise", "velocity_noise", "action_noise"):
            value = getattr(self, name)
            check(0 <= value <= 10, f"randomization.{name}", f"must be in [0, 10], got {value}")

    def check_latencies(self, timestep: float) -> None:
        """Each latency a whole number of physics steps of `timestep` s."""
        for name in LATENCIES:
            for value in getattr(self, name):
                steps = value / timestep
                check(abs(steps - round(steps)) < 1e-6, f"randomization.{name}",
                      f"must be a whole number of physics steps (sim.timestep {timestep} s), got {value}")

    @classmethod
    def nominal(cls, ball_mass: float, /, **changes: Any) -> RandomizationConfig:
        """Enabled, every range collapsed onto the nominal hand (ball mass `ball_mass`, gravity 9.81,
        factors 1, no latency, friction, backlash or noise), then `changes` (e.g. damping_scale=(3, 3))."""
        points: dict[str, Any] = {f.name: (1.0, 1.0) for f in fields(cls) if f.name in RANGES}
        points.update(ball_mass=(ball_mass, ball_mass), gravity=(9.81, 9.81), joint_friction=(0.0, 0.0),
                      backlash=(0.0, 0.0), joint_bias=(0.0, 0.0), **{k: (0.0, 0.0) for k in LATENCIES})
        base = replace(cls(enabled=True, joint_noise=0.0, velocity_noise=0.0, action_noise=0.0), **points)
        return replace(base, **changes)

    def draws_per_reset(self) -> int:
        """Uniforms per reset: the ranges', then (with `joint_common`) whether the hand's factors are
        common, and one draw per log-uniform factor."""
        return sum(WIDTHS.values()) + (1 + len(LOG_UNIFORM) if self.joint_common > 0 else 0)


def draw_ranges(cfg: RandomizationConfig, u: np.ndarray) -> dict[str, np.ndarray]:
    """Each range's values for uniforms `u` (n, draws_per_reset) in [0, 1): ball_mass (n, 2), the
    other per-env values (n,), the per-joint ones (n, 16)."""
    out, start = {}, 0
    common = sum(WIDTHS.values())  # the common hands' draws come last: the coin, then one per factor
    whole_hand = u[:, common, None] < cfg.joint_common if cfg.joint_common > 0 else None
    for name in RANGES:
        lo, hi = getattr(cfg, name)
        x = u[:, start:start + WIDTHS[name]]
        start += WIDTHS[name]
        if name in LOG_UNIFORM:
            if whole_hand is not None:
                x = np.where(whole_hand, u[:, common + 1 + LOG_UNIFORM.index(name), None], x)
            value = np.exp(math.log(lo) + (math.log(hi) - math.log(lo)) * x)
        else:
            value = lo + (hi - lo) * x
        out[name] = value[:, 0] if WIDTHS[name] == 1 else value
    return out


def randomize_physics(env: Any, ids: np.ndarray, drawn: dict[str, np.ndarray]) -> None:
    """Set the physics of envs `ids` of a Baoding env from `drawn` (`draw_ranges`).

    Friction is scaled on every geom; the balls' geoms have contact priority, so the balls'
    scaled friction is what their contacts with the hand use.
    """
    cfg, sim, model, hand = env.config, env.sim, env.model, env.config.hand
    mass = drawn["ball_mass"]
    sim.expand("body_mass")[np.ix_(ids, env.ball_body)] = mass
    sim.expand("body_inertia")[np.ix_(ids, env.ball_body)] = sphere_inertia(mass, cfg.ball_radius)[..., None]
    sim.expand("geom_friction")[ids, :, 0] = model.geom_friction[:, 0] * drawn["friction_scale"][:, None]
    sim.expand("opt.gravity")[ids] = np.stack([np.zeros(len(ids)), np.zeros(len(ids)), -drawn["gravity"]], axis=1)
    kp = np.asarray(hand.joint_stiffness()) * drawn["stiffness_scale"]
    sim.expand("actuator_gainprm")[ids, :, 0] = kp
    sim.expand("actuator_biasprm")[ids, :, 1] = -kp
    dofs = np.ix_(ids, env.joint_dof_adr)
    sim.expand("dof_damping")[dofs] = np.asarray(hand.joint_damping()) * drawn["damping_scale"]
    sim.expand("dof_frictionloss")[dofs] = drawn["joint_friction"]
    sim.expand("dof_armature")[dofs] = hand.armature * drawn["armature_scale"]
    limit = np.asarray(hand.joint_torque_limit()) * drawn["torque_limit_scale"]
    sim.expand("actuator_forcerange")[ids] = np.stack([-limit, limit], axis=-1)
    sim.set_const(ids)  # the mass matrix (dof_M0) follows the balls' masses and the armature


class HandIO:
    """The motors' and encoders' side of a real hand, per env: what the policy's actions go through
    on the way to the joints, and what the joints' readings go through on the way back.

    Actions: noise, then a latency of `action_latency` physics steps (the motors keep the last
    target that has arrived). Readings: the state `joint_latency` ago (interpolated between the
    last two control steps), through a backlash dead band, plus a fixed bias and white noise.
    With randomisation off it passes everything through unchanged and draws nothing.

    Shapes (N envs, S physics steps per control step): targets (N, 16); readings (N, 16).
    """

    STATE = ("action_delay", "joint_delay", "skin_delay", "backlash", "bias", "targets", "previous_q",
             "previous_qd", "read_q", "read_qd", "noisy_q")

    def __init__(self, cfg: RandomizationConfig, num_envs: int, substeps: int, timestep: float, control_dt: float):
        self.cfg, self.substeps = cfg, substeps
        self.enabled = cfg.enabled
        n = num_envs
        latest = round(cfg.action_latency[1] / timestep) if cfg.enabled else 0
        self.history = int(math.ceil(latest / substeps)) + 1  # targets kept: the newest and the late ones
        self.skin_frames = int(math.ceil(round(cfg.skin_latency[1] / timestep) / substeps))  # most frames late
        self.timestep, self.control_dt = timestep, control_dt
        self.action_delay = np.zeros(n, np.int64)  # physics steps
        self.joint_delay = np.zeros(n)  # control steps (fraction)
        self.skin_delay = np.zeros(n, np.int64)  # frames
        self.backlash = np.zeros((n, NUM_JOINTS))
        self.bias = np.zeros((n, NUM_JOINTS))
        self.targets = np.zeros((n, self.history, NUM_JOINTS))  # newest first
        self.previous_q = np.zeros((n, NUM_JOINTS))
        self.previous_qd = np.zeros((n, NUM_JOINTS))
        self.read_q = np.zeros((n, NUM_JOINTS))
        self.read_qd = np.zeros((n, NUM_JOINTS))
        self.noisy_q = np.zeros((n, NUM_JOINTS))  # what the policy reads: read_q + bias + noise

    @property
    def has_latency(self) -> bool:
        return self.enabled and bool(self.action_delay.any())

    def reset(self, ids: np.ndarray, drawn: dict[str, np.ndarray], target: np.ndarray, q: np.ndarray,
              qd: np.ndarray) -> None:
        """Envs `ids` start holding `target` (len(ids), 16) at joints `q`, `qd`, with the latencies,
        backlash and bias of `drawn` (`draw_ranges`)."""
        self.targets[ids] = target[:, None]
        if not self.enabled:
            return
        self.action_delay[ids] = np.rint(drawn["action_latency"] / self.timestep).astype(np.int64)
        self.joint_delay[ids] = np.rint(drawn["joint_latency"] / self.timestep) * self.timestep / self.control_dt
        skin_steps = np.rint(drawn["skin_latency"] / self.timestep)
        self.skin_delay[ids] = np.ceil(skin_steps / self.substeps).astype(np.int64)
        self.backlash[ids] = drawn["backlash"]
        self.bias[ids] = drawn["joint_bias"]
        self.previous_q[ids], self.previous_qd[ids] = q, qd
        self.read_q[ids], self.read_qd[ids] = q, qd
        self.noisy_q[ids] = q + self.bias[ids]

    def command(self, actions: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The actions the motors are sent: `actions` (N, 16) plus noise, clipped to [-1, 1]."""
        if not self.enabled or self.cfg.action_noise == 0:
            return actions
        return np.clip(actions + self.cfg.action_noise * rng.standard_normal(actions.shape), -1.0, 1.0)

    def banded(self, target: np.ndarray, q: np.ndarray, band: float, ranges: np.ndarray) -> np.ndarray:
        """`target` (N, 16) kept within `band` rad of the angles the joints read now (true `q` when off),
        then inside `ranges` (16, 2): the real controller's `max_step_rad`. Unchanged when `band` is 0."""
        if band == 0:
            return target
        near = keep_near(target, self.noisy_q if self.enabled else q, band)
        return np.clip(near, ranges[:, 0], ranges[:, 1])

    def push(self, target: np.ndarray) -> None:
        """A new control step's joint targets (N, 16)."""
        self.targets[:, 1:] = self.targets[:, :-1]
        self.targets[:, 0] = target

    def target_at(self, substep: int) -> np.ndarray:
        """(N, 16) targets the motors hold during physics step `substep` of this control step."""
        return self.targets[:, 0] if not self.enabled else self._arrived(np.array([substep]))[:, 0]

    def targets_of_step(self) -> np.ndarray:
        """(N, S, 16) targets the motors hold during each physics step of this control step."""
        if not self.enabled:
            return np.repeat(self.targets[:, :1], self.substeps, axis=1)
        return self._arrived(np.arange(self.substeps))

    def _arrived(self, substeps: np.ndarray) -> np.ndarray:
        """(N, len(substeps), 16): during each physics step in `substeps`, the newest target that has
        arrived, sent ceil((delay - substep) / S) control steps ago."""
        back = np.maximum(0, -((substeps[None, :] - self.action_delay[:, None]) // self.substeps))
        return self.targets[np.arange(len(back))[:, None], np.minimum(back, self.history - 1)]

    def observe(self, q: np.ndarray, qd: np.ndarray, rng: np.random.Generator) -> None:
        """Advance the readings by one control step to the joints' true `q`, `qd` (N, 16)."""
        if not self.enabled:
            return
        late = self.joint_delay[:, None]
        q_seen = q + late * (self.previous_q - q)
        qd_seen = qd + late * (self.previous_qd - qd)
        self.previous_q[...], self.previous_qd[...] = q, qd
        half = self.backlash / 2
        self.read_q = np.clip(self.read_q, q_seen - half, q_seen + half)  # the dead band follows the joint
        noise = rng.standard_normal((2, *q.shape))
        self.read_qd = qd_seen + self.cfg.velocity_noise * noise[1]
        self.noisy_q = self.read_q + self.bias + self.cfg.joint_noise * noise[0]

    def readings(self, ids: Any, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The joint readings (positions, velocities) of envs `ids`; the true `q`, `qd` when off."""
        if not self.enabled:
            return q, qd
        return self.noisy_q[ids], self.read_qd[ids]

    def state_dict(self) -> dict[str, Any]:
        return {name: getattr(self, name).copy() for name in self.STATE}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for name in self.STATE:
            getattr(self, name)[...] = state[name]
