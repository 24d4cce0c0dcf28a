"""Perception models: one tactile frame -> object state (e.g. two ball centres).

All models share one interface::

    model(readings, positions) -> state
    readings  (B, T)     normal force per taxel, 0 when not touched
    positions (B, T, 3)  world position of every taxel (the caller passes cm)
    state     (B, out_dim)

Models (TacGNN, RA-L 2023, and its baselines):

* :class:`TacGNN`  hierarchical dynamic-graph network on the *activated* taxels.
* :class:`TactileMLP`  MLP on the raw readings.
* :class:`TactileCNN`  CNN on the readings packed into a square image.
* :class:`TactileGCN`  GCN on a fixed kNN graph of all taxels.

Build them from a :class:`PerceptionModelConfig` with :func:`build_model`.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from tacgnn.perception import graph_numba
from tacgnn.perception.graph_ops import (
    FPS_STARTS,
    dense_fps,
    dense_knn,
    fps_counts,
    knn_graph,
    pairwise_sqdist,
    sqdist_keys_,
    to_dense,
)

__all__ = [
    "MODEL_NAMES",
    "PerceptionModelConfig",
    "PerceptionModel",
    "TacGNN",
    "EdgeMaxConv",
    "TactileMLP",
    "TactileCNN",
    "TactileGCN",
    "build_model",
    "reading_input",
    "keep_freed_memory",
]

MODEL_NAMES = ("tacgnn", "mlp", "cnn", "gcn")
#: TacGNN force node feature (with ``use_force``): the reading in N, or ``log(f / 1 N)``.
FORCE_FEATURES = ("raw", "log")
#: MLP, CNN and GCN force input: the reading in N ("raw", the paper), or ``log(1 + f / 0.01 N)``
#: ("log1p": 0 where nothing presses, and a force scaled by a constant becomes nearly a shift,
#: as TacGNN's log force does; experiments/perception_inputs.sh).
READING_FEATURES = ("raw", "log1p")
READING_LOG_SCALE = 0.01  # N: log1p's knee; readings well above it are compressed like a log
#: GCN node positions: each taxel's current position ("current", our default; it carries the whole
#: hand's pose), or its fixed rest position ("rest": the nodes' inputs then vary with the forces only,
#: a GCN blind to the hand's pose as the paper describes it, sec. V-A and VI). facts.md gives the
#: node features as [force, xyz] without saying which xyz; docs/results.md, section 14, compares both.
GCN_NODE_POSITIONS = ("current", "rest")
#: TacGNN readout input: global max pool of the last layer ("last", the paper), or of every
#: layer: concatenated ("all", L x C wide), concatenated and mapped to C by a linear layer
#: without bias ("jk", jumping knowledge; the head's input stays C wide) or summed ("sum").
POOLS = ("last", "all", "jk", "sum")


# --------------------------------------------------------------------------
# config
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class PerceptionModelConfig:
    """Hyper-parameters of all perception models (unused fields are ignored).

    The defaults are the paper's TacGNN, and must stay so: checkpoints that
    store a model config from before a field existed (PPO runs with online
    perception) are rebuilt with that field's default. Offline training
    (:class:`tacgnn.perception.train.PerceptionTrainConfig`, ``tacgnn
    train-perception``) starts from better TacGNN settings instead
    (``train.TRAIN_MODEL_DEFAULTS``: log force input, jumping-knowledge pool).

    Lists (e.g. from YAML) are turned into tuples; invalid values raise a
    ``ValueError`` that names the field.
    """

    name: str = "tacgnn"
    out_dim: int = 6
    num_taxels: int = 653
    # TacGNN
    channels: int = 32  # C of every layer; the paper sweeps 16/32/64/128
    k: tuple[int, ...] = (3, 3, 3)  # neighbours per layer; len(k) = number of layers
    sample_ratio: float = 0.5  # FPS keeps ceil(ratio * n) nodes
    downsample_layers: tuple[int, ...] = (0, 1, 2)  # FPS after these layers (0-based)
    use_force: bool = False  # node input [x, y, z, force] instead of [x, y, z]
    self_loop: bool = False  # let a node be its own neighbour
    fps_start: str = "centroid"  # see graph_ops.FPS_STARTS; centroid = order independent
    exact_graph: bool = False  # exact kNN/FPS (slower); default: fast path, near-ties may differ
    force_feature: str = "raw"  # with use_force: node force input, see FORCE_FEATURES
    pos_scale: float = 1.0  # node positions (cm) are multiplied by this before the network
    message_layers: int = 2  # Linear layers of the message MLP phi (paper: 2)
    head_layers: int = 2  # Linear layers of the readout MLP (paper: 2)
    head_hidden: int = 0  # width of its hidden layers; 0 = width of all pooled features (C, or L*C with pool all/jk)
    residual: bool = False  # h^l = conv(h^{l-1}) + h^{l-1} where the widths match
    pool: str = "last"  # global max pool of the last layer (the paper) or of every layer: see POOLS
    joint_inputs: int = 0  # TacGNN and MLP: hand joint angles given beside the skin (0 = skin only, the paper)
    reading_feature: str = "raw"  # MLP, CNN and GCN: force input, see READING_FEATURES
    # MLP
    mlp_hidden: tuple[int, ...] = (64, 64)
    # CNN
    image_size: int = 36
    # GCN
    gcn_k: int = 6
    gcn_channels: tuple[int, ...] = (32, 32, 32)
    gcn_node_positions: str = "current"  # see GCN_NODE_POSITIONS

    def __post_init__(self) -> None:
        for f in ("k", "downsample_layers", "mlp_hidden", "gcn_channels"):
            v = getattr(self, f)
            if isinstance(v, (list, tuple)):
                object.__setattr__(self, f, tuple(v))
            else:
                raise ValueError(f"{f} must be a sequence of ints, got {v!r}")

        def positive_int(field: str, v) -> None:
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{field} must be a positive int, got {v!r}")

        if self.name not in MODEL_NAMES:
            raise ValueError(f"name must be one of {MODEL_NAMES}, got {self.name!r}")
        for f in ("out_dim", "num_taxels", "channels", "image_size", "gcn_k", "message_layers", "head_layers"):
            positive_int(f, getattr(self, f))
        if isinstance(self.head_hidden, bool) or not isinstance(self.head_hidden, int) or self.head_hidden < 0:
            raise ValueError(f"head_hidden must be an int >= 0, got {self.head_hidden!r}")
        if self.message_layers < 2:
            raise ValueError(f"message_layers must be >= 2, got {self.message_layers!r}")
        for f in ("k", "mlp_hidden", "gcn_channels"):
            if len(getattr(self, f)) == 0:
                raise ValueError(f"{f} must not be empty")
            for v in getattr(self, f):
                positive_int(f, v)
        if not isinstance(self.sample_ratio, (int, float)) or not 0.0 < self.sample_ratio <= 1.0:
            raise ValueError(f"sample_ratio must be in (0, 1], got {self.sample_ratio!r}")
        layers = range(len(self.k))
        if any(isinstance(i, bool) or i not in layers for i in self.downsample_layers):
            raise ValueError(
                f"downsample_layers must be layer indices in {list(layers)}, got {self.downsample_layers}"
            )
        if len(set(self.downsample_layers)) != len(self.downsample_layers):
            raise ValueError(f"downsample_layers has duplicates: {self.downsample_layers}")
        if self.force_feature not in FORCE_FEATURES:
            raise ValueError(f"force_feature must be one of {FORCE_FEATURES}, got {self.force_feature!r}")
        if self.reading_feature not in READING_FEATURES:
            raise ValueError(f"reading_feature must be one of {READING_FEATURES}, got {self.reading_feature!r}")
        if self.reading_feature != "raw" and self.name == "tacgnn":
            raise ValueError("reading_feature is the mlp, cnn and gcn input; TacGNN's force input is force_feature")
        if self.gcn_node_positions not in GCN_NODE_POSITIONS:
            raise ValueError(f"gcn_node_positions must be one of {GCN_NODE_POSITIONS}, got {self.gcn_node_positions!r}")
        if self.pool not in POOLS:
            raise ValueError(f"pool must be one of {POOLS}, got {self.pool!r}")
        if isinstance(self.pos_scale, bool) or not isinstance(self.pos_scale, (int, float)) or not self.pos_scale > 0:
            raise ValueError(f"pos_scale must be a positive number, got {self.pos_scale!r}")
        if isinstance(self.joint_inputs, bool) or not isinstance(self.joint_inputs, int) or self.joint_inputs < 0:
            raise ValueError(f"joint_inputs must be an int >= 0, got {self.joint_inputs!r}")
        if self.joint_inputs and self.name not in ("tacgnn", "mlp"):
            raise ValueError(f"joint_inputs is supported by tacgnn and mlp, not {self.name!r}")
        for f in ("use_force", "self_loop", "exact_graph", "residual"):
            if not isinstance(getattr(self, f), bool):
                raise ValueError(f"{f} must be a bool, got {getattr(self, f)!r}")
        if self.fps_start not in FPS_STARTS:
            raise ValueError(f"fps_start must be one of {FPS_STARTS}, got {self.fps_start!r}")
        if self.image_size**2 < self.num_taxels:
            raise ValueError(f"image_size={self.image_size} too small for {self.num_taxels} taxels")


# --------------------------------------------------------------------------
# shared base
# --------------------------------------------------------------------------
class PerceptionModel(nn.Module):
    """Base class: input checks shared by all models."""

    num_taxels: int
    joint_inputs: int = 0
    """Hand joint angles (rad) the model reads beside the skin; 0 = the skin alone."""

    def _check(self, readings: Tensor, positions: Tensor, joints: Tensor | None = None) -> None:
        T = self.num_taxels
        if readings.dim() != 2 or readings.shape[1] != T:
            raise ValueError(f"readings must be (B, {T}), got {tuple(readings.shape)}")
        if positions.shape != (readings.shape[0], T, 3):
            raise ValueError(f"positions must be (B, {T}, 3), got {tuple(positions.shape)}")
        # one reduction instead of a full mask: NaN anywhere makes the sum NaN
        if torch.isnan(readings.sum()) and torch.isnan(readings).any():
            raise ValueError("readings contain NaN")
        if self.joint_inputs:
            if joints is None:
                raise ValueError(f"this model reads {self.joint_inputs} joint angles: pass joints (B, "
                                 f"{self.joint_inputs})")
            if joints.shape != (readings.shape[0], self.joint_inputs):
                raise ValueError(f"joints must be (B, {self.joint_inputs}), got {tuple(joints.shape)}")
            if not torch.isfinite(joints.sum()):
                raise ValueError("joints contain NaN or inf")
        elif joints is not None:
            raise ValueError("this model was built without joint inputs (joint_inputs=0) but was given joints")


def reading_input(readings: Tensor, kind: str) -> Tensor:
    """The dense models' force input from the readings (N): see :data:`READING_FEATURES`."""
    if kind == "raw":
        return readings
    return torch.log1p(readings.clamp_min(0.0) / READING_LOG_SCALE)


def _mlp(sizes: list[int]) -> nn.Sequential:
    """Linear layers with ReLU in between (none after the last)."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def _reset_all(module: nn.Module) -> None:
    for m in module.modules():
        if m is not module and hasattr(m, "reset_parameters"):
            m.reset_parameters()


# --------------------------------------------------------------------------
# TacGNN
# --------------------------------------------------------------------------
class EdgeMaxConv(nn.Module):
    r"""One TacGNN message-passing layer on a flat node list with K neighbours per node.

    .. math::
        h_i' = \mathrm{ReLU}\Big(\max_{j \in \mathcal{N}(i)}
               \phi\big([h_i,\ h_j,\ x_j - x_i]\big)\Big),
        \qquad \phi = \mathrm{Lin}_2 \circ \mathrm{ReLU} \circ \mathrm{Lin}_1

    :math:`\phi` maps :math:`2C_{in} + 3 \to C`.

    Speed-ups, exact in real arithmetic:

    * split :math:`\mathrm{Lin}_1` by input block,
      :math:`W [h_i, h_j, x_j - x_i] + b = a_i + c_j` with
      :math:`a_i = W_i h_i - W_x x_i + b`, :math:`c_j = W_j h_j + W_x x_j`:
      per-node matmuls, edges only gather and add;
    * the bias of :math:`\mathrm{Lin}_2` and the final ReLU are applied after
      the max (:math:`\max_j (z_j + b) = \max_j z_j + b`; ReLU is monotone);
    * every node has exactly K neighbour slots (the caller fills missing ones
      with a repeated neighbour, which does not change a max), so the max is
      an ``amax`` over a ``(K, n, C)`` tensor: no scatter;
    * edges are processed in chunks of :attr:`chunk_size` nodes, in place
      where autograd allows. Same result; small temporaries stay in cache
      and are reused by malloc instead of being page-faulted in again on
      every call (measured ~1.5x faster than one ``(K, V, C)`` tensor).

    Shapes:
        - **input:** ``h (V, C_in)``, ``pos (V, 3)``, ``neighbours (K, V)``
          rows of the neighbours of every node
        - **output:** ``(V, C)``
    """

    chunk_size: int = 4096

    def __init__(self, in_channels: int, out_channels: int, layers: int = 2) -> None:
        super().__init__()
        if layers < 2:
            raise ValueError(f"layers must be >= 2, got {layers}")
        self.in_channels, self.out_channels = in_channels, out_channels
        self.lin1 = nn.Linear(2 * in_channels + 3, out_channels)
        # message_layers > 2: Linear + ReLU on every edge between lin1 and lin2
        self.hidden = nn.ModuleList(nn.Linear(out_channels, out_channels) for _ in range(layers - 2))
        self.lin2 = nn.Linear(out_channels, out_channels)

    def reset_parameters(self) -> None:
        self.lin1.reset_parameters()
        for lin in self.hidden:
            lin.reset_parameters()
        self.lin2.reset_parameters()

    def forward(self, h: Tensor, pos: Tensor, neighbours: Tensor) -> Tensor:
        K, V = neighbours.shape
        C = self.out_channels
        if V == 0:
            return h.new_zeros(0, C)
        W_i, W_j, W_x = self.lin1.weight.split([self.in_channels, self.in_channels, 3], dim=1)
        hx = torch.cat([h, pos], 1)
        a = torch.addmm(self.lin1.bias, hx, torch.cat([W_i, -W_x], 1).t())  # (V, C)
        c = hx @ torch.cat([W_j, W_x], 1).t()  # (V, C)
        chunks = []
        for lo in range(0, V, self.chunk_size):
            nbr = neighbours[:, lo : lo + self.chunk_size]
            n = nbr.shape[1]
            e = c.index_select(0, nbr.reshape(-1)).view(K, n, C)
            e = e.add_(a[lo : lo + n]).relu_().view(K * n, C)  # ReLU(Lin1) of the edges j -> i
            for lin in self.hidden:
                e = torch.addmm(lin.bias, e, lin.weight.t()).relu_()
            chunks.append((e @ self.lin2.weight.t()).view(K, n, C).amax(0))
        z = chunks[0] if len(chunks) == 1 else torch.cat(chunks)
        return (z + self.lin2.bias).relu_()


class TacGNN(PerceptionModel):
    r"""TacGNN: hierarchical dynamic-graph network over activated taxels.

    Nodes are the taxels with reading > 0, node input :math:`h^0_i = x_i`
    (position, times ``pos_scale``) or :math:`[x_i, g(f_i)]` with
    ``use_force``, :math:`g(f) = \log(f / 1\,\mathrm{N})` (``force_feature="log"``) or :math:`g(f) = f` (``"raw"``). The log turns the skin's
    multiplicative noise and the unknown contact force into additive offsets
    that a difference :math:`g(f_j) - g(f_i)` along an edge cancels, and for
    a bell-shaped pressure profile that difference is nearly linear in where
    the contact centre lies between the two taxels (on the Baoding data log
    and raw force measured the same; force vs none was worth ~4% RMSE).
    Layer :math:`l = 1..L`:

    1. rebuild the graph: :math:`\mathcal{N}(i)` = the :math:`k_l` nearest
       current nodes (dynamic graph, recomputed every forward);
    2. :class:`EdgeMaxConv`:
       :math:`h^l_i = \mathrm{ReLU}(\max_{j} \phi_l([h^{l-1}_i, h^{l-1}_j, x_j - x_i]))`;
    3. if ``l`` is in ``downsample_layers``: farthest point sampling keeps
       :math:`\lceil r \cdot n \rceil` nodes (positions and features).

    Readout (``pool``): ``"last"`` (the paper) :math:`y = \mathrm{MLP}(\max_i h^L_i)`,
    MLP ``[C, C, out]``; ``"jk"`` pools every layer before its
    downsampling, :math:`z = W[\max_i h^1_i, \dots, \max_i h^L_i]` with a
    bias-free :math:`W: LC \to C`, and :math:`y = \mathrm{MLP}(z)`, MLP
    ``[C, LC, out]``; ``"all"`` skips :math:`W` (MLP ``[LC, LC, out]``).
    Why it helps (measured ~10% lower RMSE on Baoding): the first layer's
    features are computed on all activated taxels with their local force
    pattern; with ``"last"`` they reach the head only through two more
    layers and two rounds of FPS that drop 3/4 of the nodes, and a
    C-wide head hidden layer. ``message_layers``/``head_layers``/``head_hidden`` set the
    depth of :math:`\phi` and the head, ``residual`` adds :math:`h^{l-1}`
    to :math:`h^l` where the widths match.

    Tactile blind area: a node without neighbours (a frame with one
    activated taxel) is its own neighbour, :math:`\phi([h_i, h_i, 0])`, so
    its position still reaches the head; an empty frame pools to 0 (features
    are ReLU outputs, :math:`\ge 0`) and gives the finite output
    :math:`\mathrm{MLP}(0)`.

    FPS start: the node farthest from the centroid (``fps_start``); later
    levels continue the same FPS ordering (a prefix, see
    :func:`graph_ops.dense_fps`), which equals running FPS again from that
    node. With this start the output does not depend on the taxel order (up
    to exact distance ties): kNN and max are set functions.

    Implementation: node features live in a flat ``(V, C)`` list of real
    nodes, positions also in a padded ``(B, N, 3)`` batch (N = most active
    taxels in the batch) for the graph ops. Real nodes are a prefix of each
    padded row, so slot ``(b, j)`` is flat row ``ptr[b] + j``. No scatter
    ops, no loop over frames; graph building runs without autograd (indices
    only), by default on the fast path of :mod:`graph_ops`
    (``exact_graph=False``), which may break near-ties (relative 1e-5)
    differently from an exact sort.

    Shapes:
        - **input:** ``readings (B, T)``, ``positions (B, T, 3)``
        - **output:** ``(B, out_dim)``
    """

    use_compiled_graphs: bool = True  # False: the torch graph ops (tests compare the two)

    def __init__(
        self,
        out_dim: int = 6,
        num_taxels: int = 653,
        channels: int = 32,
        k: tuple[int, ...] = (3, 3, 3),
        sample_ratio: float = 0.5,
        downsample_layers: tuple[int, ...] = (0, 1, 2),
        use_force: bool = False,
        self_loop: bool = False,
        fps_start: str = "centroid",
        exact_graph: bool = False,
        force_feature: str = "raw",
        pos_scale: float = 1.0,
        message_layers: int = 2,
        head_layers: int = 2,
        residual: bool = False,
        pool: str = "last",
        head_hidden: int = 0,
        joint_inputs: int = 0,
    ) -> None:
        super().__init__()
        if force_feature not in FORCE_FEATURES:
            raise ValueError(f"force_feature must be one of {FORCE_FEATURES}, got {force_feature!r}")
        if pool not in POOLS:
            raise ValueError(f"pool must be one of {POOLS}, got {pool!r}")
        self.num_taxels, self.out_dim = num_taxels, out_dim
        self.k, self.sample_ratio = tuple(k), sample_ratio
        self.downsample_layers = frozenset(downsample_layers)
        self.use_force, self.self_loop, self.fps_start = use_force, self_loop, fps_start
        self.exact_graph = exact_graph
        self.force_feature, self.pos_scale = force_feature, float(pos_scale)
        self.residual, self.pool = residual, pool
        self.joint_inputs = joint_inputs
        in_ch = 4 if use_force else 3
        self.convs = nn.ModuleList(
            EdgeMaxConv(in_ch if l == 0 else channels, channels, message_layers) for l in range(len(self.k))
        )
        L = len(self.k)
        # no bias: an empty frame (all pooled features 0) still reads head(0)
        self.jk = nn.Linear(L * channels, channels, bias=False) if pool == "jk" and L > 1 else None
        pooled = channels * (L if pool == "all" else 1)
        hidden = head_hidden or channels * (L if pool in ("all", "jk") else 1)
        self.head = _mlp([pooled + joint_inputs] + [hidden] * (head_layers - 1) + [out_dim])

    def reset_parameters(self) -> None:
        _reset_all(self)

    def forward(self, readings: Tensor, positions: Tensor, joints: Tensor | None = None) -> Tensor:
        self._check(readings, positions, joints)
        B, T = readings.shape
        active = (readings > 0).view(-1).nonzero().squeeze(1)  # frame by frame, taxel order
        x = positions.reshape(B * T, 3).index_select(0, active)
        if not torch.isfinite(x.sum()):  # one cheap reduction instead of a mask
            raise ValueError("positions of activated taxels contain NaN or inf")
        force = readings.reshape(-1).index_select(0, active) if self.use_force else None
        return self.forward_nodes(x, torch.div(active, T, rounding_mode="floor"), B, force, joints)

    def forward_pyg(self, data) -> Tensor:
        """Interop: a torch_geometric ``Data``/``Batch`` whose nodes are the activated taxels.

        Uses ``data.pos (V, 3)``, ``data.batch`` (``None`` = one graph) and,
        with ``use_force``, ``data.x`` of shape ``(V,)`` or ``(V, 1)`` as force.
        Returns ``(num_graphs, out_dim)``.
        """
        batch = getattr(data, "batch", None)
        B = int(data.num_graphs) if batch is not None else 1
        if batch is None:
            batch = torch.zeros(data.pos.shape[0], dtype=torch.long, device=data.pos.device)
        force = None
        if self.use_force:
            if data.x is None:
                raise ValueError("use_force=True needs data.x (force per node)")
            force = data.x.reshape(-1)
        return self.forward_nodes(data.pos, batch, B, force, getattr(data, "joints", None))

    def forward_nodes(self, x: Tensor, batch: Tensor, num_graphs: int, force: Tensor | None = None,
                      joints: Tensor | None = None) -> Tensor:
        """Core network on a flat node list (PyG style).

        Shapes:
            - **input:** ``x (V, 3)`` positions, ``batch (V,)`` sorted graph
              ids, ``force (V,)`` (only with ``use_force``)
            - **output:** ``(num_graphs, out_dim)``
        """
        B = num_graphs
        if x.shape[0] == 0:  # whole batch in the blind area: pooled feature is 0
            return self._readout(x.new_zeros(B, self.head[0].in_features - self.joint_inputs), joints)
        if self.pos_scale != 1.0:
            x = x * self.pos_scale
        h = x
        if force is not None:
            f = force.reshape(-1, 1).to(x.dtype)
            if self.force_feature == "log":
                f = torch.log(f.clamp_min(1e-6))
            h = torch.cat([x, f], 1)
        if self._compiled_graphs(x):
            return self._finish(self._layers_compiled(h, x, batch, B), joints)
        pos, mask = to_dense(x, batch, batch_size=B)
        counts, sampled = mask.sum(1), False
        pooled: list[Tensor] = []
        fast = not self.exact_graph and pos.dtype == torch.float32  # int32 keys need float32
        for l, conv in enumerate(self.convs):
            with torch.no_grad():  # graph structure: indices only
                ptr = torch.cumsum(counts, 0) - counts  # flat row of slot 0 of each graph
                dist = pairwise_sqdist(pos, mask, exact=not fast)
                if fast:
                    dist = sqdist_keys_(dist)
                fps = None
                if l in self.downsample_layers and not sampled:  # before kNN: it overwrites keys
                    fps = dense_fps(pos, mask, self.sample_ratio, start=self.fps_start, dist=dist)
                nbr = self._neighbours(pos, mask, ptr, self.k[l], dist)
                del dist  # free the (B, N, N) matrix before the conv allocates
            h_new = conv(h, x, nbr)
            h = h_new + h if self.residual and h.shape == h_new.shape else h_new
            if self.pool != "last" and l < len(self.convs) - 1:
                pooled.append(self._max_pool(h, mask, B))
            if l in self.downsample_layers:
                with torch.no_grad():
                    if fps is not None:
                        idx, mask = fps
                        pos = pos.gather(1, idx.unsqueeze(-1).expand(-1, -1, 3))
                        sampled = True
                    else:  # FPS of an FPS-ordered set from its first node = a prefix
                        m = fps_counts(counts, self.sample_ratio)
                        idx = torch.arange(int(m.max()), device=x.device).expand(B, -1)
                        pos, mask = pos[:, : idx.shape[1]], idx < m.unsqueeze(1)
                    keep = (idx + ptr.unsqueeze(1))[mask]  # flat rows of the kept nodes
                    counts = mask.sum(1)
                h, x = h.index_select(0, keep), x.index_select(0, keep)
        pooled.append(self._max_pool(h, mask, B))
        return self._finish(pooled, joints)

    def _compiled_graphs(self, x: Tensor) -> bool:
        """Build the graphs with the numba kernels (:mod:`graph_numba`): same graphs as the
        exact torch path up to ties, 1.3x faster forwards. Not for ``exact_graph`` (the
        reference), ``fps_start="random"`` or tensors off the CPU."""
        return (self.use_compiled_graphs and not self.exact_graph and self.fps_start != "random"
                and x.device.type == "cpu" and x.dtype == torch.float32 and graph_numba.available())

    def _layers_compiled(self, h: Tensor, x: Tensor, batch: Tensor, B: int) -> list[Tensor]:
        """The layers of :meth:`forward_nodes` on flat node lists, graphs from :mod:`graph_numba`."""
        counts, sampled = torch.bincount(batch, minlength=B), False
        pooled: list[Tensor] = []
        for l, conv in enumerate(self.convs):
            keep = None
            with torch.no_grad():
                nbr = graph_numba.knn_table(x, counts, self.k[l], self.self_loop)
                if l in self.downsample_layers:
                    kept = fps_counts(counts, self.sample_ratio)
                    if not sampled:
                        keep = graph_numba.fps_rows(x, counts, kept, self.fps_start == "centroid")
                        sampled = True
                    else:  # FPS of an FPS-ordered set from its first node = a prefix:
                        # kept row r of graph g is input row r + (first input row - first kept row)
                        shift = (torch.cumsum(counts, 0) - counts) - (torch.cumsum(kept, 0) - kept)
                        keep = torch.arange(int(kept.sum())) + torch.repeat_interleave(shift, kept)
            h_new = conv(h, x, nbr)
            h = h_new + h if self.residual and h.shape == h_new.shape else h_new
            if self.pool != "last" and l < len(self.convs) - 1:
                pooled.append(self._segment_max(h, counts))
            if keep is not None:
                h, x, counts = h.index_select(0, keep), x.index_select(0, keep), kept
        pooled.append(self._segment_max(h, counts))
        return pooled

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
        return self.head(z if joints is None else torch.cat([z, joints.to(z.dtype)], 1))

    @staticmethod
    def _segment_max(h: Tensor, counts: Tensor) -> Tensor:
        """Global max pool of consecutive groups of ``counts`` rows (0 for an empty group)."""
        return torch.segment_reduce(h, "max", lengths=counts, unsafe=True, initial=0.0)

    @staticmethod
    def _max_pool(h: Tensor, mask: Tensor, B: int) -> Tensor:
        """Global max pool of the flat node features (graph by graph, in order).

        ``h >= 0`` (ReLU outputs), so starting the max at 0 changes nothing and
        gives 0 for an empty graph. ``segment_reduce`` on the flat rows is ~3x
        faster (forward + backward) than scattering into a padded batch.
        """
        return torch.segment_reduce(h, "max", lengths=mask.sum(1), unsafe=True, initial=0.0)

    def _neighbours(self, pos: Tensor, mask: Tensor, ptr: Tensor, k: int, dist: Tensor) -> Tensor:
        """kNN as a ``(K, V)`` table of flat node rows.

        Missing slots (graphs with at most k nodes) repeat the nearest
        neighbour, which leaves the max unchanged; a node with no neighbour
        at all gets itself.
        """
        nbr, valid = dense_knn(pos, mask, k, self.self_loop, dist=dist)
        B, N, K = nbr.shape
        real = mask.reshape(-1).nonzero().squeeze(1)  # slots of the V real nodes
        if K == 0:  # every graph has a single node
            return torch.arange(real.shape[0], device=pos.device).unsqueeze(0)
        own = torch.arange(N, device=pos.device).view(1, N, 1)
        fallback = torch.where(valid[..., :1], nbr[..., :1], own)
        nbr = torch.where(valid, nbr, fallback) + ptr.view(B, 1, 1)
        return nbr.view(B * N, K).index_select(0, real).t().contiguous()


# --------------------------------------------------------------------------
# baselines
# --------------------------------------------------------------------------
class TactileMLP(PerceptionModel):
    r"""MLP baseline on the readings: :math:`y = \mathrm{MLP}(g(f))`, sizes ``[T, 64, 64, out]``
    (:math:`g` = ``reading_feature``: the raw reading, the paper's, or :func:`reading_input`'s log1p).

    Shapes:
        - **input:** ``readings (B, T)``, ``positions (B, T, 3)`` (unused)
        - **output:** ``(B, out_dim)``
    """

    def __init__(self, out_dim: int = 6, num_taxels: int = 653, hidden: tuple[int, ...] = (64, 64),
                 joint_inputs: int = 0, reading_feature: str = "raw") -> None:
        super().__init__()
        self.num_taxels, self.out_dim, self.joint_inputs = num_taxels, out_dim, joint_inputs
        self.reading_feature = reading_feature
        self.mlp = _mlp([num_taxels + joint_inputs, *hidden, out_dim])

    def reset_parameters(self) -> None:
        _reset_all(self)

    def forward(self, readings: Tensor, positions: Tensor, joints: Tensor | None = None) -> Tensor:
        self._check(readings, positions, joints)
        f = reading_input(readings, self.reading_feature)
        return self.mlp(f if joints is None else torch.cat([f, joints.to(f.dtype)], 1))


class TactileCNN(PerceptionModel):
    r"""CNN baseline on the readings packed into an ``S x S`` image (S = 36).

    Taxel ``t`` goes to pixel ``layout[t] = (row, col)``; the default layout
    is row-major (pixel ``t``), the remaining pixels are 0. Network:

    ``conv3x3(1->32) maxpool2 ReLU -> conv3x3(32->16) maxpool2 ReLU -> flatten``
    ``-> Linear(->128) ReLU -> Linear(->out)``

    (valid convolutions: 36 -> 34 -> 17 -> 15 -> 7, i.e. 16 x 7 x 7 = 784
    features, matching the paper's 784-128-6 head).

    Shapes:
        - **input:** ``readings (B, T)``, ``positions (B, T, 3)`` (unused)
        - **output:** ``(B, out_dim)``
    """

    def __init__(
        self,
        out_dim: int = 6,
        num_taxels: int = 653,
        image_size: int = 36,
        layout: Tensor | None = None,
        reading_feature: str = "raw",
    ) -> None:
        super().__init__()
        self.num_taxels, self.out_dim, self.image_size = num_taxels, out_dim, image_size
        self.reading_feature = reading_feature  # pixel values: see READING_FEATURES
        S = image_size
        if layout is None:
            pixel = torch.arange(num_taxels)
        else:
            layout = torch.as_tensor(layout, dtype=torch.long)
            if layout.shape != (num_taxels, 2) or layout.min() < 0 or layout.max() >= S:
                raise ValueError(f"layout must be ({num_taxels}, 2) with (row, col) in [0, {S})")
            pixel = layout[:, 0] * S + layout[:, 1]
            if pixel.unique().numel() != num_taxels:
                raise ValueError("layout maps two taxels to the same pixel")
        self.register_buffer("pixel", pixel, persistent=False)
        # max-pool before ReLU: the same function (ReLU is monotone) on a quarter of the
        # pixels; channels-last weights and images: with both, inference 2.6x and a training
        # step 1.3x faster on CPU (bench_perception.py)
        self.features = nn.Sequential(
            nn.Conv2d(1, 32, 3), nn.MaxPool2d(2), nn.ReLU(),
            nn.Conv2d(32, 16, 3), nn.MaxPool2d(2), nn.ReLU(),
            nn.Flatten(),
        ).to(memory_format=torch.channels_last)
        side = ((S - 2) // 2 - 2) // 2
        self.head = _mlp([16 * side * side, 128, out_dim])

    def reset_parameters(self) -> None:
        _reset_all(self)

    def forward(self, readings: Tensor, positions: Tensor, joints: Tensor | None = None) -> Tensor:
        self._check(readings, positions, joints)
        B, S = readings.shape[0], self.image_size
        img = readings.new_zeros(B, S * S)
        img[:, self.pixel] = reading_input(readings, self.reading_feature)
        return self.head(self.features(img.view(B, 1, S, S).contiguous(memory_format=torch.channels_last)))


class _SymmetricSparseMM(torch.autograd.Function):
    """``adj @ x`` for a symmetric sparse ``adj``, whose gradient is ``adj @ grad``.

    ``torch.sparse.mm``'s own backward transposes the CSR matrix, which sorts its
    B x 5,000 entries on every training step (most of a GCN training step at batch
    32). A symmetric matrix is its own transpose, so the sort is not needed.
    """

    @staticmethod
    def forward(ctx, adj: Tensor, x: Tensor) -> Tensor:
        ctx.adj = adj
        return torch.sparse.mm(adj, x)

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[None, Tensor]:
        return None, torch.sparse.mm(ctx.adj, grad)


def _symmetric_gcn_conv(in_channels: int, out_channels: int) -> nn.Module:
    """``GCNConv(normalize=False)`` that propagates with :class:`_SymmetricSparseMM`.

    Same parameters and outputs as GCNConv (``message_and_aggregate`` is PyG's hook
    for sparse propagation); only valid for a symmetric adjacency.
    """
    from torch_geometric.nn import GCNConv

    class SymmetricGCNConv(GCNConv):
        def message_and_aggregate(self, adj_t: Tensor, x: Tensor) -> Tensor:
            return _SymmetricSparseMM.apply(adj_t, x)

    return SymmetricGCNConv(in_channels, out_channels, normalize=False)


class TactileGCN(PerceptionModel):
    r"""GCN baseline on a fixed graph of all taxels.

    The graph is built once from the rest positions: symmetric kNN (k = 6),
    :math:`\hat A = \tilde D^{-1/2}(A + I)\tilde D^{-1/2}`. Node input
    :math:`[f_i, x_i, y_i, z_i]` (force and *current* position; with
    ``node_positions="rest"`` the rest position, so the nodes do not see the hand's pose). Layers
    (``torch_geometric.nn.GCNConv``) :math:`H' = \mathrm{ReLU}(\hat A H W + b)`
    with widths ``[32, 32, 32]``, then global max pool and MLP ``[32, out]``.

    :math:`\hat A` is precomputed (``normalize=False``) and expanded to a
    block-diagonal sparse matrix per batch size, so GCNConv runs one sparse
    matmul per layer instead of re-normalising 653 * B nodes every call; as
    :math:`\hat A` is symmetric, the backward pass reuses it instead of
    transposing it (training step 68.7 -> 26.9 ms at batch 32, bench_perception.py).

    Shapes:
        - **input:** ``readings (B, T)``, ``positions (B, T, 3)``
        - **output:** ``(B, out_dim)``
    """

    def __init__(
        self,
        rest_positions: Tensor,
        out_dim: int = 6,
        k: int = 6,
        channels: tuple[int, ...] = (32, 32, 32),
        reading_feature: str = "raw",
        node_positions: str = "current",
    ) -> None:
        super().__init__()
        self.reading_feature = reading_feature  # the node's force input: see READING_FEATURES
        self.node_positions = node_positions  # see GCN_NODE_POSITIONS
        from torch_geometric.utils import add_self_loops, is_undirected, to_undirected

        rest = torch.as_tensor(rest_positions, dtype=torch.float32)
        if rest.dim() != 2 or rest.shape[1] != 3 or torch.isnan(rest).any():
            raise ValueError(f"rest_positions must be a finite (T, 3) tensor, got {tuple(rest.shape)}")
        T = self.num_taxels = rest.shape[0]
        self.out_dim = out_dim
        ei = to_undirected(knn_graph(rest, k=k), num_nodes=T)
        ei, _ = add_self_loops(ei, num_nodes=T)
        deg = torch.bincount(ei[1], minlength=T).float()
        w = deg[ei[0]].rsqrt() * deg[ei[1]].rsqrt()
        if not is_undirected(ei, w, num_nodes=T):  # the propagation relies on it
            raise AssertionError("the GCN adjacency must be symmetric")
        self.register_buffer("edge_index", ei, persistent=False)
        self.register_buffer("rest", rest, persistent=False)
        self.register_buffer("edge_weight", w, persistent=False)
        sizes = [4, *channels]
        self.convs = nn.ModuleList(
            _symmetric_gcn_conv(sizes[i], sizes[i + 1]) for i in range(len(channels))
        )
        self.head = _mlp([channels[-1], channels[-1], out_dim])
        # batch size -> adjacency; a few sizes alternate in use (rollout, training, evaluation)
        self._adj_cache: dict[tuple, Tensor] = {}

    def reset_parameters(self) -> None:
        _reset_all(self)

    def _batched_adjacency(self, B: int) -> Tensor:
        """Block-diagonal sparse :math:`\\hat A` for B frames (cached for the last 3 batch sizes)."""
        key = (B, self.edge_index.device)
        if key not in self._adj_cache:
            T, E = self.num_taxels, self.edge_index.shape[1]
            off = (torch.arange(B, device=self.edge_index.device) * T).view(1, B, 1)
            ei = (self.edge_index.view(2, 1, E) + off).reshape(2, B * E)
            # GCNConv takes the transposed adjacency: row = target, col = source
            adj = torch.sparse_coo_tensor(
                ei.flip(0), self.edge_weight.repeat(B), (B * T, B * T), check_invariants=False
            ).coalesce()
            with warnings.catch_warnings():  # "sparse CSR support is in beta": fine here
                warnings.simplefilter("ignore", UserWarning)
                if len(self._adj_cache) == 3:
                    self._adj_cache.pop(next(iter(self._adj_cache)))  # the oldest
                self._adj_cache[key] = adj.to_sparse_csr()
        return self._adj_cache[key]

    def forward(self, readings: Tensor, positions: Tensor, joints: Tensor | None = None) -> Tensor:
        self._check(readings, positions, joints)
        B, T = readings.shape
        f = reading_input(readings, self.reading_feature)
        if self.node_positions == "rest":
            positions = self.rest.to(positions.dtype).expand(B, T, 3)
        x = torch.cat([f.unsqueeze(-1), positions], -1).reshape(B * T, 4)
        adj = self._batched_adjacency(B)
        for conv in self.convs:
            x = torch.relu(conv(x, adj))
        return self.head(x.view(B, T, -1).amax(1))


# --------------------------------------------------------------------------
# factory
# --------------------------------------------------------------------------
def build_model(
    name_or_cfg: PerceptionModelConfig | str,
    cfg: PerceptionModelConfig | None = None,
    *,
    rest_positions: Tensor | None = None,
    cnn_layout: Tensor | None = None,
) -> PerceptionModel:
    """Build a perception model.

    ``build_model(cfg)`` uses ``cfg.name``; ``build_model("gcn", cfg)`` takes
    the name from the first argument and everything else from ``cfg``;
    ``build_model("mlp")`` uses defaults. The GCN needs the taxel
    ``rest_positions (T, 3)``; the CNN accepts an optional ``cnn_layout``
    ``(T, 2)`` of (row, col) pixels.
    """
    if isinstance(name_or_cfg, str):
        c = dataclasses.replace(cfg if cfg is not None else PerceptionModelConfig(), name=name_or_cfg)
    else:
        c = name_or_cfg
    if c.name == "tacgnn":
        return TacGNN(c.out_dim, c.num_taxels, c.channels, c.k, c.sample_ratio, c.downsample_layers,
                      c.use_force, c.self_loop, c.fps_start, c.exact_graph, c.force_feature, c.pos_scale,
                      c.message_layers, c.head_layers, c.residual, c.pool, c.head_hidden, c.joint_inputs)
    if c.name == "mlp":
        return TactileMLP(c.out_dim, c.num_taxels, c.mlp_hidden, c.joint_inputs, c.reading_feature)
    if c.name == "cnn":
        return TactileCNN(c.out_dim, c.num_taxels, c.image_size, cnn_layout, c.reading_feature)
    if c.name == "gcn":
        if rest_positions is None:
            raise ValueError("rest_positions (T, 3) is required for the gcn model")
        if tuple(rest_positions.shape) != (c.num_taxels, 3):
            raise ValueError(f"rest_positions must be ({c.num_taxels}, 3), got {tuple(rest_positions.shape)}")
        return TactileGCN(rest_positions, c.out_dim, c.gcn_k, c.gcn_channels, c.reading_feature, c.gcn_node_positions)
    raise ValueError(f"name must be one of {MODEL_NAMES}, got {c.name!r}")  # unreachable after validation


# --------------------------------------------------------------------------
# CPU allocator knob (opt-in)
# --------------------------------------------------------------------------
def keep_freed_memory(mmap_threshold: int = 32 << 20, trim_threshold: int = 256 << 20) -> bool:
    """Opt-in, glibc only: let ``malloc`` keep freed memory for reuse.

    Why: a forward pass allocates and frees MBs of temporaries. With glibc's
    default settings, freed heap can be returned to the OS and page-faulted
    back in on the next call (this cost TacGNN ~40% of its CPU time before
    its edge work was chunked; now a few %). Same as setting the environment
    variables ``MALLOC_MMAP_THRESHOLD_`` and ``MALLOC_TRIM_THRESHOLD_``; the
    process then keeps up to ``trim_threshold`` bytes of free heap.

    Process wide, so call it once from an entry point (training script,
    benchmark), never on import. Returns False where it does not apply.
    """
    import ctypes

    try:
        libc = ctypes.CDLL("libc.so.6")
        M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # from <malloc.h>
        return bool(libc.mallopt(M_MMAP_THRESHOLD, mmap_threshold)) and bool(
            libc.mallopt(M_TRIM_THRESHOLD, trim_threshold)
        )
    except (OSError, AttributeError):
        return False
