"""Power grasps of a cube, a cylinder or a meat can: the paper's object-state experiment.

Each of N envs drops the object onto the palm-up hand in a random pose, closes all
fingers and the thumb to a random power-grasp posture, holds, and records the final
frame: the skin (readings and taxel positions) and the object's pose. One call to
`PowerGrasp.run` makes N grasps at once.

Objects (config `object`):
* cube: 3 cm, 0.05 kg (the authors'); its yaw on the palm is drawn in [0, 90) deg,
  one period of its symmetry, as in the paper.
* cylinder: radius 2 cm, length 8 cm, 0.1 kg, lying on the palm; its rotation about its
  own axis is ignored (the label is the axis direction).
* meat_can: the YCB 010 potted meat can as a box of 50 x 97 x 82 mm and 0.37 kg (the
  YCB paper's table; the real can's rounded edges are left out), yaw in [0, 180) deg.
  It is dropped on its broad 97 x 82 face (`can_face="broad"`, the default) or stood on
  its narrow 50 x 97 face (`"narrow"`), where the fingers wrap its 82 mm sides.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import mujoco
import numpy as np

from tacgnn.config import check
from tacgnn.envs.base import HandEnvBase
from tacgnn.hand.allegro import NUM_JOINTS, OBJECT_CONAFFINITY, OBJECT_CONTYPE, HandConfig
from tacgnn.hand.skin_layout import SkinLayout, default_skin
from tacgnn.sim.scene import SimConfig, hand_scene, palm_frame

ObjectName = Literal["cube", "cylinder", "meat_can"]
YAW_RANGE_DEG = {"cube": 90.0, "cylinder": 180.0, "meat_can": 180.0}
MAX_PHASE_STEPS = 5_000


class SimulationDiverged(RuntimeError):
    """The physics blew up: with the shipped configs it does not, so a changed value is the cause."""


@dataclass(frozen=True)
class GraspConfig:
    object: ObjectName = "cube"
    num_envs: int = 64
    hand: HandConfig = field(default_factory=lambda: HandConfig(palm_tilt_deg=0.0))
    skin: SkinLayout = field(default_factory=default_skin)
    sim: SimConfig = field(default_factory=SimConfig)
    control_dt: float = 0.02
    settle_steps: int = 15
    close_steps: int = 25
    hold_steps: int = 15
    position_noise: float = 0.015
    """Uniform +- noise (m) of the drop point along the palm."""
    closure: tuple[float, float] = (0.5, 1.0)
    """Range of the random closure, as a fraction of each flexion joint's range."""
    can_face: Literal["broad", "narrow"] = "broad"
    """meat_can: the face it is dropped on. On the broad face it covers most of the palm and
    its yaw barely shows in the skin (experiments/perception_accuracy/NOTES.md)."""

    def __post_init__(self) -> None:
        check(1 <= self.num_envs <= 65_536, "num_envs", f"must be in 1..65536, got {self.num_envs}")
        substeps = self.control_dt / self.sim.timestep
        whole = round(substeps) >= 1 and abs(substeps - round(substeps)) < 1e-6
        check(0 < self.control_dt <= 1 and whole, "control_dt",
              f"must be a whole multiple of sim.timestep ({self.sim.timestep} s) in (0, 1] s, got {self.control_dt}")
        for key in ("settle_steps", "close_steps", "hold_steps"):  # a grasp of minutes is a typo, not a grasp
            check(1 <= getattr(self, key) <= MAX_PHASE_STEPS, key,
                  f"must be in 1..{MAX_PHASE_STEPS}, got {getattr(self, key)}")
        check(self.position_noise >= 0, "position_noise", f"must be >= 0, got {self.position_noise}")
        check(0 <= self.closure[0] <= self.closure[1] <= 1, "closure", "needs 0 <= low <= high <= 1")
        check(self.can_face in ("broad", "narrow"), "can_face", f"must be 'broad' or 'narrow', got {self.can_face!r}")


def _add_object(spec: mujoco.MjSpec, name: ObjectName) -> None:
    body = spec.worldbody.add_body(name="object", pos=[0, 0, 0.1])
    body.add_freejoint(name="object_free")
    common = dict(contype=OBJECT_CONTYPE, conaffinity=OBJECT_CONAFFINITY, rgba=[0.8, 0.6, 0.2, 1])
    if name == "cube":
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.015] * 3, mass=0.05, **common)
    elif name == "cylinder":
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.02, 0.04, 0], mass=0.1, **common)
    else:
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.025, 0.0485, 0.041], mass=0.37, **common)


class PowerGrasp(HandEnvBase):
    """N power grasps in parallel; `run(seed)` returns the final frames and object poses."""

    def __init__(self, config: GraspConfig | None = None):
        cfg = config or GraspConfig()
        self.config = cfg
        spec = hand_scene(cfg.hand, cfg.sim)
        _add_object(spec, cfg.object)
        super().__init__(spec, cfg.hand, cfg.skin, cfg.sim, cfg.num_envs, cfg.control_dt)
        self.object_body = self.model.body("object").id
        self.object_qpos_adr = self.model.joint("object_free").qposadr[0]
        self.palm_axes = palm_frame(cfg.hand)
        # half extent along the palm normal in the spawn pose
        self.rest_height = {"cube": 0.015, "cylinder": 0.02,
                            "meat_can": 0.025 if cfg.can_face == "broad" else 0.041}[cfg.object]

    def _spawn(self, rng: np.random.Generator) -> None:
        """Object above the palm centre in a random pose, fingers open."""
        cfg, sim, n = self.config, self.sim, self.num_envs
        sim.reset(np.arange(n))
        yaw = np.deg2rad(rng.uniform(0, YAW_RANGE_DEG[cfg.object], n))
        along = rng.uniform(-cfg.position_noise, cfg.position_noise, (n, 2))
        palm_pos = np.stack([np.full(n, 0.0111 + self.rest_height + 0.004),
                             along[:, 0], -0.045 + along[:, 1]], 1)
        normal, across, along = self.palm_axes.T
        heading = np.cos(yaw)[:, None] * across + np.sin(yaw)[:, None] * along  # (n, 3) in the palm plane
        up = np.tile(normal, (n, 1))
        # columns of the object's rotation: which object axis points up, which along `heading`
        if cfg.object == "cube":  # z up, x along heading
            x, z = heading, up
            y = np.cross(z, x)
        elif cfg.object == "cylinder":  # lying: its axis (z) along heading, x up
            x, z = up, heading
            y = np.cross(z, x)
        elif cfg.can_face == "broad":  # meat can lying on its broad face: x (50 mm) up, y (97 mm) along heading
            x, y = up, heading
            z = np.cross(x, y)
        else:  # meat can standing on its narrow face: z (82 mm) up, y (97 mm) along heading
            y, z = heading, up
            x = np.cross(y, z)
        rot = np.stack([x, y, z], axis=2)  # (n, 3, 3)
        quat = np.zeros((n, 4))
        for i in range(n):
            mujoco.mju_mat2Quat(quat[i], rot[i].flatten())
        qpos = sim.qpos.copy()
        a = self.object_qpos_adr
        qpos[:, a:a + 3] = palm_pos @ self.palm_axes.T
        qpos[:, a + 3:a + 7] = quat
        open_pose = np.clip(np.zeros(NUM_JOINTS), self.joint_low, self.joint_high)
        open_pose[12] = self.joint_low[12]  # thumb out of the way
        qpos[:, self.joint_qpos_adr] = open_pose
        sim.qpos[:] = qpos
        sim.qvel[:] = 0
        sim.ctrl[:] = open_pose
        sim.forward()
        self._open = open_pose

    def _closed_pose(self, rng: np.random.Generator) -> np.ndarray:
        """A random power-grasp posture per env: fingers and thumb flexed, thumb opposed."""
        n, lo, hi = self.num_envs, self.joint_low, self.joint_high
        frac = rng.uniform(*self.config.closure, (n, NUM_JOINTS))
        pose = lo + frac * (hi - lo)
        pose[:, [0, 4, 8]] = rng.uniform(-0.15, 0.15, (n, 3))  # a little spread
        pose[:, 12] = rng.uniform(0.9, 1.3, n)  # thumb rotated to oppose the fingers
        return pose

    def run(self, seed: int) -> dict[str, np.ndarray]:
        """Make N grasps; return final-frame skin and object pose for each env."""
        cfg, sim = self.config, self.sim
        rng = np.random.default_rng(seed)
        self._rng = np.random.default_rng(seed + 1)
        self._spawn(rng)
        closed = self._closed_pose(rng)
        for _ in range(cfg.settle_steps):
            self._check(sim.step(self.substeps))
        for k in range(1, cfg.close_steps + 1):
            sim.ctrl[:] = self._open + (closed - self._open) * (k / cfg.close_steps)
            self._check(sim.step(self.substeps))
        for _ in range(cfg.hold_steps):
            self._check(sim.step(self.substeps))
        quat = np.zeros((self.num_envs, 4))
        for i in range(self.num_envs):
            mujoco.mju_mat2Quat(quat[i], sim.xmat[i, self.object_body])
        return {
            "tactile": self.tactile_readings(),
            "taxel_pos": self.taxel_positions(),
            "joint_pos": self.joint_pos.copy(),
            "object_pos": sim.xpos[:, self.object_body].copy(),
            "object_rot": sim.xmat[:, self.object_body].reshape(-1, 3, 3).copy(),
            "object_quat": quat,
        }

    def _check(self, diverged: np.ndarray) -> None:
        if diverged.any():
            raise SimulationDiverged(f"grasp simulation diverged in {int(diverged.sum())} of {len(diverged)} envs: "
                                     "a hand, sim or object value changed from its default is out of a workable range")
