"""Shared base of the batched hand environments: the hand, its skin and the physics batch.

A task file (e.g. `baoding.py`) adds its objects to the scene, and implements reset,
observation, reward and termination on top of what this base gives:

* `sim`: the `BatchedSim` of `num_envs` envs,
* `tactile`: the skin model, `tactile_readings()` and `taxel_positions()` for all envs (numpy;
  `skin_to_host` for the skin arrays a step hands out, tensors on the Warp engine's device),
* `action_to_ctrl`: the paper's action mapping, [-1, 1] onto each joint's range,
* joint position/velocity views and the physics substeps of one control step.
"""

from __future__ import annotations

import mujoco
import numpy as np

from tacgnn.envs import observation
from tacgnn.hand.allegro import NUM_JOINTS, HandConfig
from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.sim.backend import SkinArray, make_sim, make_tactile, skin_positions, skin_readings, skin_to_host
from tacgnn.sim.scene import SimConfig, compile_with_skin


class HandEnvBase:
    """Builds the batched simulation of a scene that holds the hand and the skin."""

    def __init__(self, spec: mujoco.MjSpec, hand: HandConfig, skin: SkinLayout, sim: SimConfig,
                 num_envs: int, control_dt: float):
        substeps = control_dt / sim.timestep
        if abs(substeps - round(substeps)) > 1e-6:
            raise ValueError(f"control_dt {control_dt} must be a multiple of sim.timestep {sim.timestep}")
        self.substeps = int(round(substeps))
        self.control_dt = control_dt
        self.num_envs = num_envs
        self.model = compile_with_skin(spec, skin, sim)
        self.sim = make_sim(self.model, num_envs, sim)  # BatchedSim, or WarpSim (sim.backend: warp)
        self.tactile = make_tactile(skin, self.model, sim)
        lo, hi = np.asarray(hand.joint_ranges, dtype=np.float64).T
        self.joint_low, self.joint_high = lo, hi
        self.target_ranges = np.asarray(hand.joint_target_ranges(), dtype=np.float64)
        self.joint_qpos_adr = self.model.jnt_qposadr[:NUM_JOINTS].copy()
        self.joint_dof_adr = self.model.jnt_dofadr[:NUM_JOINTS].copy()
        self._rng = np.random.default_rng()

    # --- the hand ----------------------------------------------------------------------
    def action_to_ctrl(self, action: np.ndarray) -> np.ndarray:
        """Absolute joint targets from actions in [-1, 1] (clipped), as in the paper."""
        return observation.action_to_target(action, self.joint_low, self.joint_high, self.target_ranges)

    def ctrl_to_action(self, ctrl: np.ndarray) -> np.ndarray:
        return observation.target_to_action(ctrl, self.joint_low, self.joint_high)

    @property
    def joint_pos(self) -> np.ndarray:
        return self.sim.qpos[:, self.joint_qpos_adr]

    @property
    def joint_vel(self) -> np.ndarray:
        return self.sim.qvel[:, self.joint_dof_adr]

    # --- the skin ----------------------------------------------------------------------
    def tactile_readings(self, noisy: bool = True) -> np.ndarray:
        """(N, T) taxel forces (N) at the start of the last physics substep, as numpy."""
        return self.skin_to_host(skin_readings(self.tactile, self.sim, slice(None), self._rng if noisy else None))

    def taxel_positions(self) -> np.ndarray:
        """(N, T, 3) world positions (m) of all taxels, same instant as the readings, as numpy."""
        return self.skin_to_host(skin_positions(self.tactile, self.sim, slice(None)))

    def skin_to_host(self, array: SkinArray) -> np.ndarray:
        """A skin array of this env's (``info['tactile']``, ``info['taxel_pos']``: numpy on the C
        engine, a tensor on the Warp engine's device) as numpy."""
        return skin_to_host(self.tactile, array)
