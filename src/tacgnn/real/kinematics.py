"""Taxel world positions from measured joint angles, by forward kinematics of our hand model.

On the real hand nothing measures where a taxel is: the perception model's node
positions come from the joint encoders through the kinematics of the same MuJoCo model
the simulator uses (same links, palm tilt and skin layout), so a pose gives exactly the
positions the simulator would give for it.
"""

from __future__ import annotations

import mujoco
import numpy as np

from tacgnn.hand.allegro import JOINT_NAMES, HandConfig
from tacgnn.hand.skin_layout import SkinLayout, default_skin
from tacgnn.sim.scene import SimConfig, compile_with_skin, hand_scene
from tacgnn.sim.tactile import TactileModel


class TaxelKinematics:
    """positions(joint_angles (16,) rad) -> (T, 3) float32 taxel positions (m), world frame.

    The world frame is the simulator's: the origin on the line of the finger bases, the
    palm up and tilted by ``hand.palm_tilt_deg``.
    """

    def __init__(self, hand: HandConfig | None = None, skin: SkinLayout | None = None,
                 sim: SimConfig | None = None):
        self.hand = hand or HandConfig()
        self.skin = skin or default_skin()
        sim = sim or SimConfig()
        self.model = compile_with_skin(hand_scene(self.hand, sim), self.skin, sim)
        self.data = mujoco.MjData(self.model)
        self.tactile = TactileModel(self.skin, self.model)
        self.qpos_adr = np.array([self.model.joint(name).qposadr[0] for name in JOINT_NAMES])

    @property
    def num_taxels(self) -> int:
        return self.tactile.num_taxels

    def positions(self, joint_pos: np.ndarray) -> np.ndarray:
        joint_pos = np.asarray(joint_pos, dtype=np.float64)
        if joint_pos.shape != (len(JOINT_NAMES),):
            raise ValueError(f"joint_pos must have shape ({len(JOINT_NAMES)},) (rad), got {joint_pos.shape}")
        if not np.isfinite(joint_pos).all():
            raise ValueError(f"joint_pos holds non-finite values at joints "
                             f"{[JOINT_NAMES[i] for i in np.flatnonzero(~np.isfinite(joint_pos))]}")
        self.data.qpos[self.qpos_adr] = joint_pos
        mujoco.mj_kinematics(self.model, self.data)
        return self.tactile.positions(self.data.xpos[None], self.data.xmat[None])[0]
