"""The Baoding-balls task: rotate two balls 180 degrees around each other in a palm-up hand.

One file, in the shape of MuJoCo Playground's tasks: a config, the batched env class
(reset, step, observation, reward terms, termination), domain randomisation beside it.
Rules follow the TacGNN paper and its authors' code (see docs/environment.md):

* Observation (54): joint positions scaled to [-1, 1] (16), 0.2 x joint velocities (16),
  ball positions (6; by `obs_mode`), last action (16). ``finger_torque`` replaces the ball
  positions by the 16 actuator torques (64 values); ``tactile`` returns a dict with the
  raw skin output instead of ball positions.
* Action (16): absolute joint targets, [-1, 1] mapped onto each joint's range.
* Angle: of the vector from ball 0 to ball 1 in the palm plane, unwrapped, signed by
  `direction`. Reward = 0.5 x (angle change, deg) - 0.0002 |a|^2, +250 on success,
  -100 when a ball falls, -50 on timeout (named terms in ``info["reward_terms"]``; an
  optional per-step alive bonus and a cap on the rewarded turn per step, both off by default).
* Tasks: simple (succeed at `success_angle_deg`), middle (plus a random-direction
  force ~ N(0, 0.1) N on each ball every 10 steps), hard (middle, then hold 5 steps),
  hold (simple, then 1 s in the hand), continuous (turn for 10 s; with ``ball_order:
  canonical`` the balls are shown in an order that ignores which is which, so that the
  state after each half turn looks like the start).

Ball positions, skin readings and taxel positions are all taken at one instant, the
start of the last physics substep of the control step, so that a perception model's
input and its label match exactly.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.vector import AutoresetMode

from tacgnn.config import ConfigError, check, check_seed
from tacgnn.envs import observation
from tacgnn.envs.base import HandEnvBase
from tacgnn.envs.observation import track_ball_identities  # noqa: F401  (its home before observation.py)
from tacgnn.envs.randomization import HandIO, RandomizationConfig, draw_ranges, randomize_physics
from tacgnn.hand.allegro import FINGER_RANGES, NUM_JOINTS, THUMB_BAODING_RANGES, HandConfig
from tacgnn.hand.skin_layout import SkinLayout, default_skin
from tacgnn.sim.backend import SkinArray, skin_positions, skin_readings
from tacgnn.sim.scene import SimConfig, add_sphere, hand_scene, palm_frame, sphere_inertia
from tacgnn.sim.skin_signal import SkinSignal, SkinSignalConfig

log = logging.getLogger(__name__)

EnvIds = np.ndarray | slice  # rows of envs: an index array, or a slice (rows as views)
ObsMode = Literal["groundtruth", "no_perception", "finger_torque", "noise_2", "noise_4",
                  "noise_10", "perceived", "tactile"]
# Uniform noise (m) on the ball positions for the paper's NOISE_* ablations; the authors'
# code used +-2, +-5 and +-10 mm for NOISE_2, NOISE_4 and NOISE_10.
ABLATION_NOISE = {"noise_2": 0.002, "noise_4": 0.005, "noise_10": 0.010}
BAODING_RANGES = FINGER_RANGES * 3 + THUMB_BAODING_RANGES
BALLS = ("ball_0", "ball_1")
BALL_CONTACTS = 4  # strongest contacts of each ball that its contact sensor reports
_FOUND_AND_FORCE = ((1 << int(mujoco.mjtConDataField.mjCONDATA_FOUND))
                    | (1 << int(mujoco.mjtConDataField.mjCONDATA_FORCE)))
_STRONGEST_FIRST = 2  # the contact sensor's 'maxforce' reduction
SPAWN_TRIES = 20
ORDER_WINDOW_START_DEG = -20.0
"""'canonical' ball order: the half turn shown starts this far (in the task direction) from the
spawn points' ball-to-ball angle, so that the spawn noise (up to about 20 deg) rarely puts a
start on the other side of the cut and the start looks as it did in the 180-degree tasks."""


@dataclass(frozen=True)
class RewardConfig:
    rotation: float = 0.5
    """Per degree of rotation in the task's direction."""
    action: float = -0.0002
    """Times |a|^2."""
    success: float = 250.0
    fall: float = -100.0
    timeout: float = -50.0
    squeeze: float = -0.05
    """Per newton of each ball contact's normal force above `squeeze_free_force` (not in the paper:
    without it the policies squeeze the balls with 15-35 N, far beyond what holding them needs)."""
    squeeze_free_force: float = 5.0
    """Contact force (N) a ball may feel without penalty: 30 times its weight."""
    squeeze_peak: bool = False
    """Charge `squeeze` on each contact slot's largest force over the control step's physics
    substeps instead of its force at the step's end, so that a short impact between control
    steps (a ball landing on a fingertip) is seen; the physics is then stepped one substep per
    call (same trajectory, a little slower)."""
    squeeze_tail: float = 0.0
    """Per newton of each ball contact's normal force above `squeeze_tail_force`, on top of
    `squeeze` (not in the paper): a steep second hinge that charges the grip's tail (the hand's
    target is a 99th percentile of 10 N) while the ordinary grip pays only `squeeze`; 0: off."""
    squeeze_tail_force: float = 8.0
    """Contact force (N) where `squeeze_tail` starts."""
    action_rate: float = -0.001
    """Times |a_t - a_(t-1)|^2 (not in the paper): a real motor does not follow targets flipped
    end to end every 20 ms, and a policy that does that leans on the simulator's ideal drive."""
    effort: float = -0.002
    """Times sum over joints of (torque / nominal torque limit)^2 (not in the paper): a hand that
    holds its motors at the limit has no margin for a weaker motor or a stiffer joint."""
    alive: float = 0.0
    """Per step that ends with both balls in the hand (not in the paper; for the continuous
    task, where staying in the hand is worth more than one fast half turn)."""
    rotation_cap_deg: float = 0.0
    """Degrees per step above which turning earns no more rotation reward; 0: no cap (not in
    the paper: a capped rate rewards a steady turn over a flick)."""

    def __post_init__(self) -> None:
        check(self.alive >= 0, "reward.alive", f"must be >= 0, got {self.alive}")
        for name in ("action_rate", "effort"):
            check(-1e3 <= getattr(self, name) <= 0, f"reward.{name}",
                  f"is a cost: must be in [-1000, 0], got {getattr(self, name)}")
        check(self.squeeze_tail <= 0, "reward.squeeze_tail", f"is a penalty: must be <= 0, got {self.squeeze_tail}")
        check(self.squeeze_tail_force >= self.squeeze_free_force, "reward.squeeze_tail_force",
              f"must be >= reward.squeeze_free_force ({self.squeeze_free_force} N), got {self.squeeze_tail_force}")
        check(self.rotation_cap_deg >= 0, "reward.rotation_cap_deg",
              f"must be >= 0 (0: no cap), got {self.rotation_cap_deg}")


@dataclass(frozen=True)
class BaodingConfig:
    num_envs: int = 64
    task: Literal["simple", "middle", "hard", "hold", "continuous"] = "simple"
    """simple: reach the angle; middle: with disturbing kicks; hard: middle, then hold `hold_steps`;
    hold: simple, then keep both balls in the hand `long_hold_steps` (1 s); continuous: turn as far
    as possible in `continuous_seconds` (no success, a fall ends the episode)."""
    obs_mode: ObsMode = "groundtruth"
    hand: HandConfig = field(default_factory=lambda: HandConfig(joint_ranges=BAODING_RANGES))
    skin: SkinLayout = field(default_factory=default_skin)
    skin_signal: SkinSignalConfig = field(default_factory=SkinSignalConfig)
    """What the skin reads like: 'real' (a resistive array and its calibration) or 'ideal'."""
    sim: SimConfig = field(default_factory=SimConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    randomization: RandomizationConfig = field(default_factory=RandomizationConfig)
    control_dt: float = 0.02
    max_episode_steps: int = 200
    """Step limit of the 180-degree tasks (the continuous task's is `continuous_seconds`)."""
    continuous_seconds: float = 10.0
    """Length of a continuous-task episode (s): a whole number of control steps."""
    continuous_disturbances: bool = False
    """Continuous task: the Middle task's kicks on the balls."""
    ball_order: Literal["as_simulated", "canonical"] = "as_simulated"
    """Order of the two balls in the observation. 'as_simulated': ball 0 first (the paper's).
    'canonical': the order that does not depend on which ball is which (see
    `observation.canonical_ball_order`), so that the state after a half turn looks like the
    start and a continuous turn is one skill repeated; the critic's ground truth follows it."""
    ball_radius: float = 0.02625
    ball_mass: float = 0.15
    ball_friction: float = 1.0
    spawn_offsets: tuple[tuple[float, float, float], tuple[float, float, float]] = (
        (0.028, -0.01, 0.05), (-0.028, -0.01, 0.05))
    """Ball centres at reset relative to the hand origin (world frame, m)."""
    spawn_noise: float = 0.01
    """Uniform +- noise (m) on each ball's x and y at reset."""
    spawn_clearance: float = 0.001
    """Least gap (m) between a spawned ball and the other ball or any link; closer draws are redrawn."""
    initial_joint_pos: tuple[float, ...] = (
        -0.15, 0.9, 0.9, 0.6, 0.0, 0.9, 0.9, 0.6, 0.15, 0.9, 0.9, 0.6, 0.8, 0.2, 0.85, 0.5)
    """A cupped pose: index and ring turned towards the middle so the balls cannot roll off."""
    joint_noise: float = 0.03
    """Uniform +- noise (rad) on the initial joint positions (clipped to the ranges)."""
    success_angle_deg: float = 180.0
    direction: int = 1
    """+1: counter-clockwise seen from above the palm; -1: clockwise."""
    disturbance_interval: int = 10
    disturbance_std: float = 0.1
    """Std (N) of the disturbing force's magnitude on each ball, middle and hard tasks."""
    hold_steps: int = 5
    """Steps both balls must stay in the hand after the angle on the Hard task (the paper's 5)."""
    long_hold_steps: int = 50
    """... and on the 'hold' task: 1 s at 50 Hz, long enough that a flick past the angle fails."""
    fall_height: tuple[float, float] = (0.0, 0.065)
    """A ball has fallen when its centre's height above the palm plane leaves this band (m)
    (at rest it is 0.037): lifting a ball by more than one radius ends the episode, so a
    policy cannot toss a ball or pass it over the other to rack up the angle."""
    fall_radius: float = 0.13
    """... or its distance from the palm centre along the palm exceeds this (m)."""
    tactile: bool = True
    """Compute the skin every step (needed by 'tactile' and 'perceived' observations)."""
    ball_velocity: bool = False
    """Also show the balls' velocities (m/s, 6 values after the positions, in the same ball order):
    the change of the shown positions (true, or perceived with identities tracked) over the last
    control step, zero at an episode's start. One frame of positions does not say where a rolling
    ball is heading. 'groundtruth' and 'perceived' (the privileged critic sees the true ones), and
    'tactile', whose `groundtruth_obs` (a policy recording a dataset) then shows them."""
    track_balls: bool = True
    """'perceived': give the two predicted balls the identities that keep each nearest to where
    it was perceived one step before (starting from the spawn positions at reset). The balls
    look alike, so a skin model can only say where two balls are, not which is which; the
    policy, trained on ground truth, expects ball 0 to stay ball 0 while they swap places."""
    seed: int = 0

    def __post_init__(self) -> None:
        check(1 <= self.num_envs <= 65_536, "num_envs", f"must be in 1..65536, got {self.num_envs}")
        check_seed(self.seed)
        check(self.max_episode_steps >= 1, "max_episode_steps", "must be >= 1")
        substeps = self.control_dt / self.sim.timestep
        whole = round(substeps) >= 1 and abs(substeps - round(substeps)) < 1e-6
        check(0 < self.control_dt <= 1 and whole, "control_dt",
              f"must be a whole multiple of sim.timestep ({self.sim.timestep} s) in (0, 1] s, got {self.control_dt}")
        steps = self.continuous_seconds / self.control_dt if self.control_dt > 0 else 0.0
        check(self.continuous_seconds > 0 and abs(steps - round(steps)) < 1e-6, "continuous_seconds",
              f"must be a positive whole number of control steps (control_dt {self.control_dt} s), "
              f"got {self.continuous_seconds}")
        check(self.ball_radius > 0, "ball_radius", f"must be positive, got {self.ball_radius}")
        # MuJoCo refuses a moving body whose mass or inertia is below mjMINVAL (at compile, or
        # silently misbehaves when randomisation sets it later)
        key, lightest = "ball_mass", self.ball_mass
        if self.randomization.enabled and self.randomization.ball_mass[0] < lightest:
            key, lightest = "randomization.ball_mass", self.randomization.ball_mass[0]
        check(lightest > mujoco.mjMINVAL, key,
              f"must be above MuJoCo's smallest mass ({mujoco.mjMINVAL} kg), got {lightest}")
        check(sphere_inertia(lightest, self.ball_radius) > mujoco.mjMINVAL, "ball_radius",
              f"{self.ball_radius} m gives a {lightest} kg ball an inertia below MuJoCo's smallest "
              f"({mujoco.mjMINVAL} kg m^2)")
        check(self.ball_friction > 0, "ball_friction", "must be positive")
        check(len(self.initial_joint_pos) == NUM_JOINTS, "initial_joint_pos", "needs 16 values")
        check(self.success_angle_deg > 0, "success_angle_deg", "must be positive")
        check(self.direction in (1, -1), "direction", "must be +1 or -1")
        check(self.ball_order in ("as_simulated", "canonical"), "ball_order",
              f"must be 'as_simulated' or 'canonical', got {self.ball_order!r}")
        check(self.disturbance_interval >= 1, "disturbance_interval", "must be >= 1")
        check(self.disturbance_std >= 0, "disturbance_std", "must be >= 0")
        check(self.hold_steps >= 0, "hold_steps", "must be >= 0")
        check(self.long_hold_steps >= 0, "long_hold_steps", "must be >= 0")
        check(self.fall_height[0] < self.fall_height[1], "fall_height", "needs low < high")
        check(self.spawn_noise >= 0, "spawn_noise", f"must be >= 0, got {self.spawn_noise}")
        check(self.joint_noise >= 0, "joint_noise", f"must be >= 0, got {self.joint_noise}")
        check(not self.ball_velocity or self.obs_mode in ("groundtruth", "perceived", "tactile"), "ball_velocity",
              f"shows the velocities of the balls the observation shows: 'groundtruth' or 'perceived' "
              f"('tactile': in its ground-truth view), not '{self.obs_mode}'")
        if self.randomization.enabled:
            self.randomization.check_latencies(self.sim.timestep)
        check(self.tactile or self.obs_mode not in ("tactile", "perceived"), "tactile",
              f"obs_mode '{self.obs_mode}' needs tactile: true")


class BaodingEnv(HandEnvBase, gym.vector.VectorEnv):
    """`num_envs` Baoding envs stepped together; gymnasium VectorEnv, same-step autoreset.

    ``step`` returns the first observation of the next episode for envs that ended;
    their last observation is in ``info["final_obs"]`` (rows where ``info["_final_obs"]``).
    ``info`` also holds per-env arrays: ``reward_terms``, ``angle_deg``, ``success``,
    ``fall``, ``timeout``, ``diverged``, ``ball_pos`` (N, 2, 3), with the skin on
    ``tactile`` (N, T), and in the 'tactile' and 'perceived' modes ``taxel_pos``
    (N, T, 3), all of the step just taken (before any reset). The skin's arrays (there and
    in the 'tactile' observation) are numpy on the C engine and torch tensors on the Warp
    engine's device, which they never leave unless a consumer asks (`skin_to_host`).
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_fps": 50}

    def __init__(self, config: BaodingConfig | None = None,
                 perception: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None):
        cfg = config or BaodingConfig()
        self.config = cfg
        self._obs_uses_skin = cfg.obs_mode in ("tactile", "perceived")
        spec = hand_scene(cfg.hand, cfg.sim)
        for name, offset, rgba in zip(BALLS, cfg.spawn_offsets, ((0.85, 0.3, 0.2, 1), (0.2, 0.4, 0.85, 1))):
            add_sphere(spec, name, cfg.ball_radius, cfg.ball_mass, offset, cfg.ball_friction, rgba)
            spec.add_sensor(name=f"{name}_contacts", type=mujoco.mjtSensor.mjSENS_CONTACT,
                            objtype=mujoco.mjtObj.mjOBJ_BODY, objname=name,
                            intprm=[_FOUND_AND_FORCE, _STRONGEST_FIRST, BALL_CONTACTS])
        HandEnvBase.__init__(self, spec, cfg.hand, cfg.skin, cfg.sim, cfg.num_envs, cfg.control_dt)
        self.perception = perception
        bind = getattr(perception, "bind_env", None)
        if bind is not None:  # a perception with memory keeps one state per env: it reads this env's steps
            bind(self)
        m = self.model
        self.ball_body = np.array([m.body(b).id for b in BALLS])
        self.ball_qpos_adr = np.array([m.joint(f"{b}_free").qposadr[0] for b in BALLS])
        self.ball_dof_adr = np.array([m.joint(f"{b}_free").dofadr[0] for b in BALLS])
        self.ball_geom = np.array([m.geom(f"{b}_geom").id for b in BALLS])
        # sensordata columns of each ball contact's normal force (slots of found, fn, ft1, ft2)
        self._ball_force_cols = np.concatenate([m.sensor(f"{b}_contacts").adr[0] + 1 + 4 * np.arange(BALL_CONTACTS)
                                                for b in BALLS])
        self._scratch = mujoco.MjData(m)  # checks spawn points for overlaps
        self.palm_axes = palm_frame(cfg.hand)  # columns: normal, across, along fingers
        self.palm_centre = self.palm_axes @ np.array([0.0, 0.0, -0.0475])
        self._spawn = np.array(cfg.spawn_offsets, dtype=np.float64)  # (2, 3) ball centres at reset
        self.initial_ctrl = np.clip(np.asarray(cfg.initial_joint_pos), *self.target_ranges.T)  # a pose it can hold
        start = m.qpos0.copy()
        start[self.joint_qpos_adr] = self.initial_ctrl
        if self._spawn_overlaps(self._place_balls(start, np.zeros((len(BALLS), 2)))):
            raise ConfigError("config keys 'spawn_offsets' / 'initial_joint_pos' (with 'ball_radius', "
                              "'spawn_clearance', 'hand.palm_tilt_deg', 'hand.joint_ranges'): at the noise-free "
                              "start the balls overlap each other or the hand")

        n = cfg.num_envs
        self.episode_steps = np.zeros(n, np.int64)
        self.angle = np.zeros(n)  # unwrapped, signed by direction, rad
        self.vec_angle = np.zeros(n)  # last wrapped angle of the ball-to-ball vector
        self.hold_count = np.full(n, -1, np.int64)  # >= 0 while holding after reaching the angle
        self.last_action = np.zeros((n, NUM_JOINTS))
        self.perceived_balls = np.zeros((n, 6))  # last perceived positions, identities tracked
        self.true_balls = np.zeros((n, 6))  # true positions at the last step (ball_velocity)
        self.true_velocity = np.zeros((n, 6))  # their change over the last step / control_dt
        self._seed(cfg.seed)
        self.hand_io = HandIO(cfg.randomization, n, self.substeps, cfg.sim.timestep, cfg.control_dt)
        self.skin_signal = SkinSignal(cfg.skin_signal, cfg.skin, n, cfg.control_dt)
        self._nominal_torque_limit = np.asarray(cfg.hand.joint_torque_limit())  # the effort cost's unit
        late = self.hand_io.skin_frames if self._obs_uses_skin and cfg.randomization.enabled else 0
        self._skin_history = None if late == 0 else (  # newest first: what a late frame shows
            np.zeros((n, late + 1, self.tactile.num_taxels), np.float32),
            np.zeros((n, late + 1, self.tactile.num_taxels, 3), np.float32))

        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (NUM_JOINTS,), np.float32)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, n)
        self.single_observation_space = self._make_obs_space()
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, n)
        self._reset_envs(np.arange(n))

    # --- spaces and observations ---------------------------------------------------------
    def _make_obs_space(self) -> gym.Space:
        t = self.tactile.num_taxels
        if self.config.obs_mode == "tactile":
            return gym.spaces.Dict({
                "proprio": gym.spaces.Box(-np.inf, np.inf, (3 * NUM_JOINTS,), np.float32),
                "tactile": gym.spaces.Box(0.0, np.inf, (t,), np.float32),
                "taxel_pos": gym.spaces.Box(-np.inf, np.inf, (t, 3), np.float32),
            })
        dim = 4 * NUM_JOINTS if self.config.obs_mode == "finger_torque" else 3 * NUM_JOINTS + 6
        dim += observation.BALL_VALUES if self.config.ball_velocity else 0
        return gym.spaces.Box(-np.inf, np.inf, (dim,), np.float32)

    @property
    def episode_limit(self) -> int:
        """Steps after which an episode is truncated: `max_episode_steps`, or the continuous task's
        `continuous_seconds` in control steps."""
        cfg = self.config
        if cfg.task == "continuous":
            return int(round(cfg.continuous_seconds / cfg.control_dt))
        return cfg.max_episode_steps

    def ball_positions(self) -> np.ndarray:
        """(N, 2, 3) ball centres relative to the hand origin (world axes, m)."""
        return self.sim.xpos[:, self.ball_body]  # a copy (fancy index)

    def _object_obs(self, ids: EnvIds, tactile: SkinArray | None, taxel_pos: SkinArray | None) -> np.ndarray:
        mode = self.config.obs_mode
        balls = self.ball_positions()[ids].reshape(-1, 6)
        if mode == "groundtruth":
            return self._ordered(balls, self.true_velocity[ids])
        if mode == "no_perception":
            return np.zeros_like(balls)
        if mode == "finger_torque":
            return self.sim.actuator_force[ids]
        if mode in ABLATION_NOISE:
            return self._ordered(balls + self._rng.uniform(-1, 1, balls.shape) * ABLATION_NOISE[mode])
        if mode == "perceived":
            if self.perception is None:
                raise RuntimeError("obs_mode 'perceived' needs a perception model: BaodingEnv(perception=...)")
            joints = self.hand_io.readings(ids, self.joint_pos[ids], self.joint_vel[ids])[0]  # for models that read it
            previous = self.perceived_balls[ids] if self.config.track_balls else None
            assert tactile is not None and taxel_pos is not None  # the config turns the skin on for 'perceived'
            pred = observation.perceive_balls(self.perception, tactile, taxel_pos, joints, previous)
            velocity = None
            if self.config.ball_velocity:
                velocity = observation.ball_velocity(pred, self.perceived_balls[ids], self.episode_steps[ids] == 0,
                                                     self.config.control_dt)
            self.perceived_balls[ids] = pred
            return self._ordered(pred, velocity)
        raise AssertionError(mode)

    def _ordered(self, balls: np.ndarray, velocity: np.ndarray | None = None) -> np.ndarray:
        """(N, 6) ball positions in the config's `ball_order`; with `ball_velocity`, (N, 12): then
        the balls' `velocity` (N, 6) in the same order."""
        return ordered_balls(balls, self.config, velocity if self.config.ball_velocity else None)

    def _observe(self, ids: EnvIds, tactile: SkinArray | None, taxel_pos: SkinArray | None) -> Any:
        q, qd = self.hand_io.readings(ids, self.joint_pos[ids], self.joint_vel[ids])  # as the encoders read them
        lo, hi = self.joint_low, self.joint_high
        if self.config.obs_mode == "tactile":
            proprio = observation.proprioception(q, qd, lo, hi)
            return {"proprio": np.concatenate([proprio, self.last_action[ids]], 1).astype(np.float32),
                    "tactile": tactile, "taxel_pos": taxel_pos}
        obj = self._object_obs(ids, tactile, taxel_pos)
        return observation.assemble(q, qd, obj, self.last_action[ids], lo, hi)

    def groundtruth_obs(self) -> np.ndarray:
        """(N, 54) the 'groundtruth' observation of the current state, whatever the obs mode:
        what a privileged critic reads during training (the actor gets the env's own obs)."""
        balls = self._ordered(self.ball_positions().reshape(self.num_envs, 6), self.true_velocity)
        return observation.assemble(self.joint_pos, self.joint_vel, balls, self.last_action, self.joint_low,
                                    self.joint_high)

    def raw_skin(self) -> np.ndarray:
        """(N, T) what the skin's driver reports now, before any calibration: the real skin's raw
        values (advancing it one frame), or the ideal skin's forces. For the simulated hand behind
        ROS, whose consumer calibrates them as it would a real hand's."""
        forces = self.tactile_readings()
        return forces if self.config.skin_signal.is_ideal else self.skin_signal.raw(forces, slice(None), self._rng)

    def _skin(self, ids: EnvIds) -> tuple[SkinArray | None, SkinArray | None]:
        """Readings of envs `ids`, and taxel positions if the observation needs them.

        Other modes get positions on demand from `taxel_positions()` (same instant,
        until the next step), so a ground-truth run does not pay for them.
        """
        if not self.config.tactile:
            return None, None
        readings = skin_readings(self.tactile, self.sim, ids, self._rng)  # on Warp: from the device arrays
        if not self.config.skin_signal.is_ideal:  # what a real skin and its calibration make of it
            readings = self.skin_signal(self.skin_to_host(readings), ids, self._rng)
        if not self._obs_uses_skin:
            return readings, None
        return readings, skin_positions(self.tactile, self.sim, ids)

    # --- random streams ----------------------------------------------------------------
    def _seed(self, seed: int | None) -> None:
        """One stream for the whole batch (skin noise seeds, observation noise: a fixed
        number of draws per step) and one per env (resets, randomisation, kicks): an env
        that resets or diverges never shifts another env's draws."""
        main, *envs = np.random.SeedSequence(seed).spawn(self.num_envs + 1)
        self._rng = np.random.default_rng(main)
        self._env_rngs = [np.random.default_rng(s) for s in envs]

    def _env_draws(self, ids: np.ndarray, size: int, normal: bool = False) -> np.ndarray:
        """(len(ids), size) uniforms in [0, 1) or standard normals, each row from its env's stream."""
        draw = (lambda g: g.standard_normal(size)) if normal else (lambda g: g.random(size))
        return np.array([draw(self._env_rngs[i]) for i in ids]).reshape(len(ids), size)

    def rng_state(self) -> dict:
        """The random streams' states (plain dicts), for checkpoints that resume bit for bit."""
        return {"main": self._rng.bit_generator.state, "envs": [g.bit_generator.state for g in self._env_rngs]}

    def set_rng_state(self, state: dict) -> None:
        if "envs" not in state:  # a checkpoint from before the per-env streams: one generator
            log.warning("checkpoint has one random stream (older version): the env streams restart "
                        "from the seed, so this resume is not bit-for-bit")
            self._rng.bit_generator.state = state
            return
        if len(state["envs"]) != self.num_envs:
            raise ValueError(f"saved random state has {len(state['envs'])} env streams, this env has {self.num_envs}")
        self._rng.bit_generator.state = state["main"]
        for g, s in zip(self._env_rngs, state["envs"]):
            g.bit_generator.state = s

    # --- state for exact resume --------------------------------------------------------
    # Per-env arrays beyond the physics that `state_dict` saves (a resume test fails if one is missed).
    EPISODE_STATE = ("episode_steps", "angle", "vec_angle", "hold_count", "last_action", "perceived_balls",
                     "true_balls", "true_velocity")

    def state_dict(self) -> dict[str, Any]:
        """Everything that lets this batch continue bit for bit (numpy copies and plain data).

        The MuJoCo batch keeps each env's whole integration state (positions, velocities,
        controls, applied forces, solver warm start) in one row of ``batch.state``; model
        fields made per-env (domain randomisation) are saved too, then the per-env episode
        state (`EPISODE_STATE`) and the random streams.
        """
        from mujoco import batch as mjbatch  # loaded with the sim already

        batch = self.sim.batch
        fields = {name: np.array(values) for name in mjbatch.MODEL_FIELDS
                  if (values := batch.expanded(name)) is not None}
        return {"sim_state": batch.state.copy(), "model_fields": fields,
                "buffers": {name: getattr(self, name).copy() for name in self.EPISODE_STATE},
                "rng": self.rng_state(), "hand_io": self.hand_io.state_dict(),
                "skin_signal": self.skin_signal.state_dict(),
                "skin_history": None if self._skin_history is None else [a.copy() for a in self._skin_history]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what `state_dict` saved, into an env built from the same config.

        Derived fields (xpos, sensors) stay stale until the next step recomputes them; a step
        reads none of them before it does, and calling forward() here would not be
        guaranteed to leave the state (warm start) untouched.
        """
        batch = self.sim.batch
        if tuple(state["sim_state"].shape) != batch.state.shape:
            raise ValueError(f"saved env state has shape {tuple(state['sim_state'].shape)}, "
                             f"this env's is {batch.state.shape} (different num_envs or model)")
        unknown = sorted(set(state["buffers"]) - set(self.EPISODE_STATE))
        if unknown:
            raise ValueError(f"saved env state has buffers this env does not know: {unknown}")
        unused = () if self.config.ball_velocity else ("true_balls", "true_velocity")  # read only with ball_velocity
        missing = [name for name in self.EPISODE_STATE if name not in state["buffers"] and name not in unused]
        if missing:  # a checkpoint of an older version
            log.warning("saved env state lacks %s (older version): they restart from their reset values, "
                        "so this resume is not bit-for-bit", missing)
        batch.state[...] = state["sim_state"]
        for name, values in state["model_fields"].items():
            self.sim.expand(name)[...] = values
        for name, values in state["buffers"].items():
            getattr(self, name)[...] = values
        self.set_rng_state(state["rng"])
        self.hand_io.load_state_dict(state["hand_io"])
        self.skin_signal.load_state_dict(state["skin_signal"])
        if self._skin_history is not None:
            for mine, saved in zip(self._skin_history, state["skin_history"]):
                mine[...] = saved

    # --- reset -------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._seed(seed)
        ids = np.arange(self.num_envs)
        self._reset_envs(ids)
        tactile, taxel_pos = self._late_skin(ids, *self._skin(ids), fresh=True)
        return self._observe(ids, tactile, taxel_pos), {}

    def _reset_envs(self, ids: np.ndarray) -> None:
        cfg, sim = self.config, self.sim
        if len(ids) == 0:
            return
        sim.reset(ids)
        k = NUM_JOINTS + 2 * len(BALLS)  # joint noise, then the balls' x, y shifts
        u = self._env_draws(ids, k)
        q0 = self.initial_ctrl + cfg.joint_noise * (2 * u[:, :NUM_JOINTS] - 1)
        q0 = np.clip(q0, *self.target_ranges.T)
        qpos = sim.qpos[ids]
        qpos[:, self.joint_qpos_adr] = q0
        shift = cfg.spawn_noise * (2 * u[:, NUM_JOINTS:k] - 1).reshape(-1, len(BALLS), 2)
        for row, env_id in enumerate(ids):
            qpos[row] = self._clear_spawn(qpos[row], shift[row], env_id)
        # the hand after the start: the same seed starts the same episode on every hand
        drawn = {}
        if cfg.randomization.enabled:
            drawn = draw_ranges(cfg.randomization, self._env_draws(ids, cfg.randomization.draws_per_reset()))
            randomize_physics(self, ids, drawn)
        sim.qpos[ids] = qpos
        sim.qvel[ids] = 0.0
        sim.ctrl[ids] = q0
        sim.xfrc_applied[ids] = 0.0
        sim.forward(ids)
        self.last_action[ids] = self.ctrl_to_action(q0)
        self.episode_steps[ids] = 0
        self.angle[ids] = 0.0
        self.vec_angle[ids] = self._ball_vector_angle(ids)
        self.hold_count[ids] = -1
        self.perceived_balls[ids] = self._spawn.ravel()  # where the balls are put
        self.true_balls[ids] = self.ball_positions()[ids].reshape(-1, 6)
        self.true_velocity[ids] = 0.0
        self.hand_io.reset(ids, drawn, q0, self.joint_pos[ids], self.joint_vel[ids])
        self.skin_signal.reset(ids, [self._env_rngs[i] for i in ids])

    def _place_balls(self, qpos: np.ndarray, shift: np.ndarray) -> np.ndarray:
        for b, adr in enumerate(self.ball_qpos_adr):
            qpos[adr:adr + 3] = self._spawn[b]
            qpos[adr:adr + 2] += shift[b]
            qpos[adr + 3:adr + 7] = (1.0, 0.0, 0.0, 0.0)
        return qpos

    def _clear_spawn(self, qpos: np.ndarray, shift: np.ndarray, env_id: int) -> np.ndarray:
        """`qpos` with the balls placed at the spawn points plus `shift` (2, 2), redrawn from the
        env's stream while a ball would overlap the other ball or a link (at most
        `SPAWN_TRIES` draws; then the noise-free spawn points, which clear the hand at
        construction). A ball that starts inside a link is shot out by the contact solver."""
        for _ in range(SPAWN_TRIES):
            qpos = self._place_balls(qpos, shift)
            if not self._spawn_overlaps(qpos):
                return qpos
            shift = self.config.spawn_noise * (2 * self._env_rngs[env_id].random((len(BALLS), 2)) - 1)
        return self._place_balls(qpos, np.zeros((len(BALLS), 2)))

    def _spawn_overlaps(self, qpos: np.ndarray) -> bool:
        """Whether a ball touches (within `spawn_clearance`) the other ball or a link at `qpos`."""
        m, d = self.model, self._scratch
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        geoms = d.contact.geom[:d.ncon]
        with_ball = np.isin(geoms, self.ball_geom).any(axis=1)
        return bool((d.contact.dist[:d.ncon][with_ball] < self.config.spawn_clearance).any())

    # --- step --------------------------------------------------------------------------
    def step(self, actions: np.ndarray):
        cfg = self.config
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != (self.num_envs, NUM_JOINTS):
            raise ValueError(f"actions must have shape ({self.num_envs}, {NUM_JOINTS}), got {actions.shape}")
        if not np.isfinite(actions).all():
            raise ValueError(f"non-finite actions in envs {np.flatnonzero(~np.isfinite(actions).all(1)).tolist()}")
        actions = np.clip(actions, -1.0, 1.0)
        self.hand_io.push(self.action_to_ctrl(self.hand_io.command(actions, self._rng)))
        self._apply_disturbances()
        diverged, ball_forces = self._step_physics()
        self.episode_steps += 1
        action_change = actions - self.last_action
        self.last_action[:] = actions

        all_ids = slice(None)  # a slice: rows as views, not copies
        if diverged.any():  # keep NaN out of everything computed below; these envs reset
            self._scrub(diverged)
        self.hand_io.observe(self.joint_pos, self.joint_vel, self._rng)
        tactile, taxel_pos = self._skin(all_ids)
        balls = self.ball_positions()
        flat = balls.reshape(self.num_envs, 6)
        self.true_velocity[:] = (flat - self.true_balls) / cfg.control_dt
        self.true_balls[:] = flat
        d_angle = self._update_angle(all_ids)
        fall = self._fallen(balls)
        reached = self.angle >= np.deg2rad(cfg.success_angle_deg) - 1e-9  # float round-off
        success = self._success(reached, fall)
        timeout = (self.episode_steps >= self.episode_limit) & ~success & ~fall
        terms = self._reward_terms(d_angle, actions, action_change, success, fall, timeout, ball_forces)
        reward = sum(terms.values())
        terminated = success | fall | diverged
        truncated = timeout & ~terminated
        # A diverged env's step is not a step: no reward from it.
        reward = np.where(diverged, 0.0, reward)
        for term in terms.values():
            term[diverged] = 0.0

        info: dict[str, Any] = {
            "reward_terms": terms, "angle_deg": np.rad2deg(self.angle), "success": success & ~diverged,
            "fall": fall & ~diverged, "timeout": truncated, "diverged": diverged,
            "episode_steps": self.episode_steps.copy(), "ball_pos": balls,
        }
        if tactile is not None:
            info["tactile"] = tactile
            info["joint_pos"] = self.sim.qpos[:, self.joint_qpos_adr]  # rad, beside each frame of the skin
        if taxel_pos is not None:
            info["taxel_pos"] = taxel_pos
        obs = self._observe(all_ids, *self._late_skin(all_ids, tactile, taxel_pos))
        done = np.flatnonzero(terminated | truncated)
        if len(done):
            info["final_obs"], info["_final_obs"] = obs, terminated | truncated
            obs = _copy_obs(obs)
            self._reset_envs(done)
            new_tactile, new_pos = self._late_skin(done, *self._skin(done), fresh=True) \
                if self._obs_uses_skin else (None, None)
            _assign_obs(obs, done, self._observe(done, new_tactile, new_pos))
        return obs, reward.astype(np.float32), terminated, truncated, info

    def _scrub(self, ids: np.ndarray) -> None:
        """Put diverged envs back at their reset state, so no NaN leaves this step.

        Their episode still ends in this step (with zero reward) and restarts fresh.
        """
        ids = np.flatnonzero(ids)
        self.sim.reset(ids)
        self.sim.qpos[ids] = self.model.qpos0
        self.sim.forward(ids)
        self.vec_angle[ids] = self._ball_vector_angle(ids)

    def _apply_disturbances(self) -> None:
        cfg, xfrc = self.config, self.sim.xfrc_applied
        xfrc[:] = 0.0
        if cfg.task in ("simple", "hold") or (cfg.task == "continuous" and not cfg.continuous_disturbances):
            return
        kick = (self.episode_steps % cfg.disturbance_interval == 0) & (self.episode_steps > 0)
        ids = np.flatnonzero(kick)
        if len(ids) == 0:
            return
        draws = self._env_draws(ids, 4 * len(self.ball_body), normal=True).reshape(len(ids), -1, 4)
        for b, body in enumerate(self.ball_body):
            direction = draws[:, b, :3] / np.linalg.norm(draws[:, b, :3], axis=1, keepdims=True)
            xfrc[ids, body, :3] = direction * (cfg.disturbance_std * draws[:, b, 3:])

    # --- task rules --------------------------------------------------------------------
    def _ball_vector_angle(self, ids: EnvIds) -> np.ndarray:
        balls = self.sim.xpos[ids][:, self.ball_body]
        v = (balls[:, 1] - balls[:, 0]) @ self.palm_axes  # palm coordinates
        return np.arctan2(v[:, 2], v[:, 1])

    def _update_angle(self, ids: EnvIds) -> np.ndarray:
        """Accumulate the wrapped change of the ball-to-ball angle; return it (rad)."""
        new = self._ball_vector_angle(ids)
        delta = (new - self.vec_angle[ids] + np.pi) % (2 * np.pi) - np.pi
        self.vec_angle[ids] = new
        delta *= self.config.direction
        self.angle[ids] += delta
        return delta

    def _fallen(self, balls: np.ndarray) -> np.ndarray:
        rel = (balls - self.palm_centre) @ self.palm_axes  # (N, 2, 3) palm coordinates
        lo, hi = self.config.fall_height
        across = rel[..., 1] ** 2 + rel[..., 2] ** 2
        out = (rel[..., 0] < lo) | (rel[..., 0] > hi) | (across > self.config.fall_radius**2)
        return out.any(axis=1)

    def _success(self, reached: np.ndarray, fall: np.ndarray) -> np.ndarray:
        cfg = self.config
        if cfg.task == "continuous":
            return np.zeros_like(reached)
        if cfg.task not in ("hard", "hold"):
            return reached & ~fall
        holding = self.hold_count >= 0
        self.hold_count[holding] += 1
        self.hold_count[reached & ~holding] = 0
        steps = cfg.hold_steps if cfg.task == "hard" else cfg.long_hold_steps
        return (self.hold_count >= steps) & ~fall

    def ball_contact_forces(self) -> np.ndarray:
        """(N, 2 x BALL_CONTACTS) normal forces (N) of the balls' strongest contacts, 0 where none."""
        return self.sim.sensordata[:, self._ball_force_cols]

    def _step_physics(self) -> tuple[np.ndarray, np.ndarray]:
        """Step one control step; return the diverged mask and the balls' contact forces (N) that
        the squeeze cost reads: at the step's end, or with `reward.squeeze_peak` each contact
        slot's largest over the substeps.

        The targets of `hand_io` reach the motors whole control steps at a time, unless an action
        latency makes them arrive between physics steps: then (and for the peak forces) the physics
        is stepped one substep per call (the same trajectory, a little slower).
        """
        sim, io, peak_wanted = self.sim, self.hand_io, self.config.reward.squeeze_peak
        if not io.has_latency and not peak_wanted:
            sim.ctrl[:] = io.target_at(0)
            return sim.step(self.substeps), self.ball_contact_forces()
        diverged = np.zeros(self.num_envs, bool)
        peak = np.zeros_like(self.ball_contact_forces())  # forces are >= 0
        forces = peak
        for substep in range(self.substeps):
            sim.ctrl[:] = io.target_at(substep)
            diverged |= sim.step(1)
            forces = self.ball_contact_forces()
            np.maximum(peak, forces, out=peak)
        return diverged, peak if peak_wanted else forces

    def _late_skin(self, ids: EnvIds, tactile: SkinArray | None, taxel_pos: SkinArray | None,
                   fresh: bool = False) -> tuple[SkinArray | None, SkinArray | None]:
        """The skin frame the policy sees: the newest that has arrived, `hand_io.skin_delay` frames
        old (skin latency); `fresh` (after a reset) fills the envs' history with this frame."""
        history = self._skin_history
        if history is None or tactile is None or taxel_pos is None:
            return tactile, taxel_pos
        frames, positions = history
        tactile, taxel_pos = self.skin_to_host(tactile), self.skin_to_host(taxel_pos)
        if fresh:
            frames[ids], positions[ids] = tactile[:, None], taxel_pos[:, None]
            return tactile, taxel_pos
        frames[ids, 1:], positions[ids, 1:] = frames[ids, :-1], positions[ids, :-1]
        frames[ids, 0], positions[ids, 0] = tactile, taxel_pos
        rows = np.arange(self.num_envs)[ids]
        late = self.hand_io.skin_delay[rows]
        return frames[rows, late], positions[rows, late]

    def _reward_terms(self, d_angle, actions, action_change, success, fall, timeout,
                      ball_forces) -> dict[str, np.ndarray]:
        w = self.config.reward
        effort = self.sim.actuator_force / self._nominal_torque_limit
        return {
            "rotation": w.rotation * _capped(np.rad2deg(d_angle), w.rotation_cap_deg),
            "action": w.action * np.sum(actions**2, axis=1),
            "action_rate": w.action_rate * np.sum(action_change**2, axis=1),
            "effort": w.effort * np.sum(effort**2, axis=1),
            "success": w.success * success,
            "fall": w.fall * fall,
            "timeout": (0.0 if self.config.task == "continuous" else w.timeout) * timeout,  # 10 s is the goal there
            "squeeze": w.squeeze * np.maximum(ball_forces - w.squeeze_free_force, 0.0).sum(axis=1),
            "squeeze_tail": w.squeeze_tail * np.maximum(ball_forces - w.squeeze_tail_force, 0.0).sum(axis=1),
            "alive": w.alive * ~fall,
        }


def training_env_config() -> BaodingConfig:
    """The env `tacgnn train-policy` starts from: the hand as uncertain as a real one
    (randomisation on, every range at its default) and the real skin."""
    return BaodingConfig(randomization=RandomizationConfig(enabled=True))


def _capped(degrees: np.ndarray, cap: float) -> np.ndarray:
    """Per-step turn (deg) counted at most `cap` forward (0: no cap); turning back is never capped."""
    return np.minimum(degrees, cap) if cap > 0 else degrees


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


class BaodingSingleEnv(gym.Env):
    """One Baoding env as a plain `gymnasium.Env` (passes `gymnasium.utils.env_checker.check_env`).

    For training use `BaodingEnv`: this wrapper steps a batch of one.
    """

    metadata = {"render_modes": [], "render_fps": 50}

    def __init__(self, config: BaodingConfig | None = None):
        cfg = config or BaodingConfig()
        self.vec = BaodingEnv(replace(cfg, num_envs=1))
        self.observation_space = self.vec.single_observation_space
        self.action_space = self.vec.single_action_space

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        obs, info = self.vec.reset(seed=seed)
        return _row(obs, 0), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.vec.step(np.asarray(action)[None])
        if terminated[0] or truncated[0]:
            obs = info["final_obs"]
        return _row(obs, 0), float(reward[0]), bool(terminated[0]), bool(truncated[0]), \
            {"angle_deg": float(info["angle_deg"][0]), "success": bool(info["success"][0])}


def _row(obs, i):
    return {k: v[i] for k, v in obs.items()} if isinstance(obs, dict) else obs[i]


def _copy_obs(obs):
    """A copy of an observation (the 'tactile' mode's dict may hold the Warp skin's tensors)."""
    if isinstance(obs, dict):
        return {k: v.copy() if isinstance(v, np.ndarray) else v.clone() for k, v in obs.items()}
    return obs.copy()


def _assign_obs(obs, ids, new) -> None:
    if isinstance(obs, dict):
        for k in obs:
            obs[k][ids] = new[k]
    else:
        obs[ids] = new
