"""The same batch of simulations on MuJoCo Warp: one model, N worlds, on a CPU or a GPU.

`WarpSim` has the interface of `BatchedSim` (qpos, qvel, ctrl, xfrc_applied, xpos, xmat,
sensordata, actuator_force; expand / reset / forward / step), so an env written
against one runs on the other unchanged. On the CPU its arrays are numpy views of the
engine's own memory (no copies); on a GPU they are host mirrors that move only what host
code uses: an array the engine changed is downloaded when host code first reads it (an
array nobody reads, such as `xmat` when the skin runs on the device, never comes down),
and before an engine call only the rows the host changed go up (a control step uploads
`ctrl`; a reset, the reset envs' rows). `device_views()` gives the device arrays as torch
tensors for code that stays on the device (the skin reads its inputs there:
`DeviceTactile.engine_readings`).

What differs from the C engine, and why:

* float32 arithmetic, and a solver tolerance of at least 1e-6 (MuJoCo Warp raises it for
  float32), so trajectories drift apart from the C engine's by round-off, then chaos;
* fixed buffers: `njmax` constraint rows per world, and a pool of `nconmax` contacts per
  world shared by all. An env that overflows its rows (an exploding env does) counts as
  diverged, as a MuJoCo error does in the C batch; an overflow of the shared pool would
  drop contacts anywhere, so `step` raises, naming the setting;
* MuJoCo Warp never resets a diverged world (the C engine's autoreset, which the scenes
  disable, is not implemented), so the flag is cleared on the engine's copy of the model;
* it computes a free body's inertia from `body_mass` at every step, where MuJoCo 4's C
  engine uses the `dof_M0` set at compile time (or by `mj_setConst`): a per-env ball mass
  moves the two apart unless the C batch runs `set_const` after setting it.
"""

from __future__ import annotations

import copy
import logging
from typing import Any

import mujoco
import numpy as np

from tacgnn.config import ConfigError
from tacgnn.sim.batched import step_each

log = logging.getLogger(__name__)

# Overflows that change the physics; iteration limits do not. Constraint rows and sensor
# matches are per env (that env's step is lost, like a MuJoCo error in the C batch); the
# contact pool is shared by all envs (an overflow there loses contacts anywhere).
_ENV_OVERFLOWS = {1 << 0: "constraint rows (sim.warp_njmax)", 1 << 6: "contact-sensor matches"}
_POOL_OVERFLOWS = {1 << 2: "broadphase pairs", 1 << 3: "contacts"}
# State the env writes, and derived arrays it reads; (name in mujoco_warp.Data, trailing shape).
_STATE = ("qpos", "qvel", "ctrl", "xfrc_applied", "qacc_warmstart")
_DERIVED = ("xpos", "xmat", "sensordata", "actuator_force")
_FIELDS = _STATE + _DERIVED + ("time",)
# What an engine step or forward can change (it reads ctrl and xfrc_applied, never writes them).
_ENGINE_WRITES = ("qpos", "qvel", "qacc_warmstart", "time") + _DERIVED


# MuJoCo's integration state (mjSTATE_INTEGRATION) in its order: (component, mujoco_warp.Data
# field); None for components this backend does not carry (an error if the model has them).
_S = mujoco.mjtState
_INTEGRATION_STATE = (
    (_S.mjSTATE_TIME, "time"), (_S.mjSTATE_QPOS, "qpos"), (_S.mjSTATE_QVEL, "qvel"), (_S.mjSTATE_ACT, "act"),
    (_S.mjSTATE_HISTORY, None), (_S.mjSTATE_WARMSTART, "qacc_warmstart"), (_S.mjSTATE_CTRL, "ctrl"),
    (_S.mjSTATE_QFRC_APPLIED, "qfrc_applied"), (_S.mjSTATE_XFRC_APPLIED, "xfrc_applied"),
    (_S.mjSTATE_EQ_ACTIVE, "eq_active"), (_S.mjSTATE_MOCAP_POS, "mocap_pos"),
    (_S.mjSTATE_MOCAP_QUAT, "mocap_quat"), (_S.mjSTATE_USERDATA, "userdata"), (_S.mjSTATE_PLUGIN, None),
    (_S.mjSTATE_PLASTIC, None))


class WarpUnavailable(ConfigError):
    """`sim.backend: warp` cannot run here: the package is missing or the model uses an unsupported feature."""

    def __init__(self, message: str):
        super().__init__(message, key="sim.backend", detail=message)


def import_warp():
    """(warp, mujoco_warp), or WarpUnavailable naming what to install."""
    try:
        import mujoco_warp as mjw
        import warp as wp
    except ImportError as err:
        raise WarpUnavailable(f"sim.backend: warp needs the mujoco-warp package ({err}); "
                              "install it with: pip install mujoco-warp==4.0.0") from err
    wp.config.log_level = wp.LOG_WARNING  # no banner, no line per kernel module loaded
    return wp, mjw


def warp_model_copy(model: mujoco.MjModel) -> mujoco.MjModel:
    """The model as MuJoCo Warp takes it: autoreset cleared (Warp never resets a world), and
    box-box pairs through the primitive box-box test, the one MuJoCo's C engine uses.

    MuJoCo Warp collides two boxes with its general convex (CCD) pipeline unless native CCD
    is disabled; that found other contact points on a finger link pressed against the palm
    (2 where C found 1) and moved the joints up to 9e-3 rad apart in one control step, in
    3 % of envs. With the primitive test the gap is float32 round-off (3e-7 rad).
    """
    m = copy.copy(model)
    m.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)  # Warp reads it for box-box only
    return m


class _Mirrored:
    """A `WarpSim` array as host code sees it: on a mirrored sim, downloaded on the first read
    after an engine call changed it (a write goes through a read, so it lands on fresh rows)."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, sim: WarpSim, owner: type | None = None) -> np.ndarray:
        if self.name in sim._stale:
            sim._download(self.name)
        return sim._host[self.name]


class WarpSim:
    """A batch of `num_envs` worlds of `model` on MuJoCo Warp; see `BatchedSim` for the contract.

    Args:
        model: the compiled model (the same one the C backend steps).
        num_envs: worlds.
        device: a Warp device ("cpu", "cuda:0").
        nconmax: contacts per world the buffers hold.
        njmax: constraint rows per world.
        max_speed: |qvel| above which an env counts as diverged.
        mirror: keep host copies of the arrays (forced on a GPU; on the CPU, for tests).
        device_only_sensors: sensordata columns that only code on the device reads (the skin's
            contact slots: `tactile_device` reads them there); the host mirror skips them and
            holds NaN in their place, so a host read of them is loud rather than stale.

    Attributes: as `BatchedSim`; all (N, ...) numpy arrays, float32. And:
        host_bytes: bytes copied between the host mirrors and the device so far (0 without mirrors):
            what a GPU run moves over the bus.
        host_sensors: the sensordata columns the mirror copies down (None: all of them).
    """

    # the Data fields of the same names (_FIELDS)
    qpos = _Mirrored()
    qvel = _Mirrored()
    ctrl = _Mirrored()
    xfrc_applied = _Mirrored()
    qacc_warmstart = _Mirrored()
    xpos = _Mirrored()
    xmat = _Mirrored()
    sensordata = _Mirrored()
    actuator_force = _Mirrored()
    time = _Mirrored()

    def __init__(self, model: mujoco.MjModel, num_envs: int, device: str = "cpu", nconmax: int = 64,
                 njmax: int = 256, max_speed: float = 1000.0, mirror: bool | None = None,
                 device_only_sensors: np.ndarray | None = None):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        wp, mjw = import_warp()
        self._wp, self._mjw = wp, mjw
        self.model = model
        self.num_envs = num_envs
        self.max_speed = max_speed
        self.device = wp.get_device(device)
        self._mirror = bool(self.device.is_cuda) if mirror is None else bool(mirror)
        if self.device.is_cuda and not self._mirror:
            raise ValueError("WarpSim on a GPU keeps host mirrors: mirror must not be False")
        m = warp_model_copy(model)
        with wp.ScopedDevice(self.device):
            try:
                self.wmodel = mjw.put_model(m)
            except NotImplementedError as err:  # MuJoCo Warp names the feature: "['mjGEOM_SDF'] not supported."
                raise WarpUnavailable(f"sim.backend: warp: the model uses a feature MuJoCo Warp does not "
                                      f"support: {err}") from err
            data = mujoco.MjData(m)
            self.wdata = mjw.put_data(m, data, nworld=num_envs, nconmax=nconmax, njmax=njmax)
        self.wmodel.opt.warn_overflow = 0  # `step` checks the flags itself
        self.nconmax, self.njmax = nconmax, njmax
        self.host_bytes = 0
        self._expanded: dict[str, tuple[Any, np.ndarray]] = {}  # field -> (device array (warp), view)
        self._mask = wp.zeros(num_envs, dtype=bool, device=self.device)
        self._device_views: dict[str, Any] | None = None  # made on first use (imports torch)
        self._host = {name: self._view(getattr(self.wdata, name)) for name in _FIELDS}
        self._host["xmat"] = self._host["xmat"].reshape(num_envs, model.nbody, 9)  # (N, nbody, 3, 3) -> C's
        self._stale: set[str] = set()  # mirrored arrays the engine changed since the host last read them
        self._synced: dict[str, np.ndarray] = {}  # mirror mode: each uploadable array as the device holds it
        self._start_mirrors(self._mirror)
        self.host_sensors: np.ndarray | None = None
        self._host_sensor_index: Any = None  # host_sensors as a torch index on the device
        if device_only_sensors is not None and len(device_only_sensors):
            self.host_sensors = np.setdiff1d(np.arange(self.sensordata.shape[1]), device_only_sensors)
            if self.mirror:
                self.sensordata[:, device_only_sensors] = np.nan

    # --- arrays ------------------------------------------------------------------------
    def _view(self, array) -> np.ndarray:
        """A numpy view of a device array (CPU), or a host copy of it (mirror)."""
        return array.numpy().copy() if self.mirror else array.numpy()

    @property
    def mirror(self) -> bool:
        """Whether the arrays are host copies (a GPU; on the CPU for tests and the bench's byte count)."""
        return self._mirror

    @mirror.setter
    def mirror(self, on: bool) -> None:
        """Switch the mirrors on (the host arrays taken as what the device holds) or off; on the CPU
        only, where the host arrays are the engine's memory (the bench counts bytes this way)."""
        if self.device.is_cuda and not on:
            raise ValueError("WarpSim on a GPU keeps host mirrors: mirror must not be False")
        if bool(on) != self._mirror:
            self._start_mirrors(bool(on))

    def _start_mirrors(self, on: bool) -> None:
        self._mirror = on
        self._stale.clear()
        self._synced = {name: self._host[name].copy() for name in _STATE} if on else {}
        if on:
            self._synced.update({field: host.copy() for field, (_, host) in self._expanded.items()})

    def _engine_changed(self, names: tuple[str, ...]) -> None:
        """Mirror mode: the engine wrote `names` on the device; their host copies are out of date."""
        if self.mirror:
            self._stale.update(names)

    def _upload(self) -> None:
        """Mirror mode: push the rows of the state and model fields the host changed to the device.

        An array out of date on the host was not read since the engine wrote it, so the host
        did not write it either (`_Mirrored`): it stays as the device has it.
        """
        if not self.mirror:
            return
        for name in _STATE:
            if name not in self._stale:
                self._push_changed_rows(getattr(self.wdata, name), self._host[name], self._synced[name])
        for field, (array, host) in self._expanded.items():
            self._push_changed_rows(array, host, self._synced[field])

    def _push_changed_rows(self, array, host: np.ndarray, synced: np.ndarray) -> None:
        """Upload the rows (envs) of `host` that differ from `synced`, the device's copy; count them."""
        changed = np.flatnonzero((host != synced).reshape(len(host), -1).any(axis=1))
        if len(changed) == 0:
            return
        if len(changed) == len(host):
            array.assign(host)
        else:
            import torch

            device_rows = self._wp.to_torch(array)
            index = torch.as_tensor(changed, device=device_rows.device)
            device_rows[index] = torch.from_numpy(host[changed]).to(device_rows.device).reshape(
                device_rows[index].shape)
        synced[changed] = host[changed]
        self.host_bytes += host[changed].nbytes

    def _download(self, name: str) -> None:
        """Mirror mode: bring array `name` up to date on the host (only `host_sensors` of sensordata)."""
        self._stale.discard(name)
        host = self._host[name]
        if name == "sensordata" and self.host_sensors is not None:
            self._download_host_sensors()
        else:
            host[...] = getattr(self.wdata, name).numpy().reshape(host.shape)
            self.host_bytes += host.nbytes
        if name in self._synced:
            self._synced[name][...] = host

    def _download_host_sensors(self) -> None:
        """Copy down only the `host_sensors` columns of sensordata, gathered on the device."""
        import torch

        sensordata = self.device_views()["sensordata"]
        if self._host_sensor_index is None:
            self._host_sensor_index = torch.as_tensor(self.host_sensors, device=sensordata.device)
        rows = sensordata[:, self._host_sensor_index].cpu().numpy()
        self._host["sensordata"][:, self.host_sensors] = rows
        self.host_bytes += rows.nbytes

    @property
    def batch(self) -> WarpSim:
        """Itself: code written for the C batch reads `sim.batch.state` and `sim.batch.expanded`."""
        return self

    @property
    def nstate(self) -> int:
        return mujoco.mj_stateSize(self.model, _S.mjSTATE_INTEGRATION)

    @property
    def state(self) -> IntegrationState:
        """(N, nstate) integration states in MuJoCo's layout (as `mujoco.batch.Batch.state`), float64.

        Read as a copy, written through: ``sim.state[ids] = rows``. The layout is the C
        engine's, so states (checkpoints) move between the two backends.
        """
        return IntegrationState(self)

    def device_views(self) -> dict[str, Any]:
        """Torch tensors over the device arrays (no copy): sensordata, xpos, xmat (N, nbody, 9), qpos, qvel.

        They hold what the engine computed in its last call, whatever the host mirrors hold.
        Each engine call ends by reading the device (the mirrors' download, the overflow
        flags), which waits for its kernels, so torch reads finished arrays.
        """
        if self._device_views is None:
            wp = self._wp
            views = {name: wp.to_torch(getattr(self.wdata, name))
                     for name in ("sensordata", "xpos", "xmat", "qpos", "qvel")}
            views["xmat"] = views["xmat"].reshape(self.num_envs, self.model.nbody, 9)
            self._device_views = views
        return self._device_views

    def set_const(self, ids: np.ndarray) -> None:
        """Nothing to do: MuJoCo Warp derives the mass matrix from `body_mass` every step."""

    def expand(self, field: str) -> np.ndarray:
        """Per-env (N, ...) values of model field `field` (e.g. 'body_mass', 'opt.gravity'), writable.

        The engine indexes every batchable model field by world modulo its leading size,
        so swapping in an (N, ...) array makes the field per-env without recompiling.
        """
        if field in self._expanded:
            return self._expanded[field][1]
        owner, name = (self.wmodel.opt, field[4:]) if field.startswith("opt.") else (self.wmodel, field)
        array = getattr(owner, name, None)
        if array is None or not hasattr(array, "shape") or array.shape[0] != 1:
            raise ValueError(f"model field {field!r} cannot be made per-env on MuJoCo Warp")
        wp = self._wp
        values = np.repeat(array.numpy(), self.num_envs, axis=0)
        new = wp.array(values, dtype=array.dtype, device=self.device)
        setattr(owner, name, new)
        view = self._view(new)
        self._expanded[field] = (new, view)
        if self.mirror:
            self._synced[field] = view.copy()
        return view

    def expanded(self, field: str) -> np.ndarray | None:
        """The per-env values of `field` if `expand` made it per-env, else None."""
        entry = self._expanded.get(field)
        return None if entry is None else entry[1]

    # --- engine calls ------------------------------------------------------------------
    def _set_mask(self, ids) -> np.ndarray:
        mask = np.zeros(self.num_envs, bool)
        mask[ids] = True
        self._mask.assign(mask)
        self.host_bytes += mask.nbytes if self.mirror else 0
        return mask

    def reset(self, ids: np.ndarray) -> None:
        """Reset envs `ids` to the model defaults (write qpos etc. after, then `forward`)."""
        self._upload()
        self._set_mask(ids)
        self._mjw.reset_data(self.wmodel, self.wdata, reset=self._mask)
        self._engine_changed(_FIELDS)

    def forward(self, ids: np.ndarray | None = None) -> None:
        """Recompute derived quantities (poses, contacts, sensors) of envs `ids` at their state.

        The engine recomputes every world; the other envs' derived arrays are put back, so
        they stay those of the start of their last substep, as with the C engine.
        """
        self._upload()
        keep = None
        if ids is not None:
            keep = ~self._set_mask(ids)
            saved = {name: getattr(self.wdata, name).numpy()[keep].copy() for name in _DERIVED}
        self._mjw.forward(self.wmodel, self.wdata)
        if keep is not None and keep.any():
            for name, rows in saved.items():
                array = getattr(self.wdata, name)
                full = array.numpy()  # a view on the CPU, a copy from a GPU
                full[keep] = rows
                if self.mirror:
                    array.assign(full)
                    self.host_bytes += 2 * full.nbytes  # down, then up again
        self._engine_changed(_ENGINE_WRITES)

    def step(self, nstep: int) -> np.ndarray:
        """Advance every env by `nstep` physics steps; return a (N,) mask of diverged envs."""
        self._upload()
        for _ in range(nstep):
            self._mjw.step(self.wmodel, self.wdata)
        self._engine_changed(_ENGINE_WRITES)
        bad = ~(np.abs(self.qvel).max(1, initial=0.0) <= self.max_speed) | ~np.isfinite(self.qpos).all(1)
        bad |= self._overflowed()
        if bad.any():
            log.warning("simulation diverged in envs %s; they will be reset", np.flatnonzero(bad).tolist())
        return bad

    def step_controls(self, controls: np.ndarray) -> np.ndarray:
        """Step k with ``ctrl = controls[:, k]`` (N, nstep, nu), one physics step at a time."""
        return step_each(self, controls)

    def _overflowed(self) -> np.ndarray:
        """(N,) envs whose step lost constraint rows; raise if the shared contact pool overflowed.

        The flags stay set until an env is reset, which the caller does to a diverged env.
        """
        flags = self.wdata.overflow.numpy()
        self.host_bytes += flags.nbytes if self.mirror else 0
        pool = [what for bit, what in _POOL_OVERFLOWS.items() if np.bitwise_or.reduce(flags) & bit]
        if pool:
            raise RuntimeError(f"MuJoCo Warp ran out of room for {' and '.join(pool)} ({self.nconmax} per env): "
                               "raise sim.warp_nconmax")
        lost = (flags & sum(_ENV_OVERFLOWS)) != 0
        if lost.any():
            names = [what for bit, what in _ENV_OVERFLOWS.items() if np.bitwise_or.reduce(flags[lost]) & bit]
            log.warning("MuJoCo Warp ran out of %s in envs %s", " and ".join(names), np.flatnonzero(lost).tolist())
        return lost


class IntegrationState:
    """A `WarpSim`'s integration states as an (N, nstate) array: gathered on read, scattered on write."""

    def __init__(self, sim: WarpSim):
        self._sim = sim
        self.shape = (sim.num_envs, sim.nstate)
        self._parts: list[tuple[str, slice]] = []  # (Data field, columns)
        start = 0
        for component, name in _INTEGRATION_STATE:
            size = mujoco.mj_stateSize(sim.model, component)
            if size:
                if name is None:
                    raise WarpUnavailable(f"sim.backend: warp does not carry the model's {component.name} state")
                self._parts.append((name, slice(start, start + size)))
            start += size

    def copy(self) -> np.ndarray:
        sim = self._sim
        sim._upload()  # mirror mode: the host copies of the state are the current ones
        out = np.empty(self.shape)
        for name, columns in self._parts:
            out[:, columns] = getattr(sim.wdata, name).numpy().reshape(sim.num_envs, -1)
        return out

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        return self.copy() if dtype is None else self.copy().astype(dtype)

    def __getitem__(self, index) -> np.ndarray:
        return self.copy()[index]

    def __setitem__(self, index, values) -> None:
        sim = self._sim
        full = self.copy()
        full[index] = values
        for name, columns in self._parts:
            array = getattr(sim.wdata, name)
            rows = full[:, columns].reshape(array.numpy().shape)
            if sim.mirror:
                array.assign(rows.astype(array.numpy().dtype))
            else:
                array.numpy()[...] = rows
        sim._engine_changed(_FIELDS)  # written on the device: the host reads them anew
