"""Assemble a simulation scene: the hand, its skin sensors, objects, lights and camera."""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from typing import Literal

import mujoco
import numpy as np

from tacgnn.config import check
from tacgnn.hand.allegro import OBJECT_CONAFFINITY, OBJECT_CONTYPE, HandConfig, add_hand
from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.sim.tactile import add_skin_sensors


@dataclass(frozen=True)
class SimConfig:
    """Physics settings shared by every scene."""

    timestep: float = 0.005
    """Physics step (s); the 50 Hz control step is split into control_dt / timestep substeps."""
    integrator: str = "implicitfast"
    contacts_per_patch: int = 4
    """How many contacts (strongest first) each skin patch's sensor reports."""
    nthread: int = 2
    """Threads stepping the batch of envs (0: all cores)."""
    backend: Literal["c", "warp"] = "c"
    """Physics engine: 'c' (MuJoCo on CPU threads) or 'warp' (MuJoCo Warp on `device`; sim/warp_backend.py)."""
    device: str = "cpu"
    """Device of the 'warp' backend and its skin model: 'cpu', 'cuda', 'cuda:1', ..."""
    warp_nconmax: int = 64
    """'warp': contacts per env the engine's buffers hold (an overflow stops the run, naming this key)."""
    warp_njmax: int = 256
    """'warp': constraint rows per env (4 per contact, plus joint limits)."""
    contact_timeconst: float = 0.01
    """Time constant (s) of every contact's spring-damper (MuJoCo solref[0]): the smallest stable
    value, 2 x timestep, so balls do not sink into the links. MuJoCo's default 0.02 let a ball
    sink 4.5 mm (99th percentile) under the torque-limited hand's grip."""
    contact_dampratio: float = 1.0
    """Damping ratio of the contacts (solref[1]); 1 is critical damping."""
    contact_solimp: tuple[float, float, float] = (0.95, 0.99, 0.001)
    """Contact impedance (MuJoCo solimp d0, d_width, width in m): how hard a contact is at first
    touch and from `width` deep on; closer to 1 is harder."""

    def __post_init__(self) -> None:
        check(1e-4 <= self.timestep <= 0.02, "sim.timestep", f"must be in [0.0001, 0.02] s, got {self.timestep}")
        check(self.integrator in ("euler", "implicitfast", "implicit", "rk4"), "sim.integrator",
              f"unknown integrator {self.integrator!r}")
        check(1 <= self.contacts_per_patch <= 16, "sim.contacts_per_patch", "must be in 1..16")
        check(0 <= self.nthread <= 1024, "sim.nthread", f"must be in 0..1024, got {self.nthread}")
        check(self.backend in ("c", "warp"), "sim.backend", f"must be 'c' or 'warp', got {self.backend!r}")
        check(self.backend != "warp" or importlib.util.find_spec("mujoco_warp") is not None, "sim.backend",
              "'warp' needs the mujoco-warp package (pip install mujoco-warp==4.0.0)")
        check(self.warp_nconmax >= 1, "sim.warp_nconmax", f"must be >= 1, got {self.warp_nconmax}")
        check(self.warp_njmax >= 1, "sim.warp_njmax", f"must be >= 1, got {self.warp_njmax}")
        check(self.contact_timeconst <= 1, "sim.contact_timeconst", f"must be <= 1 s, got {self.contact_timeconst}")
        check(self.contact_timeconst >= 2 * self.timestep - 1e-12, "sim.contact_timeconst",
              f"must be >= 2 x sim.timestep ({2 * self.timestep}) or the contacts are unstable, "
              f"got {self.contact_timeconst}")
        check(0.3 <= self.contact_dampratio <= 10, "sim.contact_dampratio",  # below 0.3 grasps diverge
              f"must be in [0.3, 10], got {self.contact_dampratio}")
        d0, d1, width = self.contact_solimp
        check(0 < d0 <= d1 < 1 and 0 < width <= 0.1, "sim.contact_solimp",
              f"needs 0 < d0 <= d_width < 1 and 0 < width <= 0.1 m, got {self.contact_solimp}")


_INTEGRATORS = {
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
}


def hand_scene(hand: HandConfig, sim: SimConfig) -> mujoco.MjSpec:
    """A spec with the hand, lights, a camera and a visual-only floor; add objects next."""
    spec = mujoco.MjSpec()
    spec.modelname = "tacgnn_hand"
    spec.compiler.degree = False  # all angles in this package are radians
    spec.option.timestep = sim.timestep
    spec.option.integrator = _INTEGRATORS[sim.integrator]
    # A diverging env must show as NaN that we detect and report, not be reset silently.
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
    spec.default.geom.solref = [sim.contact_timeconst, sim.contact_dampratio]
    spec.default.geom.solimp = [*sim.contact_solimp, 0.5, 2.0]
    spec.visual.global_.offwidth = 640
    spec.visual.global_.offheight = 480
    world = spec.worldbody
    world.add_light(pos=[0, -0.3, 0.6], dir=[0, 0.4, -1], diffuse=[0.8, 0.8, 0.8])
    world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.5, 0.5, 0.01],
                   pos=[0, 0, -0.25], rgba=[0.35, 0.4, 0.45, 1], contype=0, conaffinity=0)
    world.add_camera(name="overview", pos=[0.0, -0.28, 0.30], xyaxes=[1, 0, 0, 0, 0.7, 0.7])
    add_hand(spec, hand)
    return spec


def add_sphere(spec: mujoco.MjSpec, name: str, radius: float, mass: float, pos, friction: float,
               rgba=(0.85, 0.3, 0.2, 1.0)) -> None:
    """A free sphere that touches the hand and other objects.

    Its geom has priority over the hand's, so its `friction` is the friction of its contacts
    with the hand (MuJoCo otherwise takes the larger of the two geoms' values).
    """
    body = spec.worldbody.add_body(name=name, pos=list(pos))
    body.add_freejoint(name=f"{name}_free")
    body.add_geom(name=f"{name}_geom", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0],
                  mass=mass, friction=[friction, 0.005, 0.0001], contype=OBJECT_CONTYPE,
                  conaffinity=OBJECT_CONAFFINITY, priority=1, rgba=list(rgba))


def sphere_inertia(mass, radius: float):
    """A solid ball's moment of inertia about any axis through its centre (kg m^2), as MuJoCo
    computes it from the geom, to the last bit (MuJoCo's order of operations: a ball at its
    compiled mass gets exactly its compiled inertia, so `set_const` leaves `dof_M0` as compiled)."""
    return 2 * mass * radius * radius / 5


def compile_with_skin(spec: mujoco.MjSpec, skin: SkinLayout, sim: SimConfig) -> mujoco.MjModel:
    """Add the skin's contact sensors and compile."""
    add_skin_sensors(spec, skin, sim.contacts_per_patch)
    model = spec.compile()
    return model


def palm_frame(hand: HandConfig) -> np.ndarray:
    """3x3 rotation whose columns are the palm's x (normal), y, z (along fingers) in world."""
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, hand.palm_quat())
    return mat.reshape(3, 3)
