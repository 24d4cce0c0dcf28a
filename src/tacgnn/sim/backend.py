"""The physics engine of a scene, chosen by `SimConfig.backend`: MuJoCo's C engine or MuJoCo Warp.

Both give the same batch interface (`BatchedSim`) and the same skin model, so the envs
run unchanged on either: the C engine on CPU threads with the compiled skin kernel, or
MuJoCo Warp (CPU or GPU) with the skin in torch on the engine's device, reading the
engine's device arrays (`skin_readings`, `skin_positions`).
"""

from __future__ import annotations

import mujoco
import numpy as np

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


def skin_readings(tactile, sim, ids: slice | np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
    """Readings (len(ids), T) of envs `ids` at the sim's current state, as numpy.

    The C engine's skin reads the sim's arrays; the Warp skin reads the engine's device
    arrays (no inputs staged on the host) and keeps its readings there too.
    """
    if isinstance(tactile, TactileModel):
        return tactile.readings(sim.sensordata[ids], sim.xpos[ids], sim.xmat[ids], rng)
    return tactile.engine_readings(sim, ids, rng)


def skin_positions(tactile, sim, ids: slice | np.ndarray) -> np.ndarray:
    """World taxel positions (len(ids), T, 3) of envs `ids`, as numpy; see `skin_readings`."""
    if isinstance(tactile, TactileModel):
        return tactile.positions(sim.xpos[ids], sim.xmat[ids])
    return tactile.engine_positions(sim, ids)
