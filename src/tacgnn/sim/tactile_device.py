"""The skin's taxel model in torch, on the device of the physics (CPU or GPU).

The same model as `tactile.py` (a Hertzian disc per contact, threshold, counter-based
noise with the same draws), written with fixed shapes so that a GPU runs it without
host round trips: every contact slot of every patch is paired with every taxel of its
patch, K x T pairs per env (2,612 for the default skin), and the pairs a disc does not
reach add zero; the pairs are laid out (K, T), so the readings are a sum over K. The candidate
grid of `tactile.py` saves work on a CPU thread; on a GPU, fixed shapes are worth more than
skipped pairs.

Input arrays may be numpy (returned as numpy, sharing memory on the CPU) or torch tensors
(returned as tensors on their device), e.g. `WarpSim.device_views()`. An env on Warp calls
`engine_readings` / `engine_positions`: they read the engine's device arrays themselves, so
the skin's inputs are never staged on the host, and return tensors on the device (each env's
latest also kept as `device_readings`, `device_positions`); a consumer that needs numpy asks
`to_host`, counted in `host_bytes`.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.sim.tactile import _GOLDEN, _MIX1, _MIX2, _NORMAL_BITS, TactileModel, draw_step_seed, normal_table


def _signed(value: np.uint64) -> int:
    """The int64 with the bits of a uint64 (torch has no uint64 arithmetic)."""
    return int(np.uint64(value).view(np.int64))


def _shift_right(z: torch.Tensor, k: int) -> torch.Tensor:
    """Logical right shift of int64 bits (torch's >> is arithmetic)."""
    return (z >> k) & ((1 << (64 - k)) - 1)


class DeviceTactile:
    """Taxel readings and positions of N envs, as `TactileModel`, in torch.

    Args:
        layout: the skin.
        model: a compiled model with the skin's sensors (see `add_skin_sensors`).
        device: torch device of the tensors it is given.

    Shapes (N envs, T taxels):
        readings(sensordata (N, nsensordata), xpos (N, nbody, 3), xmat (N, nbody, 9), rng) -> (N, T) float32
        positions(xpos, xmat) -> (N, T, 3) float32
        engine_readings(sim, ids, rng) -> (len(ids), T) tensor; device_readings (N, T) tensor
        engine_positions(sim, ids) -> (len(ids), T, 3) tensor; device_positions (N, T, 3) tensor

    Attributes:
        host_bytes: bytes of host arrays it took in or handed out so far: what a GPU run
            copies over the bus for the skin (on the CPU the numpy views cost no copy).
    """

    def __init__(self, layout: SkinLayout, model: mujoco.MjModel, device: str | torch.device = "cpu"):
        ref = TactileModel(layout, model)
        self.layout, self.num_taxels = layout, layout.num_taxels
        self.device = torch.device(device)
        dev = self.device
        patches = layout.patches
        patch_of_slot = ref._patch_of_slot  # (S,) slots: patch-major, K contacts per patch
        self.force_idx = torch.as_tensor(ref._force_idx.ravel(), device=dev)
        self.pos_idx = torch.as_tensor(ref._pos_idx.reshape(-1, 3), device=dev)
        self.slot_body = torch.as_tensor(ref.body_ids[patch_of_slot], device=dev)
        self.slot_radius = torch.as_tensor(ref._radius[patch_of_slot], device=dev)  # a_1N, float64
        self.slot_floor = torch.as_tensor(ref._floor_over_a2[patch_of_slot], device=dev)  # k E / a^2
        # pairs (k, taxel t) for k < K: t with its patch's k-th contact slot; (K * T,) row-major
        k_count = ref.contacts_per_patch
        slot_of_pair = ref.patch_of_taxel[None, :] * k_count + np.arange(k_count)[:, None]
        self.slot_of_pair = torch.as_tensor(slot_of_pair.ravel(), device=dev)
        self.pair_xyz = torch.as_tensor(np.tile(ref.local_positions.T, (1, k_count)), device=dev)  # (3, K * T)
        patch_onehot = np.eye(len(patches))[ref.patch_of_taxel]  # (T, P): sums each patch's taxels
        self.patch_onehot = torch.as_tensor(patch_onehot, dtype=torch.float32, device=dev)
        self.contacts_per_patch = k_count
        self.body_of_taxel = torch.as_tensor(ref.body_ids[ref.patch_of_taxel], device=dev)
        self.local_positions = torch.as_tensor(ref.local_positions, device=dev)  # (T, 3) float32
        self.table = torch.as_tensor(normal_table(), device=dev)
        self.num_slots = len(patch_of_slot)
        self.host_bytes = 0
        self.device_readings: torch.Tensor | None = None
        self.device_positions: torch.Tensor | None = None

    def _tensor(self, array) -> torch.Tensor:
        """A tensor on the device; numpy input shares memory where it can (read-only arrays are copied)."""
        if isinstance(array, np.ndarray):
            self.host_bytes += array.nbytes  # staged from the host: crosses the bus on a GPU
            if not array.flags.writeable:
                array = array.copy()
        return torch.as_tensor(array, device=self.device)

    def to_host(self, out: torch.Tensor) -> np.ndarray:
        """A tensor of the skin's as numpy; its bytes count in `host_bytes` (on a GPU, a copy)."""
        self.host_bytes += out.numel() * out.element_size()
        return out.cpu().numpy()

    # --- fed by the engine's device arrays -----------------------------------------------
    def _engine_views(self, sim, ids) -> tuple[slice | torch.Tensor, list[torch.Tensor]]:
        """Rows `ids` of the engine's sensordata, xpos and xmat, as tensors on its device (no copy
        for a slice), and the row index as used."""
        views = sim.device_views()
        if not isinstance(ids, slice):
            ids = np.asarray(ids)
            self.host_bytes += ids.nbytes  # the row indices go up (reset steps only)
            ids = torch.as_tensor(ids, device=self.device)
        return ids, [views[name][ids] for name in ("sensordata", "xpos", "xmat")]

    @staticmethod
    def _keep(last: torch.Tensor | None, ids: slice | torch.Tensor, out: torch.Tensor,
              num_envs: int) -> torch.Tensor:
        """All envs' results with rows `ids` replaced by `out`: a new tensor, so that a host copy
        handed out before (the same memory on the CPU) does not change."""
        if isinstance(ids, slice) and ids == slice(None):
            return out
        full = out.new_zeros((num_envs, *out.shape[1:])) if last is None else last.clone()
        full[ids] = out
        return full

    def engine_readings(self, sim, ids: slice | np.ndarray = slice(None),
                        rng: np.random.Generator | None = None) -> torch.Tensor:
        """Readings (len(ids), T) of envs `ids` of `sim` (a `WarpSim`), read from its device arrays.

        The same model and noise draws as `readings`, with no input staged on the host and none
        handed back: a tensor on the device; `device_readings` (N, T) holds each env's latest
        (zero before its first).
        """
        index, (sensordata, xpos, xmat) = self._engine_views(sim, ids)
        out = self.readings(sensordata, xpos, xmat, rng)
        self.device_readings = self._keep(self.device_readings, index, out, sim.num_envs)
        return out

    def engine_positions(self, sim, ids: slice | np.ndarray = slice(None)) -> torch.Tensor:
        """World taxel positions (len(ids), T, 3) of envs `ids` of `sim`, from its device arrays, as a
        tensor on the device; each env's latest also kept as `device_positions` (N, T, 3)."""
        index, (_, xpos, xmat) = self._engine_views(sim, ids)
        out = self.positions(xpos, xmat)
        self.device_positions = self._keep(self.device_positions, index, out, sim.num_envs)
        return out

    def contacts(self, sensordata):
        """Normal forces (N, P, K) and world contact points (N, P, K, 3) from sensordata."""
        as_numpy = isinstance(sensordata, np.ndarray)
        data = self._tensor(sensordata)
        k = self.contacts_per_patch
        force = data[:, self.force_idx].reshape(len(data), -1, k)
        point = data[:, self.pos_idx].reshape(len(data), -1, k, 3)
        return (force.cpu().numpy(), point.cpu().numpy()) if as_numpy else (force, point)

    def readings(self, sensordata, xpos, xmat, rng: np.random.Generator | None = None):
        """Taxel readings (N, T): each contact's normal force spread over its patch."""
        as_numpy = isinstance(sensordata, np.ndarray)
        sensordata, xpos, xmat = (self._tensor(a) for a in (sensordata, xpos, xmat))
        n = sensordata.shape[0]
        noise = self.layout.noise if rng is not None else 0.0
        seed = draw_step_seed(rng) if rng is not None and noise > 0 else np.uint64(0)  # as TactileModel draws

        force = sensordata[:, self.force_idx]  # (N, S) normal forces, 0 in empty slots
        point = sensordata[:, self.pos_idx]  # (N, S, 3) world contact points
        rot = xmat[:, self.slot_body].reshape(n, -1, 3, 3)
        # contact point in the link frame: R^T (c - x), in float64 as the compiled kernel does
        # (on float32 inputs, a float32 transform moved readings at a disc's rim by 2e-5 N)
        f64 = torch.float64
        local = torch.einsum("nsji,nsj->nsi", rot.to(f64), point.to(f64) - xpos[:, self.slot_body].to(f64))
        local = local.to(torch.float32)
        pressed = force > 0
        f = torch.where(pressed, force, torch.zeros_like(force)).to(torch.float64)
        radius = self.slot_radius * torch.pow(f, 1.0 / 3.0)  # a = a_1N F^(1/3)
        a2 = radius * radius
        # u = sqrt(max(0, a^2 - d^2)) per (k, taxel) pair, float32 as in tactile.py
        k_count, t_count = self.contacts_per_patch, self.num_taxels
        at_pair = local.permute(2, 0, 1).index_select(2, self.slot_of_pair)  # (3, N, K * T)
        u = a2.to(torch.float32).index_select(1, self.slot_of_pair)
        for axis in range(3):
            diff = self.pair_xyz[axis] - at_pair[axis]
            u = u - diff * diff
        u = torch.sqrt(torch.clamp(u, min=0.0)).reshape(n, k_count, t_count)
        total = (u @ self.patch_onehot).transpose(1, 2).reshape(n, -1)  # (N, S): each slot's sum of u
        # f_i = F u_i / max(sum u, k E a); empty slots have F = 0 and a = 0
        denom = torch.maximum(total.to(torch.float64), self.slot_floor * a2 * radius)
        scale = torch.where(pressed, f / torch.where(pressed, denom, torch.ones_like(denom)), torch.zeros_like(f))
        u = u * scale.to(torch.float32).index_select(1, self.slot_of_pair).reshape(n, k_count, t_count)
        out = u.sum(1)  # readings of several contacts add
        out = torch.where(out < self.layout.threshold, torch.zeros_like(out), out)  # below the threshold: 0
        if noise > 0:
            out = out * (1.0 + noise * self._normal(seed, n))
            out = torch.clamp(out, min=0.0)
        return self.to_host(out) if as_numpy else out

    def _normal(self, seed: np.uint64, n: int) -> torch.Tensor:
        """`tactile.counter_normal` for flat indices env * T + taxel, in int64 bit arithmetic."""
        z = torch.arange(n * self.num_taxels, dtype=torch.int64, device=self.device)
        z = z * _signed(_GOLDEN) + _signed(seed)
        z = (z ^ _shift_right(z, 30)) * _signed(_MIX1)
        z = (z ^ _shift_right(z, 27)) * _signed(_MIX2)
        z = z ^ _shift_right(z, 31)
        return self.table[_shift_right(z, 64 - _NORMAL_BITS)].reshape(n, self.num_taxels)

    def positions(self, xpos, xmat):
        """World positions (N, T, 3) of all taxels: x_link + R_link p_local."""
        as_numpy = isinstance(xpos, np.ndarray)
        xpos, xmat = (self._tensor(a) for a in (xpos, xmat))
        n = xpos.shape[0]
        rot = xmat[:, self.body_of_taxel].reshape(n, -1, 3, 3).to(torch.float32)
        out = torch.einsum("ntij,tj->nti", rot, self.local_positions) + xpos[:, self.body_of_taxel].to(torch.float32)
        return self.to_host(out) if as_numpy else out
