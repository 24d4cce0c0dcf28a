"""The Baoding-balls task: its settings (constants, reward weights, the env's config) and rules.

Apart from the env (`envs/baoding.py`), so that a module that only reads or builds a config
(checkpoints, the trainer, the CLI) imports it without the env class. The task, whose rules
`baoding_terms.py` computes, follows the TacGNN paper and its authors' code (see
docs/environment.md):

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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import mujoco

from tacgnn.config import check, check_seed
from tacgnn.envs.randomization import RandomizationConfig
from tacgnn.hand.allegro import FINGER_RANGES, MIN_FRICTION, NUM_JOINTS, THUMB_BAODING_RANGES, HandConfig
from tacgnn.hand.skin_layout import SkinLayout, default_skin
from tacgnn.sim.scene import SimConfig, sphere_inertia
from tacgnn.sim.skin_signal import SkinSignalConfig

ObsMode = Literal["groundtruth", "no_perception", "finger_torque", "noise_2", "noise_4",
                  "noise_10", "perceived", "tactile"]
# Uniform noise (m) on the ball positions for the paper's NOISE_* ablations; the authors'
# code used +-2, +-5 and +-10 mm for NOISE_2, NOISE_4 and NOISE_10.
ABLATION_NOISE = {"noise_2": 0.002, "noise_4": 0.005, "noise_10": 0.010}
BAODING_RANGES = FINGER_RANGES * 3 + THUMB_BAODING_RANGES
BALLS = ("ball_0", "ball_1")
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
    saturation: float = 0.0
    """Times sum over joints of how far |torque| reaches into the top `saturation_knee` share of its
    env's torque limit, scaled to 1 at the limit (not in the paper): charges a motor held at its
    limit, where a PD drive turns bang-bang, and leaves the grip below the knee free; 0: off."""
    saturation_knee: float = 0.9
    """Share of the torque limit where `saturation` starts."""
    alive: float = 0.0
    """Per step that ends with both balls in the hand (not in the paper; for the continuous
    task, where staying in the hand is worth more than one fast half turn)."""
    rotation_cap_deg: float = 0.0
    """Degrees per step above which turning earns no more rotation reward; 0: no cap (not in
    the paper: a capped rate rewards a steady turn over a flick)."""

    def __post_init__(self) -> None:
        check(self.alive >= 0, "reward.alive", f"must be >= 0, got {self.alive}")
        check(0.0 < self.saturation_knee < 1.0, "reward.saturation_knee",
              f"must be in (0, 1), got {self.saturation_knee}")
        for name in ("action_rate", "effort", "saturation"):
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
    target_band_rad: float = 0.0
    """Motor targets are kept within this many rad of the joints' measured angles when sent (0: off).
    The real controller applies the same rule (`real-hand run`), so a policy trained with it acts the
    same on the hand. At the nominal gain (3 N m/rad) 0.15 rad keeps a motor under its 0.5 N m limit."""
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
        check(1 <= self.max_episode_steps <= 100_000, "max_episode_steps",
              f"must be in 1..100000 (33 min at 50 Hz), got {self.max_episode_steps}")
        check(0 < self.control_dt <= 1, "control_dt", f"must be in (0, 1] s, got {self.control_dt}")
        check(0 <= self.target_band_rad <= math.pi, "target_band_rad",
              f"must be in [0, pi] rad (0: off), got {self.target_band_rad}")
        substeps = self.control_dt / self.sim.timestep
        whole = round(substeps) >= 1 and abs(substeps - round(substeps)) < 1e-6
        check(0 < self.control_dt <= 1 and whole, "control_dt",
              f"must be a whole multiple of sim.timestep ({self.sim.timestep} s) in (0, 1] s, got {self.control_dt}")
        steps = self.continuous_seconds / self.control_dt if self.control_dt > 0 else 0.0
        check(0 < self.continuous_seconds <= 3600 and abs(steps - round(steps)) < 1e-6, "continuous_seconds",
              f"must be a positive whole number of control steps (control_dt {self.control_dt} s), "
              f"got {self.continuous_seconds}")
        check(0 < self.ball_radius <= 0.1, "ball_radius", f"must be in (0, 0.1] m (a ball the hand can hold), "
              f"got {self.ball_radius}")
        check(self.ball_mass <= 10, "ball_mass", f"must be <= 10 kg, got {self.ball_mass}")
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
        check(MIN_FRICTION <= self.ball_friction <= 100, "ball_friction",
              f"must be in [{MIN_FRICTION}, 100], got {self.ball_friction}")
        check(len(self.initial_joint_pos) == NUM_JOINTS, "initial_joint_pos", "needs 16 values")
        check(0 < self.success_angle_deg <= 36_000, "success_angle_deg",
              f"must be in (0, 36000] deg (100 turns), got {self.success_angle_deg}")
        check(self.direction in (1, -1), "direction", "must be +1 or -1")
        check(self.ball_order in ("as_simulated", "canonical"), "ball_order",
              f"must be 'as_simulated' or 'canonical', got {self.ball_order!r}")
        check(self.disturbance_interval >= 1, "disturbance_interval", "must be >= 1")
        check(self.disturbance_std >= 0, "disturbance_std", "must be >= 0")
        check(self.hold_steps >= 0, "hold_steps", "must be >= 0")
        check(self.long_hold_steps >= 0, "long_hold_steps", "must be >= 0")
        check(self.fall_height[0] < self.fall_height[1], "fall_height", "needs low < high")
        check(0 <= self.spawn_noise <= 0.05, "spawn_noise", f"must be in [0, 0.05] m, got {self.spawn_noise}")
        check(0 <= self.spawn_clearance <= 0.02, "spawn_clearance",
              f"must be in [0, 0.02] m, got {self.spawn_clearance}")
        check(self.joint_noise >= 0, "joint_noise", f"must be >= 0, got {self.joint_noise}")
        check(not self.ball_velocity or self.obs_mode in ("groundtruth", "perceived", "tactile"), "ball_velocity",
              f"shows the velocities of the balls the observation shows: 'groundtruth' or 'perceived' "
              f"('tactile': in its ground-truth view), not '{self.obs_mode}'")
        if self.randomization.enabled:
            self.randomization.check_latencies(self.sim.timestep)
            lowest, scale = min(self.hand.friction, self.ball_friction), self.randomization.friction_scale[0]
            check(lowest * scale >= MIN_FRICTION, "randomization.friction_scale",
                  f"its low end {scale} scales the lowest contact friction ({lowest}) below {MIN_FRICTION}")
            for name in ("ball_mass", "armature_scale"):  # they change the mass matrix's constants (dof_M0)
                lo, hi = getattr(self.randomization, name)
                check(self.sim.backend != "warp" or lo == hi, f"randomization.{name}",
                      f"MuJoCo Warp keeps one mass matrix for all envs: give one value (low = high), got ({lo}, {hi})")
        check(self.tactile or self.obs_mode not in ("tactile", "perceived"), "tactile",
              f"obs_mode '{self.obs_mode}' needs tactile: true")


def training_env_config() -> BaodingConfig:
    """The env `tacgnn train-policy` starts from: the hand as uncertain as a real one
    (randomisation on, every range at its default) and the real skin."""
    return BaodingConfig(randomization=RandomizationConfig(enabled=True))
