"""The physics engine of a scene, chosen by `SimConfig.backend`: MuJoCo's C engine or MuJoCo Warp.

Both give the same batch interface (`BatchedSim`) and the same skin model, so the envs
run unchanged on either: the C engine on CPU threads with the compiled skin kernel, or
MuJoCo Warp (CPU or GPU) with the skin in torch on the engine's device, reading the
engine's device arrays and leaving its results there (`skin_readings`, `skin_positions`);
`skin_to_host` brings them down for a consumer that needs numpy.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.sim.batched import BatchedSim
from tacgnn.sim.scene import SimConfig
from tacgnn.sim.tactile import TactileModel, skin_sensor_columns


def make_sim(model: mujoco.MjModel, num_envs: int, sim: SimConfig):
    """A `BatchedSim` (backend 'c') or a `WarpSim` (backend 'warp') of `num_envs` envs."""
    if sim.backend == "warp":
        from tacgnn.sim.warp_backend import WarpSim  # imports warp only when asked for
        return WarpSim(model, num_envs, device=sim.device, nconmax=sim.warp_nconmax, njmax=sim.warp_njmax,
                       device_only_sensors=skin_sensor_columns(model))
    return BatchedSim(model, num_envs, nthread=sim.nthread)


def make_tactile(layout: SkinLayout, model: mujoco.MjModel, sim: SimConfig):
    """The skin model for the backend: the compiled CPU kernel, or torch on the Warp device."""
    if sim.backend == "warp":
        from tacgnn.sim.tactile_device import DeviceTactile
        return DeviceTactile(layout, model, device=sim.device)
    return TactileModel(layout, model)


SkinArray = np.ndarray | torch.Tensor
"""Skin readings or taxel positions as a backend leaves them: numpy from the C engine's skin, a
torch tensor on the engine's device from the Warp skin (no copy to the host)."""


def skin_readings(tactile, sim, ids: slice | np.ndarray, rng: np.random.Generator | None) -> SkinArray:
    """Readings (len(ids), T) of envs `ids` at the sim's current state.

    The C engine's skin reads the sim's arrays and returns numpy; the Warp skin reads the
    engine's device arrays (no inputs staged on the host) and returns a tensor on that device.
    """
    if isinstance(tactile, TactileModel):
        return tactile.readings(sim.sensordata[ids], sim.xpos[ids], sim.xmat[ids], rng)
    return tactile.engine_readings(sim, ids, rng)


def skin_positions(tactile, sim, ids: slice | np.ndarray) -> SkinArray:
    """World taxel positions (len(ids), T, 3) of envs `ids`; numpy or a device tensor as `skin_readings`."""
    if isinstance(tactile, TactileModel):
        return tactile.positions(sim.xpos[ids], sim.xmat[ids])
    return tactile.engine_positions(sim, ids)


def skin_to_host(tactile, array: SkinArray) -> np.ndarray:
    """A skin array as numpy: the C engine's as it is, a device tensor copied down (counted in the
    Warp skin's `host_bytes`). For consumers that need the host: datasets, pictures, ROS."""
    if isinstance(array, np.ndarray):
        return array
    return tactile.to_host(array)
