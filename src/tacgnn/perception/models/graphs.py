"""TacGNN's graphs, level by level: kNN neighbour tables and farthest point sampling.

One interface, :class:`GraphBuilder`, two implementations that build the same graphs:
:class:`CompiledGraphs` (numba kernels, the default on CPU) and :class:`TorchGraphs`
(batched torch ops on a padded batch; the reference with ``exact=True``, and the path
for other devices and dtypes). The model's layer loop only sees::

    level = graphs.level(k, sample)   # neighbours (K, V), counts (B,), keep (V',) or None

Nodes are a flat list grouped by graph. Before any graph is built, :func:`canonical_order`
sorts the nodes of every graph by position, so that wherever the graph operations break a
tie by node index (two neighbours at the same distance, which the regular taxel grid
makes common; two equally far FPS candidates; a sum's rounding), the index is a function
of the node set. The output then does not depend on the order the taxels are listed in.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from tacgnn.perception import graph_numba
from tacgnn.perception.graph_ops import dense_fps, dense_knn, fps_counts, pairwise_sqdist, sqdist_keys_, to_dense


class GraphLevel(NamedTuple):
    """The graph of one layer.

    ``neighbours (K, V)``: flat rows of every node's K neighbours, nearest first (slots a
    small graph cannot fill repeat its nearest neighbour; a lone node is its own).
    ``counts (B,)``: nodes per graph. ``keep``: flat rows of the nodes the next level
    keeps, in sampling order (None: no sampling after this layer).
    """

    neighbours: Tensor
    counts: Tensor
    keep: Tensor | None


def canonical_order(pos: Tensor, batch: Tensor, force: Tensor | None = None) -> Tensor:
    """Permutation that groups nodes by graph and sorts each graph by (x, y, z, force).

    Two nodes that compare equal on every key are the same node as far as the network
    can tell, so their order does not matter. On CPU in float32 with numba, one compiled
    pass (graphs in parallel); else stable torch sorts from the least significant key up.

    Shapes:
        - **input:** ``pos (V, 3)``, ``batch (V,)`` graph ids, ``force (V,)``
        - **output:** ``(V,)`` indices
    """
    keys = [pos[:, 0], pos[:, 1], pos[:, 2]] + ([] if force is None else [force.to(pos.dtype)])
    grouped = batch.numel() < 2 or bool((batch[1:] >= batch[:-1]).all())
    if grouped and compiled_graphs_apply(pos, exact=False, start="centroid"):
        counts = torch.bincount(batch, minlength=int(batch[-1]) + 1 if batch.numel() else 0)
        return graph_numba.lexicographic_order(torch.stack(keys), counts)
    order = torch.arange(pos.shape[0], device=pos.device)
    for key in [*reversed(keys), batch]:  # least significant first
        order = order.index_select(0, torch.sort(key.index_select(0, order), stable=True).indices)
    return order


def prefix_rows(counts: Tensor, kept: Tensor) -> Tensor:
    """Flat rows of the first ``kept[g]`` nodes of every graph g of ``counts[g]`` nodes."""
    shift = (torch.cumsum(counts, 0) - counts) - (torch.cumsum(kept, 0) - kept)
    return torch.arange(int(kept.sum()), device=counts.device) + torch.repeat_interleave(shift, kept)


class GraphBuilder:
    """Builds the graphs of successive layers on a flat node list that shrinks by sampling.

    Sampling: farthest point sampling keeps ``ceil(ratio * n)`` nodes of every graph, in
    sampling order. Later levels take a prefix of that order: FPS of an FPS-ordered set,
    started at its first node, returns it in the same order (each pick was the argmax
    over a superset), so one FPS run serves every level.

    Args:
        pos: ``(V, 3)`` node positions, grouped by graph (no gradient is taken).
        counts: ``(B,)`` nodes per graph.
        ratio: fraction of nodes sampling keeps. loop: a node may be its own neighbour.
        start: first FPS pick, one of ``graph_ops.FPS_STARTS``.
    """

    def __init__(self, pos: Tensor, counts: Tensor, ratio: float, loop: bool = False,
                 start: str = "centroid") -> None:
        self.pos, self.counts = pos.detach(), counts
        self.ratio, self.loop, self.start = ratio, loop, start
        self.sampled = False

    def level(self, k: int, sample: bool) -> GraphLevel:
        """The k-nearest-neighbour graph of the current nodes; with ``sample``, which nodes stay."""
        counts = self.counts
        first_sample = sample and not self.sampled
        neighbours, fps = self._build(k, first_sample)
        keep = None
        if sample:
            kept = fps_counts(counts, self.ratio)
            keep = prefix_rows(counts, kept) if fps is None else fps  # FPS rows come with the first sample only
            self.pos, self.counts, self.sampled = self.pos.index_select(0, keep), kept, True
        return GraphLevel(neighbours, counts, keep)

    def _build(self, k: int, fps: bool) -> tuple[Tensor, Tensor | None]:
        """``(K, V)`` neighbour table and, with ``fps``, the flat rows FPS keeps."""
        raise NotImplementedError


class CompiledGraphs(GraphBuilder):
    """Graphs from the numba kernels of :mod:`tacgnn.perception.graph_numba` (CPU, float32).

    Exact float32 distances; ties go to the lower row. Not for ``start="random"``.
    """

    def _build(self, k: int, fps: bool) -> tuple[Tensor, Tensor | None]:
        neighbours = graph_numba.knn_table(self.pos, self.counts, k, self.loop)
        rows = None
        if fps:
            kept = fps_counts(self.counts, self.ratio)
            rows = graph_numba.fps_rows(self.pos, self.counts, kept, self.start == "centroid")
        return neighbours, rows


class TorchGraphs(GraphBuilder):
    """Graphs from the batched torch ops of :mod:`tacgnn.perception.graph_ops`.

    ``exact=True``: distances from coordinate differences and ``topk`` (the reference);
    ``exact=False`` (float32 only): one batched matmul and int32 sort keys, which may
    order near-ties (relative 1e-5) differently.
    """

    def __init__(self, pos: Tensor, counts: Tensor, ratio: float, loop: bool = False,
                 start: str = "centroid", exact: bool = True) -> None:
        super().__init__(pos, counts, ratio, loop, start)
        self.exact = exact or pos.dtype != torch.float32  # the int32 keys need float32

    def _build(self, k: int, fps: bool) -> tuple[Tensor, Tensor | None]:
        B = self.counts.shape[0]
        batch = torch.repeat_interleave(torch.arange(B, device=self.pos.device), self.counts)
        pos, mask = to_dense(self.pos, batch, batch_size=B)
        ptr = torch.cumsum(self.counts, 0) - self.counts  # flat row of slot 0 of every graph
        dist = pairwise_sqdist(pos, mask, exact=self.exact)
        if not self.exact:
            dist = sqdist_keys_(dist)
        rows = None
        if fps:  # before kNN, which overwrites the keys
            idx, keep = dense_fps(pos, mask, self.ratio, start=self.start, dist=dist)
            rows = (idx + ptr.unsqueeze(1))[keep]
        return self._table(pos, mask, ptr, k, dist), rows

    def _table(self, pos: Tensor, mask: Tensor, ptr: Tensor, k: int, dist: Tensor) -> Tensor:
        """:func:`dense_knn` as a ``(K, V)`` table of flat rows, missing slots filled."""
        nbr, valid = dense_knn(pos, mask, k, self.loop, dist=dist)
        B, N, K = nbr.shape
        real = mask.reshape(-1).nonzero().squeeze(1)  # slots of the V real nodes
        if K == 0:  # every graph has a single node: its own neighbour
            return torch.arange(real.shape[0], device=pos.device).unsqueeze(0)
        own = torch.arange(N, device=pos.device).view(1, N, 1)
        fallback = torch.where(valid[..., :1], nbr[..., :1], own)
        nbr = torch.where(valid, nbr, fallback) + ptr.view(B, 1, 1)
        return nbr.view(B * N, K).index_select(0, real).t().contiguous()


def compiled_graphs_apply(pos: Tensor, exact: bool, start: str) -> bool:
    """Whether :class:`CompiledGraphs` can build these graphs (numba, CPU, float32)."""
    return (not exact and start != "random" and pos.device.type == "cpu" and pos.dtype == torch.float32
            and graph_numba.available())


__all__ = ["GraphLevel", "GraphBuilder", "CompiledGraphs", "TorchGraphs", "canonical_order", "prefix_rows",
           "compiled_graphs_apply"]
