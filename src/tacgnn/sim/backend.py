"""The physics engine of a scene, chosen by `SimConfig.backend`: MuJoCo's C engine or MuJoCo Warp.

Both give the same batch interface (`BatchedSim`) and the same skin model, so the envs
run unchanged on either: the C engine on CPU threads with the compiled skin kernel, or
MuJoCo Warp (CPU or GPU) with the skin in torch on the engine's device.
"""

from __future__ import annotations

import mujoco

from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.sim.batched import BatchedSim
from tacgnn.sim.scene import SimConfig
from tacgnn.sim.tactile import TactileModel


def make_sim(model: mujoco.MjModel, num_envs: int, sim: SimConfig):
    """A `BatchedSim` (backend 'c') or a `WarpSim` (backend 'warp') of `num_envs` envs."""
    if sim.backend == "warp":
        from tacgnn.sim.warp_backend import WarpSim  # imports warp only when asked for
        return WarpSim(model, num_envs, device=sim.device, nconmax=sim.warp_nconmax, njmax=sim.warp_njmax)
    return BatchedSim(model, num_envs, nthread=sim.nthread)


def make_tactile(layout: SkinLayout, model: mujoco.MjModel, sim: SimConfig):
    """The skin model for the backend: the compiled CPU kernel, or torch on the Warp device."""
    if sim.backend == "warp":
        from tacgnn.sim.tactile_device import DeviceTactile
        return DeviceTactile(layout, model, device=sim.device)
    return TactileModel(layout, model)

