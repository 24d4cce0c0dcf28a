"""TacGNN: a hierarchical dynamic-graph network over the activated taxels."""

from __future__ import annotations

from typing import cast

import torch
from torch import Tensor, nn

from tacgnn.perception.models.base import PerceptionModel, mlp
from tacgnn.perception.models.config import PerceptionModelConfig
from tacgnn.perception.models.edge_conv import EdgeMaxConv
from tacgnn.perception.models.graphs import (
    CompiledGraphs,
    GraphBuilder,
    TorchGraphs,
    canonical_order,
    compiled_graphs_apply,
)

LOG_FORCE_FLOOR = 1e-6  # N: log force of a barely pressed taxel stays finite


class TacGNN(PerceptionModel):
    r"""TacGNN (Yang et al., RA-L 2023): hierarchical dynamic-graph network over activated taxels.

    Nodes are the taxels with reading > 0, node input :math:`h^0_i = x_i`
    (position, times ``pos_scale``) or :math:`[x_i, g(f_i)]` with ``use_force``,
    :math:`g(f) = \log(f / 1\,\mathrm{N})` (``force_feature="log"``) or :math:`g(f) = f`
    (``"raw"``). The log turns the skin's multiplicative noise and the unknown contact
    force into additive offsets that a difference :math:`g(f_j) - g(f_i)` along an edge
    cancels. Layer :math:`l = 1..L`:

    1. rebuild the graph: :math:`\mathcal{N}(i)` = the :math:`k_l` nearest current nodes
       (dynamic graph, recomputed every forward);
    2. :class:`EdgeMaxConv`:
       :math:`h^l_i = \mathrm{ReLU}(\max_{j} \phi_l([h^{l-1}_i, h^{l-1}_j, x_j - x_i]))`
       (plus :math:`h^{l-1}_i` with ``residual`` where the widths match);
    3. if ``l`` is in ``downsample_layers``: farthest point sampling keeps
       :math:`\lceil r \cdot n \rceil` nodes (positions and features).

    Readout (``pool``): ``"last"`` (the paper) :math:`y = \mathrm{MLP}(\max_i h^L_i)`,
    MLP ``[C, C, out]``; ``"jk"`` pools every layer before its downsampling,
    :math:`z = W[\max_i h^1_i, \dots, \max_i h^L_i]` with a bias-free
    :math:`W: LC \to C`, and :math:`y = \mathrm{MLP}(z)`, MLP ``[C, LC, out]``;
    ``"all"`` skips :math:`W` (MLP ``[LC, LC, out]``); ``"sum"`` adds the pooled layers.
    The first layer's features see all activated taxels; with ``"last"`` they reach the
    head only through two more layers and two rounds of FPS (measured ~10% lower RMSE
    with ``"jk"`` on Baoding). With ``joint_inputs`` the joint angles join the pooled
    feature at the head's input.

    Tactile blind area: a node without neighbours (a frame with one activated taxel)
    is its own neighbour, :math:`\phi([h_i, h_i, 0])`, so its position still reaches
    the head; an empty frame pools to 0 (features are ReLU outputs, :math:`\ge 0`) and
    gives the finite output :math:`\mathrm{MLP}(0)`.

    Order: kNN and max are set functions, FPS starts at the node farthest from the
    centroid (``fps_start="centroid"``), and ties are broken on nodes sorted by position
    (:func:`~tacgnn.perception.models.graphs.canonical_order`), so the output does not
    depend on the order of the taxels.

    Graphs are built without autograd (indices only) by a
    :class:`~tacgnn.perception.models.graphs.GraphBuilder`: the numba kernels on CPU
    (:attr:`use_compiled_graphs`), else batched torch ops, exact with ``exact_graph``.

    Args:
        cfg: the model's :class:`PerceptionModelConfig` (``name="tacgnn"`` fields).

    Shapes:
        - **input:** ``readings (B, T)``, ``positions (B, T, 3)``, ``joints (B, J)``
        - **output:** ``(B, out_dim)``
    """

    use_compiled_graphs: bool = True
    """False: the torch graph builder even where the numba one applies (tests compare the two)."""

    def __init__(self, cfg: PerceptionModelConfig | None = None) -> None:
        super().__init__()
        cfg = cfg or PerceptionModelConfig()
        self.cfg = cfg
        self.num_taxels, self.out_dim, self.joint_inputs = cfg.num_taxels, cfg.out_dim, cfg.joint_inputs
        self.k, self.downsample_layers = cfg.k, frozenset(cfg.downsample_layers)
        self.pool, self.residual = cfg.pool, cfg.residual
        C, L = cfg.channels, len(cfg.k)
        in_ch = 4 if cfg.use_force else 3
        self.convs = nn.ModuleList(
            EdgeMaxConv(in_ch if layer == 0 else C, C, cfg.message_layers) for layer in range(L)
        )
        # no bias: an empty frame (all pooled features 0) still reads head(0)
        self.jk = nn.Linear(L * C, C, bias=False) if cfg.pool == "jk" and L > 1 else None
        pooled = C * (L if cfg.pool == "all" else 1)
        hidden = cfg.head_hidden or C * (L if cfg.pool in ("all", "jk") else 1)
        self.head = mlp([pooled + cfg.joint_inputs] + [hidden] * (cfg.head_layers - 1) + [cfg.out_dim])

    def forward(self, readings: Tensor, positions: Tensor, joints: Tensor | None = None) -> Tensor:
        readings, positions, joints = self.prepare(readings, positions, joints)
        B, T = readings.shape
        active = (readings > 0).reshape(-1).nonzero().squeeze(1)  # frame by frame
        x = positions.reshape(B * T, 3).index_select(0, active)
        if not torch.isfinite(x.sum()):  # one cheap reduction instead of a mask
            raise ValueError("positions of activated taxels contain NaN or inf")
        force = readings.reshape(-1).index_select(0, active) if self.cfg.use_force else None
        return self.forward_nodes(x, torch.div(active, T, rounding_mode="floor"), B, force, joints)

    def forward_pyg(self, data) -> Tensor:
        """Interop: a torch_geometric ``Data``/``Batch`` whose nodes are the activated taxels.

        Uses ``data.pos (V, 3)``, ``data.batch`` (``None`` = one graph) and, with
        ``use_force``, ``data.x`` of shape ``(V,)`` or ``(V, 1)`` as force; ``data.joints``
        if the model reads joint angles. Returns ``(num_graphs, out_dim)``.
        """
        batch = getattr(data, "batch", None)
        B = int(data.num_graphs) if batch is not None else 1
        if batch is None:
            batch = torch.zeros(data.pos.shape[0], dtype=torch.long, device=data.pos.device)
        force = None
        if self.cfg.use_force:
            if data.x is None:
                raise ValueError("use_force=True needs data.x (force per node)")
            force = data.x.reshape(-1)
        return self.forward_nodes(data.pos, batch, B, force, getattr(data, "joints", None))

    def forward_nodes(self, x: Tensor, batch: Tensor, num_graphs: int, force: Tensor | None = None,
                      joints: Tensor | None = None) -> Tensor:
        """The network on a flat node list (PyG style), nodes in any order.

        Shapes:
            - **input:** ``x (V, 3)`` positions, ``batch (V,)`` graph ids,
              ``force (V,)`` (only with ``use_force``), ``joints (B, J)``
            - **output:** ``(num_graphs, out_dim)``
        """
        B, cfg = num_graphs, self.cfg
        x = x.to(self.dtype)
        joints = None if joints is None else joints.to(x.dtype)
        if x.shape[0] == 0:  # whole batch in the blind area: the pooled feature is 0
            pooled_dim = cast(nn.Linear, self.head[0]).in_features - self.joint_inputs
            return self._readout(x.new_zeros(B, pooled_dim), joints)
        order = canonical_order(x.detach(), batch, None if force is None else force.detach().reshape(-1))
        x, batch = x.index_select(0, order), batch.index_select(0, order)
        if cfg.pos_scale != 1.0:
            x = x * cfg.pos_scale
        h = x
        if force is not None:
            f = force.reshape(-1).index_select(0, order).to(x.dtype).unsqueeze(1)
            if cfg.force_feature == "log":
                f = torch.log(f.clamp_min(LOG_FORCE_FLOOR))
            h = torch.cat([x, f], 1)
        graphs = self.graph_builder(x, torch.bincount(batch, minlength=B))
        pooled: list[Tensor] = []
        for layer, conv in enumerate(self.convs):
            with torch.no_grad():  # graph structure: indices only
                level = graphs.level(self.k[layer], sample=layer in self.downsample_layers)
            h_new = conv(h, x, level.neighbours)
            h = h_new + h if self.residual and h.shape == h_new.shape else h_new
            if self.pool != "last" and layer < len(self.convs) - 1:
                pooled.append(self._segment_max(h, level.counts))
            if level.keep is not None:
                h, x = h.index_select(0, level.keep), x.index_select(0, level.keep)
        pooled.append(self._segment_max(h, graphs.counts))
        return self._finish(pooled, joints)

    def graph_builder(self, x: Tensor, counts: Tensor) -> GraphBuilder:
        """The numba builder where it applies and is wanted, else the torch one."""
        cfg = self.cfg
        args = (x, counts, cfg.sample_ratio, cfg.self_loop, cfg.fps_start)
        if self.use_compiled_graphs and compiled_graphs_apply(x, cfg.exact_graph, cfg.fps_start):
            return CompiledGraphs(*args)
        return TorchGraphs(*args, exact=cfg.exact_graph)

    @staticmethod
    def _segment_max(h: Tensor, counts: Tensor) -> Tensor:
        """Global max pool of consecutive groups of ``counts`` rows.

        ``h >= 0`` (ReLU outputs, also with ``residual``), so starting the max at 0
        changes nothing and gives 0 for an empty graph; ``segment_reduce`` on the flat
        rows is ~3x faster (forward + backward) than scattering into a padded batch.
        """
        return torch.segment_reduce(h, "max", lengths=counts, unsafe=True, initial=0.0)

    def _finish(self, pooled: list[Tensor], joints: Tensor | None) -> Tensor:
        """Combine the pooled features of the layers (``pool``) and apply the head."""
        if len(pooled) == 1:
            return self._readout(pooled[0], joints)
        if self.pool == "sum":
            return self._readout(torch.stack(pooled).sum(0), joints)
        z = torch.cat(pooled, 1)
        return self._readout(z if self.jk is None else self.jk(z), joints)

    def _readout(self, z: Tensor, joints: Tensor | None) -> Tensor:
        """The head on the pooled skin feature, with the joint angles beside it when the model reads them."""
        return self.head(z if joints is None else torch.cat([z, joints], 1))
