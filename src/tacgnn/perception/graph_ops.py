"""Batched k-nearest-neighbour graphs and farthest point sampling in pure torch.

Why this module exists: ``torch_geometric.nn.knn_graph`` and ``fps`` need
torch-cluster, which cannot be installed here. Our graphs are also tiny (a
tactile frame has tens of activated taxels), so the fastest CPU design is not
a flat node list with scatter ops but a *dense padded* batch:

    pos  (B, N, 3)   node positions, N = largest graph in the batch
    mask (B, N)      True for real nodes, False for padding

Every routine below works on that layout with batched tensor ops and no
Python loop over graphs (farthest point sampling loops over the *sample
count*, each step batched over all graphs). The PyG-style functions
:func:`knn_graph` and :func:`farthest_point_sampling` are thin wrappers that
pack a flat ``(pos, batch)`` node list, call the dense routine and unpack.

Conventions (as in PyG): ``batch`` is a sorted graph-id vector, edges are
``edge_index[0] = source j``, ``edge_index[1] = target i``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = [
    "FPS_STARTS",
    "FAR",
    "to_dense",
    "from_dense",
    "pairwise_sqdist",
    "dense_knn",
    "fps_counts",
    "dense_fps",
    "knn_graph",
    "farthest_point_sampling",
]

#: Allowed ways to pick the first point of farthest point sampling.
FPS_STARTS = ("first", "random", "centroid")


# --------------------------------------------------------------------------
# flat <-> dense packing
# --------------------------------------------------------------------------
def _num_graphs(batch: Tensor, batch_size: int | None) -> int:
    if batch_size is not None:
        return int(batch_size)
    return int(batch.max()) + 1 if batch.numel() > 0 else 0


def to_dense(
    x: Tensor,
    batch: Tensor | None = None,
    batch_size: int | None = None,
    max_nodes: int | None = None,
    fill_value: float = 0.0,
) -> tuple[Tensor, Tensor]:
    """Pack a flat node tensor into a padded batch.

    Node ``n`` of graph ``g`` (its ``n``-th occurrence in ``batch``) goes to
    ``dense[g, n]``, so the real nodes of every graph form a prefix of its row.

    Args:
        x: node values ``(V, *F)``.
        batch: sorted graph ids ``(V,)``; ``None`` means one graph.
        batch_size: number of graphs B (lets trailing graphs be empty).
        max_nodes: padded size N (default: the largest graph).
        fill_value: value written into padding.

    Shapes:
        - **output:** ``dense (B, N, *F)``, ``mask (B, N)`` (bool)
    """
    if batch is None:
        batch = torch.zeros(x.shape[0], dtype=torch.long, device=x.device)
        batch_size = 1 if batch_size is None else batch_size
    if batch.numel() > 1 and bool((batch[1:] < batch[:-1]).any()):
        raise ValueError("batch must be sorted (nodes grouped by graph)")
    B = _num_graphs(batch, batch_size)
    counts = torch.bincount(batch, minlength=B)
    if counts.numel() > B:
        raise ValueError(f"batch holds graph ids >= batch_size={B}")
    N = int(counts.max()) if B > 0 and batch.numel() > 0 else 0
    if max_nodes is not None:
        if max_nodes < N:
            raise ValueError(f"max_nodes={max_nodes} < largest graph ({N} nodes)")
        N = max_nodes
    ptr = torch.cumsum(counts, 0) - counts  # first flat index of each graph
    slot = torch.arange(batch.numel(), device=x.device) - ptr[batch]
    dense = x.new_full((B, N) + tuple(x.shape[1:]), fill_value)
    dense[batch, slot] = x
    mask = torch.zeros(B, N, dtype=torch.bool, device=x.device)
    mask[batch, slot] = True
    return dense, mask


def from_dense(dense: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
    """Inverse of :func:`to_dense`: return the flat ``(x, batch)`` of the real nodes.

    Shapes:
        - **input:** ``dense (B, N, *F)``, ``mask (B, N)``
        - **output:** ``x (V, *F)``, ``batch (V,)`` with ``V = mask.sum()``
    """
    B, N = mask.shape
    graph_id = torch.arange(B, device=mask.device).unsqueeze(1).expand(B, N)
    return dense[mask], graph_id[mask]


def _flat_offsets(mask: Tensor) -> Tensor:
    """Flat index of slot 0 of every graph, for prefix masks from :func:`to_dense`."""
    counts = mask.sum(1)
    return torch.cumsum(counts, 0) - counts


# --------------------------------------------------------------------------
# distances and kNN
# --------------------------------------------------------------------------
#: Squared distance written for padding pairs. Finite (unlike inf) so that the
#: bit tricks of the fast kNN and the FPS ``minimum`` stay well defined.
FAR = 1e30
_FAR_KEY = int(torch.tensor([FAR / 2], dtype=torch.float32).view(torch.int32)[0])  # int32 bits of FAR / 2


def pairwise_sqdist(pos: Tensor, mask: Tensor | None = None, exact: bool = True) -> Tensor:
    r"""Squared distances :math:`D_{bij} = \lVert p_{bi} - p_{bj} \rVert^2` within each graph.

    ``exact=True`` sums squared coordinate differences: ``D`` is exactly
    symmetric with an exactly zero diagonal (the reference behaviour).
    ``exact=False`` uses one batched matmul of the expansion
    :math:`\lVert a \rVert^2 + \lVert b \rVert^2 - 2 a \cdot b` (about 5x faster); to limit
    cancellation, coordinates are first shifted by the graph's node 0, so the
    error is ~1e-7 of the squared graph extent, not of the squared distance
    to the world origin.

    With ``mask``, any pair involving a padding node gets :data:`FAR`.

    Shapes:
        - **input:** ``pos (B, N, 3)``, ``mask (B, N)``
        - **output:** ``(B, N, N)``
    """
    if exact or pos.shape[1] == 0:
        D = None
        for c in pos.unbind(-1):  # 3 coordinates: (dx^2 + dy^2) + dz^2
            d = c.unsqueeze(2) - c.unsqueeze(1)
            d = d * d
            D = d if D is None else D.add_(d)
        if D is None:
            D = pos.new_zeros(pos.shape[0], pos.shape[1], pos.shape[1])
        if mask is not None:
            D.masked_fill_(~(mask.unsqueeze(2) & mask.unsqueeze(1)), FAR)
        return D
    p = pos - pos[:, :1]
    sq = (p * p).sum(-1, keepdim=True)
    if mask is not None:
        sq = sq.masked_fill(~mask.unsqueeze(-1), FAR)  # padding: D = FAR + O(1) = FAR
    one = torch.ones_like(sq)
    # [-2a, |a|^2, 1] . [b, 1, |b|^2] = |a|^2 + |b|^2 - 2 a.b
    return torch.bmm(torch.cat([-2 * p, sq, one], -1), torch.cat([p, one, sq], -1).transpose(1, 2))


def _smallest_k_by_keys(D: Tensor, K: int, loop: bool) -> tuple[Tensor, Tensor]:
    """k smallest entries of every row of a float32 ``D`` via packed int32 keys.

    ``torch.topk`` costs ~0.5 us per row on CPU, far more than a vectorised
    reduction. So the low ``b = ceil(log2 N)`` mantissa bits of each
    (non-negative) distance are replaced by the column index: the int32 bit
    pattern then orders like the float and a plain ``amin`` returns distance
    *and* column in one pass; k rounds of amin + masking give the k nearest.
    Truncation only reorders distances within a relative ``2**(b-23)`` of
    each other (near-ties). Returns (keys (B, N, K) sorted, low-bit mask).
    """
    N = D.shape[-1]
    b = max(1, (N - 1).bit_length())
    low = (1 << b) - 1
    keys = (D.view(torch.int32) & ~low) | torch.arange(N, dtype=torch.int32, device=D.device)
    top = torch.iinfo(torch.int32).max
    if not loop:
        keys.diagonal(dim1=1, dim2=2).fill_(top)
    picks = []
    for r in range(K):
        m = keys.amin(-1, keepdim=True)
        picks.append(m)
        if r + 1 < K:
            keys.masked_fill_(keys == m, top)
    return torch.cat(picks, -1), low


def dense_knn(
    pos: Tensor,
    mask: Tensor,
    k: int,
    loop: bool = False,
    sqdist: Tensor | None = None,
    exact: bool = True,
) -> tuple[Tensor, Tensor]:
    """k nearest neighbours of every node among the real nodes of its graph.

    A graph with ``n <= k`` nodes gives each node all ``n - 1`` others (``n``
    with ``loop=True``, which counts the node itself as a candidate at
    distance 0); the missing slots are flagged in ``valid``.

    Args:
        pos: positions ``(B, N, 3)``; mask: real nodes ``(B, N)``.
        k: neighbours per node; loop: allow ``j == i``.
        sqdist: precomputed ``pairwise_sqdist(pos, mask, ...)`` (shared with FPS).
        exact: ``True``: exact distances + ``torch.topk``. ``False``: fast
            path (matmul distances, packed-key selection, float32 only) that
            may order near-ties (relative 1e-5) differently.

    Shapes:
        - **output:** ``index (B, N, K)`` neighbour slots sorted by distance,
          ``valid (B, N, K)`` bool, with ``K = min(k, N - 1 + loop)``.
          Invalid slots hold an arbitrary slot in ``[0, N)``.
    """
    B, N = mask.shape
    K = max(0, min(k, N if loop else N - 1))
    D = pairwise_sqdist(pos, mask, exact) if sqdist is None else sqdist
    if exact or D.dtype != torch.float32:
        if not loop:
            D = D.clone()
            D.diagonal(dim1=1, dim2=2).fill_(math.inf)
        dist, index = D.topk(K, dim=-1, largest=False, sorted=True)
        valid = dist < FAR / 2
    else:
        keys, low = _smallest_k_by_keys(D.contiguous(), K, loop)
        valid = keys < _FAR_KEY
        index = (keys & low).long().clamp_(max=max(N - 1, 0))
    return index, valid & mask.unsqueeze(2)


# --------------------------------------------------------------------------
# farthest point sampling
# --------------------------------------------------------------------------
def fps_counts(n: Tensor, ratio: float) -> Tensor:
    """Samples kept per graph: ``ceil(ratio * n)`` in double precision, 0 for empty graphs.

    ``ratio`` is in (0, 1], so a non-empty graph keeps at least one node.
    """
    return torch.ceil(n.to(torch.float64) * ratio).to(torch.long)


def _fps_start(pos: Tensor, mask: Tensor, start: str, generator) -> Tensor:
    """Index of the first FPS point of each graph (0 for empty graphs)."""
    if start == "first":
        return mask.to(torch.uint8).argmax(1)  # first True
    if start == "random":
        r = torch.rand(mask.shape, generator=generator, device=mask.device)
        return r.masked_fill(~mask, -1.0).argmax(1)
    if start == "centroid":
        # Farthest node from the centroid: depends on the node *set*, not on
        # the order of the nodes, so FPS becomes permutation invariant.
        w = mask.unsqueeze(-1).to(pos.dtype)
        centre = (pos * w).sum(1, keepdim=True) / w.sum(1, keepdim=True).clamp_min(1)
        d = ((pos - centre) ** 2).sum(-1)
        return d.masked_fill(~mask, -math.inf).argmax(1)
    raise ValueError(f"start must be one of {FPS_STARTS}, got {start!r}")


def dense_fps(
    pos: Tensor,
    mask: Tensor,
    ratio: float,
    start: str = "first",
    sqdist: Tensor | None = None,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, Tensor]:
    r"""Farthest point sampling on a padded batch.

    Graph g keeps :math:`m_g = \lceil \text{ratio} \cdot n_g \rceil` nodes:
    after the start node :math:`s_0`, each step picks

    .. math:: s_t = \arg\max_{j \notin S} \min_{s \in S} \lVert p_j - p_s \rVert^2

    (ties go to the lowest slot). One Python iteration per sample, batched
    over graphs; each step only reads one row of the distance matrix.

    Args:
        pos, mask: padded batch ``(B, N, 3)``, ``(B, N)``.
        ratio: fraction of nodes to keep, in (0, 1].
        start: ``"first"`` (first real node), ``"random"``, or
            ``"centroid"`` (farthest from the centroid: order independent).
        sqdist: precomputed :func:`pairwise_sqdist` (padding entries may
            hold anything finite: padding is masked here).

    Shapes:
        - **output:** ``index (B, M)`` slots in sampling order and
          ``keep (B, M)`` bool marking the first :math:`m_g` entries, with
          ``M = max_g m_g``. Entries beyond :math:`m_g` are meaningless.
    """
    if not 0.0 < ratio <= 1.0:
        raise ValueError(f"ratio must be in (0, 1], got {ratio}")
    B, N = mask.shape
    m = fps_counts(mask.sum(1), ratio)
    M = int(m.max()) if B > 0 else 0
    if M == 0:
        empty = torch.zeros(B, 0, dtype=torch.long, device=mask.device)
        return empty, empty.bool()
    D = pairwise_sqdist(pos) if sqdist is None else sqdist
    D_rows = D.reshape(B * N, N)
    offset = torch.arange(B, device=mask.device) * N  # flat row of slot 0 of each graph
    # min distance to the chosen set; padding at -inf is never chosen and a
    # chosen node is set to -inf so that duplicate points cannot be re-picked.
    mind = torch.full((B, N), math.inf, dtype=D.dtype, device=D.device)
    mind.masked_fill_(~mask, -math.inf)
    mind_flat = mind.view(-1)
    last = _fps_start(pos, mask, start, generator)
    picks = [last]
    for _ in range(M - 1):
        flat = last + offset
        torch.minimum(mind, D_rows.index_select(0, flat), out=mind)
        mind_flat.index_fill_(0, flat, -math.inf)
        last = mind.argmax(1)
        picks.append(last)
    index = torch.stack(picks, 1)
    keep = torch.arange(M, device=mask.device) < m.unsqueeze(1)
    return index, keep


# --------------------------------------------------------------------------
# PyG-style wrappers on flat node lists
# --------------------------------------------------------------------------
def knn_graph(
    pos: Tensor,
    batch: Tensor | None = None,
    k: int = 3,
    loop: bool = False,
    batch_size: int | None = None,
) -> Tensor:
    """kNN graph of a flat batch of point clouds (PyG convention).

    Each node i receives edges ``j -> i`` from its k nearest nodes j of the
    same graph (all other nodes if the graph has fewer than k + 1).

    Shapes:
        - **input:** ``pos (V, 3)``, ``batch (V,)`` sorted
        - **output:** ``edge_index (2, E)``; edges grouped by target in node
          order, nearest source first.
    """
    dense, mask = to_dense(pos, batch, batch_size)
    index, valid = dense_knn(dense, mask, k, loop=loop)
    B, N, K = index.shape
    offset = _flat_offsets(mask).view(B, 1, 1)
    source = (index + offset)[valid]
    target = (torch.arange(N, device=pos.device).view(1, N, 1) + offset).expand(B, N, K)[valid]
    return torch.stack([source, target])


def farthest_point_sampling(
    pos: Tensor,
    batch: Tensor | None = None,
    ratio: float = 0.5,
    random_start: bool = False,
    start: str | None = None,
    batch_size: int | None = None,
    generator: torch.Generator | None = None,
) -> Tensor:
    """Farthest point sampling of a flat batch (like ``torch_geometric.nn.fps``).

    Keeps ``ceil(ratio * n_g)`` nodes of every graph, starting at its first
    node, or a random one if ``random_start``; ``start`` (see
    :data:`FPS_STARTS`) overrides both.

    Shapes:
        - **input:** ``pos (V, 3)``, ``batch (V,)`` sorted
        - **output:** ``index (M,)`` into ``pos``, grouped by graph, in
          sampling order within each graph.
    """
    if start is None:
        start = "random" if random_start else "first"
    dense, mask = to_dense(pos, batch, batch_size)
    index, keep = dense_fps(dense, mask, ratio, start=start, generator=generator)
    return (index + _flat_offsets(mask).unsqueeze(1))[keep]
