"""The Baoding-balls task's env: rotate two balls 180 degrees around each other in a palm-up hand.

In the shape of MuJoCo Playground's tasks: the config and the task's description
(`baoding_config.py`), the task's rules as small terms (`baoding_terms.py`: angle, falls,
success, kicks, named rewards, spawn, what the policy is shown) and here the batched env
that steps them (reset, step, skin, the state for an exact resume).

Ball positions, skin readings and taxel positions are all taken at one instant, the
start of the last physics substep of the control step, so that a perception model's
input and its label match exactly.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.vector import AutoresetMode

from tacgnn.config import ConfigError
from tacgnn.envs import baoding_terms as terms
from tacgnn.envs import observation
from tacgnn.envs.baoding_config import BALLS, BAODING_RANGES, BaodingConfig, RewardConfig, training_env_config
from tacgnn.envs.baoding_terms import ordered_balls
from tacgnn.envs.base import HandEnvBase
from tacgnn.envs.observation import track_ball_identities
from tacgnn.envs.randomization import HandIO, RandomizationConfig, draw_ranges, randomize_physics
from tacgnn.hand.allegro import NUM_JOINTS
from tacgnn.sim.backend import SkinArray, skin_positions, skin_readings
from tacgnn.sim.scene import add_sphere, hand_scene, palm_frame, sphere_inertia
from tacgnn.sim.second_thread import beside
from tacgnn.sim.skin_ring import SkinRing
from tacgnn.sim.skin_signal import SkinSignal

# re-exported: the package, its tests and scripts import these from here
__all__ = ["BAODING_RANGES", "BaodingConfig", "BaodingEnv", "BaodingSingleEnv", "RandomizationConfig", "RewardConfig",
           "ordered_balls", "sphere_inertia", "track_ball_identities", "training_env_config"]

log = logging.getLogger(__name__)

EnvIds = np.ndarray | slice  # rows of envs: an index array, or a slice (rows as views)
_FOUND_AND_FORCE = ((1 << int(mujoco.mjtConDataField.mjCONDATA_FOUND))
                    | (1 << int(mujoco.mjtConDataField.mjCONDATA_FORCE)))
_STRONGEST_FIRST = 2  # the contact sensor's 'maxforce' reduction
BALL_CONTACTS = 4  # strongest contacts of each ball that its contact sensor reports
SPAWN_TRIES = 20


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
        self._on_device = cfg.sim.backend == "warp"  # its arrays stay with this thread (no `beside`)
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
        if self._spawn_overlaps(terms.place_balls(start, self._spawn, self.ball_qpos_adr, np.zeros((len(BALLS), 2)))):
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
        self._skin_ring = SkinRing(n, late + 1, self.tactile.num_taxels) if late else None

        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (NUM_JOINTS,), np.float32)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, n)
        self.single_observation_space = terms.observation_space(cfg, self.tactile.num_taxels)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, n)
        self._reset_envs(np.arange(n))

    # --- spaces and observations ---------------------------------------------------------
    @property
    def episode_limit(self) -> int:
        """Steps after which an episode is truncated (`baoding_terms.episode_limit`)."""
        return terms.episode_limit(self.config)

    def ball_positions(self) -> np.ndarray:
        """(N, 2, 3) ball centres relative to the hand origin (world axes, m)."""
        return self.sim.xpos[:, self.ball_body]  # a copy (fancy index)

    def _observe(self, ids: EnvIds, tactile: SkinArray | None, taxel_pos: SkinArray | None) -> Any:
        q, qd = self.hand_io.readings(ids, self.joint_pos[ids], self.joint_vel[ids])  # as the encoders read them
        lo, hi = self.joint_low, self.joint_high
        if self.config.obs_mode == "tactile":
            proprio = observation.proprioception(q, qd, lo, hi)
            return {"proprio": np.concatenate([proprio, self.last_action[ids]], 1).astype(np.float32),
                    "tactile": tactile, "taxel_pos": taxel_pos}
        obj = terms.object_obs(self, ids, tactile, taxel_pos)
        return observation.assemble(q, qd, obj, self.last_action[ids], lo, hi)

    def groundtruth_obs(self) -> np.ndarray:
        """(N, 54) the 'groundtruth' observation of the current state, whatever the obs mode:
        what a privileged critic reads during training (the actor gets the env's own obs)."""
        balls = terms.shown_balls(self.ball_positions().reshape(self.num_envs, 6), self.config, self.true_velocity)
        return observation.assemble(self.joint_pos, self.joint_vel, balls, self.last_action, self.joint_low,
                                    self.joint_high)

    def skin_frames_late(self) -> np.ndarray:
        """(N,) how many control steps old the skin frame each env's observation shows is (0: this step's)."""
        return np.zeros(self.num_envs, np.int64) if self._skin_ring is None else self.hand_io.skin_delay.copy()

    def raw_skin(self) -> np.ndarray:
        """(N, T) what the skin's driver reports now, before any calibration: the real skin's raw
        values (advancing it one frame), or the ideal skin's forces. For the simulated hand behind
        ROS, whose consumer calibrates them as it would a real hand's."""
        forces = self.tactile_readings()
        return forces if self.config.skin_signal.is_ideal else self.skin_signal.raw(forces, slice(None), self._rng)

    def _skin(self, ids: EnvIds) -> tuple[SkinArray | None, SkinArray | None]:
        """Readings of envs `ids`, and taxel positions if the observation needs them (other modes get
        them on demand from `taxel_positions()`, same instant until the next step)."""
        if not self.config.tactile:
            return None, None
        positions = beside(skin_positions, self.tactile, self.sim, ids, inline=self._on_device) \
            if self._obs_uses_skin else None  # a matrix product, beside the readings
        readings = skin_readings(self.tactile, self.sim, ids, self._rng)  # on Warp: from the device arrays
        if not self.config.skin_signal.is_ideal:  # what a real skin and its calibration make of it
            readings = self.skin_signal(self.skin_to_host(readings), ids, self._rng)
        return readings, None if positions is None else positions.result()

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
                "skin_history": {} if self._skin_ring is None else self._skin_ring.state_dict()}

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
        if self._skin_ring is not None:
            self._skin_ring.load_state_dict(state["skin_history"])

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

    def _clear_spawn(self, qpos: np.ndarray, shift: np.ndarray, env_id: int) -> np.ndarray:
        """`qpos` with the balls placed at the spawn points plus `shift` (2, 2), redrawn from the
        env's stream while a ball would overlap the other ball or a link (at most
        `SPAWN_TRIES` draws; then the noise-free spawn points, which clear the hand at
        construction). A ball that starts inside a link is shot out by the contact solver."""
        for _ in range(SPAWN_TRIES):
            qpos = terms.place_balls(qpos, self._spawn, self.ball_qpos_adr, shift)
            if not self._spawn_overlaps(qpos):
                return qpos
            shift = self.config.spawn_noise * (2 * self._env_rngs[env_id].random((len(BALLS), 2)) - 1)
        return terms.place_balls(qpos, self._spawn, self.ball_qpos_adr, np.zeros((len(BALLS), 2)))

    def _spawn_overlaps(self, qpos: np.ndarray) -> bool:
        """Whether a ball touches (within `spawn_clearance`) the other ball or a link at `qpos`."""
        return terms.spawn_overlaps(self.model, self._scratch, qpos, self.ball_geom, self.config.spawn_clearance)

    # --- step --------------------------------------------------------------------------
    def step(self, actions: np.ndarray):
        cfg = self.config
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != (self.num_envs, NUM_JOINTS):
            raise ValueError(f"actions must have shape ({self.num_envs}, {NUM_JOINTS}), got {actions.shape}")
        if not np.isfinite(actions).all():
            raise ValueError(f"non-finite actions in envs {np.flatnonzero(~np.isfinite(actions).all(1)).tolist()}")
        actions = np.clip(actions, -1.0, 1.0)
        target = self.action_to_ctrl(self.hand_io.command(actions, self._rng))
        self.hand_io.push(self.hand_io.banded(target, self.joint_pos, cfg.target_band_rad, self.target_ranges))
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
        late = beside(self._late_skin, all_ids, tactile, taxel_pos,  # the ring, beside the rules
                      inline=self._skin_ring is None or self._on_device)
        balls = self.ball_positions()
        flat = balls.reshape(self.num_envs, 6)
        self.true_velocity[:] = (flat - self.true_balls) / cfg.control_dt
        self.true_balls[:] = flat
        d_angle = self._update_angle(all_ids)
        fall = terms.fallen(balls, self.palm_centre, self.palm_axes, cfg)
        success = self._success(terms.reached(self.angle, cfg), fall)
        timeout = (self.episode_steps >= self.episode_limit) & ~success & ~fall
        reward_terms = self._reward_terms(d_angle, actions, action_change, success, fall, timeout, ball_forces)
        reward = sum(reward_terms.values())
        terminated = success | fall | diverged
        truncated = timeout & ~terminated
        # A diverged env's step is not a step: no reward from it.
        reward = np.where(diverged, 0.0, reward)
        for term in reward_terms.values():
            term[diverged] = 0.0

        info: dict[str, Any] = {
            "reward_terms": reward_terms, "angle_deg": np.rad2deg(self.angle), "success": success & ~diverged,
            "fall": fall & ~diverged, "timeout": truncated, "diverged": diverged,
            "episode_steps": self.episode_steps.copy(), "ball_pos": balls,
        }
        if tactile is not None:
            info["tactile"] = tactile
            info["joint_pos"] = self.sim.qpos[:, self.joint_qpos_adr]  # rad, beside each frame of the skin
        if taxel_pos is not None:
            info["taxel_pos"] = taxel_pos
        obs = self._observe(all_ids, *late.result())
        done = np.flatnonzero(terminated | truncated)
        if len(done):
            info["final_obs"], info["_final_obs"] = obs, terminated | truncated
            copied = beside(terms.copy_obs, obs, inline=not self._obs_uses_skin or self._on_device)  # beside the resets
            self._reset_envs(done)
            obs = copied.result()
            new_tactile, new_pos = self._late_skin(done, *self._skin(done), fresh=True) \
                if self._obs_uses_skin else (None, None)
            terms.assign_obs(obs, done, self._observe(done, new_tactile, new_pos))
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
        if not terms.disturbed(cfg):
            return
        ids = terms.kicked_envs(self.episode_steps, cfg)
        if len(ids) == 0:
            return
        draws = self._env_draws(ids, 4 * len(self.ball_body), normal=True).reshape(len(ids), -1, 4)
        forces = terms.kick_forces(draws, cfg)
        for b, body in enumerate(self.ball_body):
            xfrc[ids, body, :3] = forces[:, b]

    # --- task rules --------------------------------------------------------------------
    def _ball_vector_angle(self, ids: EnvIds) -> np.ndarray:
        return terms.ball_vector_angle(self.sim.xpos[ids][:, self.ball_body], self.palm_axes)

    def _update_angle(self, ids: EnvIds) -> np.ndarray:
        """Accumulate the wrapped change of the ball-to-ball angle; return it (rad)."""
        new = self._ball_vector_angle(ids)
        delta = terms.angle_change(new, self.vec_angle[ids], self.config.direction)
        self.vec_angle[ids] = new
        self.angle[ids] += delta
        return delta

    def _success(self, reached: np.ndarray, fall: np.ndarray) -> np.ndarray:
        return terms.success(reached, fall, self.hold_count, self.config)

    def ball_contact_forces(self) -> np.ndarray:
        """(N, 2 x BALL_CONTACTS) normal forces (N) of the balls' strongest contacts, 0 where none."""
        return self.sim.sensordata[:, self._ball_force_cols]

    def _step_physics(self) -> tuple[np.ndarray, np.ndarray]:
        """Step one control step; return the diverged mask and the balls' contact forces (N) that
        the squeeze cost reads: at the step's end, or with `reward.squeeze_peak` each contact
        slot's largest over the substeps.

        The targets of `hand_io` reach the motors whole control steps at a time, unless an action
        latency makes them arrive between physics steps: then each physics step gets its own
        (one call to the engine). For the peak forces the physics is stepped one substep per call
        (the same trajectory, a little slower).
        """
        sim, io = self.sim, self.hand_io
        if not self.config.reward.squeeze_peak:
            if io.has_latency:
                return sim.step_controls(io.targets_of_step()), self.ball_contact_forces()
            sim.ctrl[:] = io.target_at(0)
            return sim.step(self.substeps), self.ball_contact_forces()
        diverged = np.zeros(self.num_envs, bool)
        peak = np.zeros_like(self.ball_contact_forces())  # forces are >= 0; the cost's sums follow this layout
        for controls in io.targets_of_step().transpose(1, 0, 2):
            sim.ctrl[:] = controls
            diverged |= sim.step(1)
            np.maximum(peak, self.ball_contact_forces(), out=peak)
        return diverged, peak

    def _late_skin(self, ids: EnvIds, tactile: SkinArray | None, taxel_pos: SkinArray | None,
                   fresh: bool = False) -> tuple[SkinArray | None, SkinArray | None]:
        """The skin frame the policy sees: the newest that has arrived, `hand_io.skin_delay` frames
        old (skin latency); `fresh` (after a reset) fills the envs' history with this frame. A step
        (not `fresh`) pushes every env's frame at once: `ids` is then all of them."""
        if self._skin_ring is None or tactile is None or taxel_pos is None:
            return tactile, taxel_pos
        tactile, taxel_pos = self.skin_to_host(tactile), self.skin_to_host(taxel_pos)
        if fresh:
            self._skin_ring.fill(ids, tactile, taxel_pos)
            return tactile, taxel_pos
        if not (isinstance(ids, slice) and ids == slice(None)):
            raise ValueError("a late skin advances every env's frame at once (ids=slice(None))")
        return self._skin_ring.push(tactile, taxel_pos, self.hand_io.skin_delay)

    def _reward_terms(self, d_angle, actions, action_change, success, fall, timeout,
                      ball_forces) -> dict[str, np.ndarray]:
        drawn = self.sim.batch.expanded("actuator_forcerange")  # each env's torque limit, as drawn
        load = np.abs(self.sim.actuator_force) / (self._nominal_torque_limit if drawn is None else drawn[..., 1])
        return terms.reward_terms(self.config, d_angle, actions, action_change,
                                  self.sim.actuator_force / self._nominal_torque_limit, success, fall, timeout,
                                  ball_forces, load)


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
        return terms.obs_row(obs, 0), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.vec.step(np.asarray(action)[None])
        if terminated[0] or truncated[0]:
            obs = info["final_obs"]
        return terms.obs_row(obs, 0), float(reward[0]), bool(terminated[0]), bool(truncated[0]), \
            {"angle_deg": float(info["angle_deg"][0]), "success": bool(info["success"][0])}
