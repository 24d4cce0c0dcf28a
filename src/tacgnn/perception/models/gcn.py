"""GCN baseline: graph convolutions over a fixed kNN graph of all taxels."""

from __future__ import annotations

import warnings

import torch
from torch import Tensor, nn

from tacgnn.perception.graph_ops import knn_graph
from tacgnn.perception.models.base import PerceptionModel, mlp, reading_input


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
    ``node_positions="rest"`` the rest position, so the nodes do not see the hand's pose).
    Layers (``torch_geometric.nn.GCNConv``) :math:`H' = \mathrm{ReLU}(\hat A H W + b)`
    with widths ``[32, 32, 32]``, then global max pool and MLP ``[32, out]``.

    :math:`\hat A` is precomputed (``normalize=False``) and expanded to a
    block-diagonal sparse matrix per batch size, so GCNConv runs one sparse
    matmul per layer instead of re-normalising 653 * B nodes every call; as
    :math:`\hat A` is symmetric, the backward pass reuses it instead of
    transposing it (training step 68.7 -> 26.9 ms at batch 32, bench/bench_perception.py).

    Args:
        rest_positions: ``(T, 3)`` taxel positions at rest (cm), e.g. from
            :func:`tacgnn.perception.rest_positions.rest_positions_cm`.
        out_dim: outputs. k: neighbours of the fixed graph (default 6).
        channels: layer widths. reading_feature: ``"raw"`` or ``"log1p"``.
        node_positions: ``"current"`` or ``"rest"``.

    Shapes:
        - **input:** ``readings (B, T)``, ``positions (B, T, 3)``
        - **output:** ``(B, out_dim)``
    """

    edge_index: Tensor  # buffers, registered in __init__
    edge_weight: Tensor
    rest: Tensor

    def __init__(self, rest_positions: Tensor, out_dim: int = 6, k: int = 6,
                 channels: tuple[int, ...] = (32, 32, 32), reading_feature: str = "raw",
                 node_positions: str = "current") -> None:
        super().__init__()
        from torch_geometric.utils import add_self_loops, is_undirected, to_undirected

        self.reading_feature, self.node_positions = reading_feature, node_positions
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
        self.convs = nn.ModuleList(_symmetric_gcn_conv(sizes[i], sizes[i + 1]) for i in range(len(channels)))
        self.head = mlp([channels[-1], channels[-1], out_dim])
        # (batch size, device, dtype) -> adjacency; a few sizes alternate (rollout, training, evaluation)
        self._adj_cache: dict[tuple, Tensor] = {}

    def _batched_adjacency(self, B: int, dtype: torch.dtype) -> Tensor:
        """Block-diagonal sparse :math:`\\hat A` for B frames (cached for the last 3 batch sizes)."""
        key = (B, self.edge_index.device, dtype)
        if key not in self._adj_cache:
            T, E = self.num_taxels, self.edge_index.shape[1]
            off = (torch.arange(B, device=self.edge_index.device) * T).view(1, B, 1)
            ei = (self.edge_index.view(2, 1, E) + off).reshape(2, B * E)
            # GCNConv takes the transposed adjacency: row = target, col = source
            adj = torch.sparse_coo_tensor(
                ei.flip(0), self.edge_weight.to(dtype).repeat(B), (B * T, B * T), check_invariants=False
            ).coalesce()
            with warnings.catch_warnings():  # "sparse CSR support is in beta": fine here
                warnings.simplefilter("ignore", UserWarning)
                if len(self._adj_cache) == 3:
                    self._adj_cache.pop(next(iter(self._adj_cache)))  # the oldest
                self._adj_cache[key] = adj.to_sparse_csr()
        return self._adj_cache[key]

    def forward(self, readings: Tensor, positions: Tensor, joints: Tensor | None = None) -> Tensor:
        readings, positions, joints = self.prepare(readings, positions, joints)
        B, T = readings.shape
        f = reading_input(readings, self.reading_feature)
        if self.node_positions == "rest":
            positions = self.rest.to(positions.dtype).expand(B, T, 3)
        x = torch.cat([f.unsqueeze(-1), positions], -1).reshape(B * T, 4)
        adj = self._batched_adjacency(B, x.dtype)
        for conv in self.convs:
            x = torch.relu(conv(x, adj))
        return self.head(x.view(B, T, -1).amax(1))
