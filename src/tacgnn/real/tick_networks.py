"""The policy's networks on one frame, for the control tick: the same arithmetic, fewer and cheaper calls.

Why: a tick runs the perception and the actor on a single frame, on a machine whose
cores other work keeps busy. Measured inside the ROS controller node (2 loaded cores),
the TacGNN forward took 2.1 ms at the median and 8.8 ms at p99, almost all of it in
the graph kernels of `tacgnn.perception.graph_numba`: they are compiled ``parallel``
(for training batches), and on one frame entering and leaving their OpenMP region costs
far more than the work (15x slower than a serial copy at equal priority under load).
Here the same kernels are compiled serially, and the layers are called directly on the
frame's active taxels, without the batch bookkeeping. The actor skips the TensorDict
wrapping. Every torch op is the one the models run, on the same operands, so the
outputs are bit-identical to `OnlinePerception` and `load_policy` (the actor is compared
with the loaded policy at construction and the loaded one kept if they differ; the
perception's sameness is asserted by tests/test_real_tick_networks.py, not at run time).

Threads: the ROS loop ticks on the threads that receive messages. Torch sets a thread's
OpenMP/MKL thread count lazily, on its first parallel op; a first matmul before that
ran on more threads and rounded differently (a few ulps in one tick, which then carries
through the controller's state). Each call therefore asks `torch.get_num_threads()`
first, which does that set-up.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any, cast

import numpy as np
import torch
from torch import Tensor, nn

log = logging.getLogger("tacgnn.real")
_serial_kernels: tuple[Any, Any, Any] | None = None


def serial_graph_kernels() -> tuple[Any, Any, Any] | None:
    """(knn_table, fps_order, lex_order) of `graph_numba` compiled without ``parallel`` (None without numba)."""
    global _serial_kernels
    if _serial_kernels is None:
        from tacgnn.perception import graph_numba

        kernels = graph_numba._compile()  # the kernels' Python functions are the reference: compile them serially
        if not kernels:
            return None
        import numba

        _serial_kernels = cast(tuple[Any, Any, Any], tuple(numba.njit(nogil=True)(k.py_func) for k in kernels))
    return _serial_kernels


class TickPerception:
    """One frame through a TacGNN perception: (1, T) readings, (1, T, 3) taxel positions (m) -> (1, 6) m.

    Called like `OnlinePerception` (same arguments, same output, bit for bit); use
    `TickPerception.wrap(perception)`, which returns the perception itself where this
    path does not apply (other models, settings the graph kernels do not cover).
    """

    def __init__(self, perception: Any, kernels: tuple[Any, Any, Any]):
        from tacgnn.perception.models.tacgnn import LOG_FORCE_FLOOR

        self.perception = perception
        self.model = model = perception.model
        self.cfg = cfg = model.cfg
        self.joint_inputs = int(perception.joint_inputs)
        self.knn, self.fps, self.lex = kernels
        self.num_taxels = model.num_taxels
        self.log_floor = LOG_FORCE_FLOOR
        self.loop = bool(cfg.self_loop)
        self.centroid = cfg.fps_start == "centroid"
        self.sample = [layer in model.downsample_layers for layer in range(len(model.convs))]
        # the first layer's split weights, as EdgeMaxConv.forward builds them on every call
        self.weights = []
        with torch.no_grad():
            for conv in model.convs:
                W_i, W_j, W_x = conv.lin1.weight.split([conv.in_channels, conv.in_channels, 3], dim=1)
                self.weights.append((torch.cat([W_i, -W_x], 1).t(), torch.cat([W_j, W_x], 1).t()))
        model.eval()
        self.pooled_dim = cast(nn.Linear, model.head[0]).in_features - self.joint_inputs

    @classmethod
    def wrap(cls, perception: Any) -> Callable[..., np.ndarray]:
        """`perception` on the tick's path where it applies (a single-frame TacGNN), else itself."""
        from tacgnn.learning.online_perception import OnlinePerception
        from tacgnn.perception.models.tacgnn import TacGNN

        model = getattr(perception, "model", None)
        if type(perception) is not OnlinePerception or type(model) is not TacGNN:
            return perception
        cfg = model.cfg
        if cfg.exact_graph or cfg.fps_start not in ("centroid", "first") or model.dtype != torch.float32 \
                or not model.use_compiled_graphs:
            return perception
        kernels = serial_graph_kernels()
        return perception if kernels is None else cls(perception, kernels)

    @torch.inference_mode()
    def __call__(self, readings: np.ndarray, taxel_pos: np.ndarray, joints: np.ndarray | None = None) -> np.ndarray:
        torch.get_num_threads()  # sets this thread's torch threads up first (module docstring)
        readings = np.asarray(readings, np.float32)
        if readings.shape != (1, self.num_taxels) or np.asarray(taxel_pos).shape != (1, self.num_taxels, 3):
            return self.perception(readings, taxel_pos, joints)  # not one frame: the batched model
        r = readings[0]
        if np.isnan(r).any():
            raise ValueError("readings contain NaN")
        active = np.flatnonzero(r > 0)
        x_np = np.asarray(taxel_pos[0][active] * 100.0, np.float32)  # cm, rounded as OnlinePerception rounds
        j = None
        if self.joint_inputs:
            if joints is None:
                raise ValueError(f"this model reads {self.joint_inputs} joint angles: pass joints")
            j = torch.from_numpy(np.ascontiguousarray(joints, np.float32)).reshape(1, self.joint_inputs)
            if not torch.isfinite(j.sum()):
                raise ValueError("joints contain NaN or inf")
        return self._nodes(x_np, r[active], j).numpy().astype(np.float64) / 100.0

    def _nodes(self, x_np: np.ndarray, force_np: np.ndarray, joints: Tensor | None) -> Tensor:
        """`TacGNN.forward_nodes` for one graph of the active taxels (positions in cm)."""
        model, cfg = self.model, self.cfg
        if not np.isfinite(x_np.sum()):
            raise ValueError("positions of activated taxels contain NaN or inf")
        n = len(x_np)
        if n == 0:  # the blind area: the pooled feature is 0
            return model._readout(torch.zeros(1, self.pooled_dim), joints)
        keys = np.ascontiguousarray(np.concatenate([x_np.T, force_np[None]]), np.float32)
        order = self.lex(keys, np.array([0, n], np.int64))
        x = torch.from_numpy(np.ascontiguousarray(x_np[order]))
        if cfg.pos_scale != 1.0:
            x = x * cfg.pos_scale
        h = x
        if cfg.use_force:
            f = torch.from_numpy(np.ascontiguousarray(force_np[order])).unsqueeze(1)
            if cfg.force_feature == "log":
                f = torch.log(f.clamp_min(self.log_floor))
            h = torch.cat([x, f], 1)
        graph_x = np.ascontiguousarray(x.numpy().T)  # (3, n): the graph builder's coordinates
        sampled = False
        pooled: list[Tensor] = []
        last = len(model.convs) - 1
        for layer, conv in enumerate(model.convs):
            ptr = np.array([0, n], np.int64)
            k = max(1, min(model.k[layer], n if self.loop else n - 1))
            neighbours = torch.from_numpy(self.knn(graph_x, ptr, k, self.loop))
            keep = None
            if self.sample[layer]:
                kept = math.ceil(float(n) * cfg.sample_ratio)
                if sampled:  # later levels keep a prefix of the first FPS order
                    keep = torch.arange(kept)
                else:
                    keep = torch.from_numpy(self.fps(graph_x, ptr, np.array([kept], np.int64), self.centroid))
                    sampled = True
            h_new = self._conv(conv, self.weights[layer], h, x, neighbours)
            h = h_new + h if model.residual and h.shape == h_new.shape else h_new
            if model.pool != "last" and layer < last:
                pooled.append(model._segment_max(h, torch.tensor([n])))
            if keep is not None:
                h, x = h.index_select(0, keep), x.index_select(0, keep)
                graph_x = np.ascontiguousarray(graph_x[:, keep.numpy()])
                n = len(keep)
        pooled.append(model._segment_max(h, torch.tensor([n])))
        return model._finish(pooled, joints)

    @staticmethod
    def _conv(conv: Any, weights: tuple[Tensor, Tensor], h: Tensor, pos: Tensor, neighbours: Tensor) -> Tensor:
        """`EdgeMaxConv.forward` with its split weights made once."""
        target_w, source_w = weights
        hx = torch.cat([h, pos], 1)
        a = torch.addmm(conv.lin1.bias, hx, target_w)
        c = hx @ source_w
        K, V = neighbours.shape
        c_j = c.index_select(0, neighbours.reshape(-1)).view(K, V, -1)
        return conv.update(conv.aggregate(conv.message(a, c_j)))


class TickPolicy:
    """The actor's mean action for (1, obs_dim) observations: normaliser and MLP called directly.

    `TickPolicy.wrap(policy, path)` returns `policy` itself where the checkpoint's actor
    does not give the same actions this way.
    """

    def __init__(self, normalizer: nn.Module, mlp: nn.Module, obs_dim: int):
        self.normalizer, self.mlp, self.obs_dim = normalizer, mlp, obs_dim

    @classmethod
    def wrap(cls, policy: Callable[[np.ndarray], np.ndarray], path: str) -> Callable[[np.ndarray], np.ndarray]:
        from rsl_rl.models import MLPModel
        from tensordict import TensorDict

        from tacgnn.config import from_dict
        from tacgnn.learning import checkpoint as ckpt
        from tacgnn.learning.config import PPOConfig

        data = ckpt.load_policy_file(path)
        actor_cfg = dict(from_dict(PPOConfig, data["ppo_config"]).rsl_rl_cfg()["actor"])
        actor_cfg.pop("class_name")
        example = TensorDict({"policy": torch.zeros(1, data["obs_dim"])}, batch_size=[1])
        actor = MLPModel(example, {"actor": ["policy"]}, "actor", data["num_actions"], **actor_cfg)
        actor.load_state_dict(data["actor_state_dict"])
        actor.eval()
        fast = cls(actor.obs_normalizer, actor.mlp, data["obs_dim"])
        probe = np.random.default_rng(0).standard_normal((4, data["obs_dim"])).astype(np.float32)
        if all(np.array_equal(fast(p[None]), policy(p[None])) for p in probe):
            return fast
        log.info("policy %s: the direct actor call differs from the loaded policy; using the loaded one", path)
        return policy

    @torch.inference_mode()
    def __call__(self, obs: np.ndarray) -> np.ndarray:
        torch.get_num_threads()  # sets this thread's torch threads up first (module docstring)
        x = torch.as_tensor(np.asarray(obs), dtype=torch.float32)
        if x.ndim != 2 or x.shape[1] != self.obs_dim:
            raise ValueError(f"the policy reads ({self.obs_dim},) observations, got shape {tuple(x.shape)}")
        return self.mlp(self.normalizer(x)).numpy()
