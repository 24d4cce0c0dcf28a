"""Batched k-nearest-neighbour graphs and farthest point sampling in pure torch.

Why this module exists: ``torch_geometric.nn.knn_graph`` and ``fps`` need
torch-cluster, which cannot be installed here. Our graphs are also tiny (a
tactile frame has tens of activated taxels), so the fastest CPU design is not
a flat node list with scatter ops but a *dense padded* batch:

    pos  (B, N, 3)   node positions, N = largest graph in the batch
    mask (B, N)      True for real nodes, which form a prefix of each row

Every routine works on that layout with batched tensor ops and no Python
loop over graphs (farthest point sampling loops over the *sample count*,
each step batched over all graphs). Two speeds:

* exact (default): distances from coordinate differences, ``torch.topk``;
  this is the reference the tests compare with brute force.
* fast: distances from one batched matmul, turned into int32 sort keys
  (:func:`sqdist_keys_`) that both kNN and FPS read with plain ``amin`` /
  ``amax`` passes. Same results up to near-ties (relative ~1e-5).

The PyG-style :func:`knn_graph` and :func:`farthest_point_sampling` are thin
wrappers: pack a flat ``(pos, batch)`` node list, call the dense routine,
unpack. Conventions as in PyG: ``batch`` is a sorted graph-id vector and
``edge_index[0] = source j``, ``edge_index[1] = target i``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = [
    "FAR",
    "FPS_STARTS",
    "to_dense",
    "from_dense",
    "flat_offsets",
    "pairwise_sqdist",
    "sqdist_keys_",
    "dense_knn",
    "fps_counts",
    "dense_fps",
    "knn_graph",
    "farthest_point_sampling",
]

#: Squared distance given to pairs involving padding. Finite (unlike inf) so
#: that the bit tricks of :func:`sqdist_keys_` stay well defined.
FAR = 1e30
#: Allowed ways to pick the first point of farthest point sampling.
FPS_STARTS = ("first", "random", "centroid")

_INT_MAX = 2**31 - 1
_INT_MIN = -(2**31)
_FAR_KEY = int(torch.tensor([FAR / 2], dtype=torch.float32).view(torch.int32)[0])  # bits of FAR / 2


# --------------------------------------------------------------------------
# flat <-> dense packing
# --------------------------------------------------------------------------
def to_dense(
    x: Tensor,
    batch: Tensor | None = None,
    batch_size: int | None = None,
    max_nodes: int | None = None,
    fill_value: float = 0.0,
) -> tuple[Tensor, Tensor]:
    """Pack a flat node tensor into a padded batch.

    Node ``n`` of graph ``g`` (its ``n``-th occurrence in ``batch``) goes to
    ``dense[g, n]``, so the real nodes of every graph form a prefix of its
    row and slot ``(g, n)`` is flat row ``ptr[g] + n``.

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
    if batch_size is None:
        batch_size = int(batch.max()) + 1 if batch.numel() > 0 else 0
    B = int(batch_size)
    counts = torch.bincount(batch, minlength=B)
    if counts.numel() > B:
        raise ValueError(f"batch holds graph ids >= batch_size={B}")
    N = int(counts.max()) if batch.numel() > 0 else 0
    if max_nodes is not None:
        if max_nodes < N:
            raise ValueError(f"max_nodes={max_nodes} < largest graph ({N} nodes)")
        N = max_nodes
    slot = torch.arange(batch.numel(), device=x.device) - (torch.cumsum(counts, 0) - counts)[batch]
    dense = x.new_full((B * N,) + tuple(x.shape[1:]), fill_value)
    dense.index_copy_(0, batch * N + slot, x)
    mask = torch.arange(N, device=x.device) < counts.unsqueeze(1)
    return dense.view((B, N) + tuple(x.shape[1:])), mask


def from_dense(dense: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
    """Inverse of :func:`to_dense`: the flat ``(x, batch)`` of the real nodes.

    Shapes:
        - **input:** ``dense (B, N, *F)``, ``mask (B, N)``
        - **output:** ``x (V, *F)``, ``batch (V,)`` with ``V = mask.sum()``
    """
    B, N = mask.shape
    graph_id = torch.arange(B, device=mask.device).unsqueeze(1).expand(B, N)
    return dense[mask], graph_id[mask]


def flat_offsets(mask: Tensor) -> Tensor:
    """``ptr (B,)``: flat row of slot 0 of every graph, for prefix masks."""
    counts = mask.sum(1)
    return torch.cumsum(counts, 0) - counts


# --------------------------------------------------------------------------
# distances
# --------------------------------------------------------------------------
def pairwise_sqdist(pos: Tensor, mask: Tensor | None = None, exact: bool = True) -> Tensor:
    r"""Squared distances :math:`D_{bij} = \lVert p_{bi} - p_{bj} \rVert^2` within each graph.

    ``exact=True`` sums squared coordinate differences: ``D`` is exactly
    symmetric with an exactly zero diagonal (the reference behaviour).
    ``exact=False`` computes :math:`\lVert a \rVert^2 + \lVert b \rVert^2 - 2 a \cdot b`
    with one batched matmul (several times faster). Coordinates are first
    shifted by the graph's node 0, so the rounding error is ~1e-7 of the
    squared graph extent, not of the squared distance to the world origin.

    With ``mask``, every pair involving a padding node gets ~:data:`FAR`.

    Shapes:
        - **input:** ``pos (B, N, 3)``, ``mask (B, N)``
        - **output:** ``(B, N, N)``
    """
    B, N, _ = pos.shape
    if exact or N == 0:
        D = pos.new_zeros(B, N, N)
        for c in pos.unbind(-1):  # (dx^2 + dy^2) + dz^2
            d = c.unsqueeze(2) - c.unsqueeze(1)
            D.add_(d.mul_(d))
        if mask is not None:
            D.masked_fill_(~(mask.unsqueeze(2) & mask.unsqueeze(1)), FAR)
        return D
    p = pos - pos[:, :1]
    sq = (p * p).sum(-1, keepdim=True)
    if mask is not None:
        sq = sq.masked_fill(~mask.unsqueeze(-1), FAR)  # padding: D = FAR + O(1) = FAR
    one = torch.ones_like(sq)
    # [-2a, |a|^2, 1] . [b, 1, |b|^2] = |a|^2 + |b|^2 - 2 a.b; both operands
    # contiguous (a transposed view makes bmm 2x slower)
    left = torch.cat([-2 * p, sq, one], -1)
    right = torch.cat([p.transpose(1, 2), one.transpose(1, 2), sq.transpose(1, 2)], 1)
    return torch.bmm(left, right)


def _low_bits(n: int) -> int:
    """Mask of the low bits that hold a column index in ``[0, n)``."""
    return (1 << max(1, (n - 1).bit_length())) - 1


def sqdist_keys_(D: Tensor) -> Tensor:
    """Turn float32 squared distances ``(B, N, N)`` into int32 sort keys, in place.

    Why: on CPU ``torch.topk`` costs ~0.5 us per row and ``argmax`` on short
    rows is slow, while ``amin``/``amax`` are fast vectorised passes. For a
    non-negative float the int32 bit pattern orders like the value, so we
    clear the sign bit (rounding can give -1e-7) and the low
    ``b = ceil(log2 N)`` mantissa bits, and store the column index there:
    ``key = bits(|D|) & ~low | j``. One ``amin`` over a row then returns
    both the smallest distance and its column ``key & low``.

    Truncation only reorders distances within a relative ``2**(b - 23)``
    (~1e-5 for N <= 128). Padding keys stay above the bits of ``FAR / 2``.
    The diagonal is set to INT_MIN: in FPS, taking the minimum with the
    chosen node's row then marks that node as chosen for free.
    """
    if D.dtype != torch.float32 or not D.is_contiguous():
        raise ValueError("sqdist_keys_ needs a contiguous float32 tensor")
    N = D.shape[-1]
    keys = D.view(torch.int32)
    keys.bitwise_and_(_INT_MAX & ~_low_bits(N))
    keys.bitwise_or_(torch.arange(N, dtype=torch.int32, device=D.device))
    keys.diagonal(dim1=1, dim2=2).fill_(_INT_MIN)
    return keys


# --------------------------------------------------------------------------
# kNN
# --------------------------------------------------------------------------
def _smallest_k_keys_(keys: Tensor, K: int, loop: bool) -> Tensor:
    """The K smallest keys of every row, ascending: K rounds of ``amin``.

    Each round writes INT_MAX over the picked entries (a scatter of one
    value per row), so ``keys`` is overwritten.
    """
    N = keys.shape[-1]
    low = _low_bits(N)
    diag = keys.diagonal(dim1=1, dim2=2)
    if loop:  # self at distance 0: key = 0 bits | own column
        diag.copy_(torch.arange(N, dtype=torch.int32, device=keys.device))
    else:
        diag.fill_(_INT_MAX)
    picks = []
    for r in range(K):
        m = keys.amin(-1, keepdim=True)
        picks.append(m)
        if r + 1 < K:  # K <= N - 1 + loop, so an untouched entry remains: m < INT_MAX
            keys.scatter_(-1, (m & low).long(), torch.full_like(m, _INT_MAX))
    return torch.cat(picks, -1) if picks else keys[..., :0]


def dense_knn(
    pos: Tensor,
    mask: Tensor,
    k: int,
    loop: bool = False,
    dist: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """k nearest neighbours of every node among the real nodes of its graph.

    A graph with ``n <= k`` nodes gives each node all ``n - 1`` others (``n``
    with ``loop=True``, which counts the node itself as a candidate at
    distance 0); the missing slots are flagged in ``valid``.

    Args:
        pos: positions ``(B, N, 3)``; mask: real nodes ``(B, N)``.
        k: neighbours per node; loop: allow ``j == i``.
        dist: precomputed ``pairwise_sqdist(pos, mask, ...)`` (float:
            ``topk``) or int32 keys from :func:`sqdist_keys_` (fast path;
            the keys are used as scratch space and overwritten, so run
            :func:`dense_fps` on them first). Default: exact float distances.

    Shapes:
        - **output:** ``index (B, N, K)`` neighbour slots sorted by distance
          and ``valid (B, N, K)`` bool, with ``K = min(k, N - 1 + loop)``.
          Invalid slots hold an arbitrary slot in ``[0, N)``.
    """
    B, N = mask.shape
    K = max(0, min(k, N if loop else N - 1))
    D = pairwise_sqdist(pos, mask) if dist is None else dist
    if D.dtype == torch.int32:
        top = _smallest_k_keys_(D, K, loop)
        index, valid = (top & _low_bits(N)).long(), top < _FAR_KEY
    else:
        if not loop:
            D = D.clone()
            D.diagonal(dim1=1, dim2=2).fill_(math.inf)
        top, index = D.topk(K, dim=-1, largest=False, sorted=True)
        valid = top < FAR / 2
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
    """Slot of the first FPS point of each graph (0 for empty graphs)."""
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
        d = pos - centre
        d = (d * d).sum(-1)
        return d.masked_fill(~mask, -math.inf).max(1).indices
    raise ValueError(f"start must be one of {FPS_STARTS}, got {start!r}")


def dense_fps(
    pos: Tensor,
    mask: Tensor,
    ratio: float,
    start: str = "first",
    dist: Tensor | None = None,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, Tensor]:
    r"""Farthest point sampling on a padded batch.

    Graph g keeps :math:`m_g = \lceil \text{ratio} \cdot n_g \rceil` nodes:
    after the start node :math:`s_0`, each step picks

    .. math:: s_t = \arg\max_{j \notin S} \min_{s \in S} \lVert p_j - p_s \rVert^2

    One Python iteration per sample, batched over graphs; each step reads one
    row of the distance matrix. Ties go to the lowest slot with float
    distances (the highest slot with int32 keys).

    Useful property: FPS of the first :math:`m` samples, started at
    :math:`s_0`, returns those samples in the same order (each :math:`s_t`
    was the argmax over a superset). So hierarchical sampling needs one FPS
    run; the coarser levels are prefixes of it.

    Args:
        pos, mask: padded batch ``(B, N, 3)``, ``(B, N)``.
        ratio: fraction of nodes to keep, in (0, 1].
        start: ``"first"`` (first real node), ``"random"``, or
            ``"centroid"`` (farthest from the centroid: order independent).
        dist: precomputed :func:`pairwise_sqdist` or :func:`sqdist_keys_`
            (padding entries may hold anything finite). Default: exact.

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
    D = pairwise_sqdist(pos) if dist is None else dist
    D_rows = D.reshape(B * N, N)
    last = _fps_start(pos, mask, start, generator)
    # mind = distance to the chosen set. Padding holds the lowest value, so it
    # is never chosen; a chosen node gets the lowest value too, so that even
    # duplicate points are not picked twice.
    if D.dtype == torch.int32:  # keys: the diagonal is already INT_MIN
        low = _low_bits(N)
        offset = torch.arange(B, dtype=torch.int32, device=mask.device) * N  # row of slot 0
        mind = torch.full((B, N), _INT_MAX, dtype=torch.int32, device=D.device).masked_fill_(~mask, _INT_MIN)
        last = last.to(torch.int32)
        picks = [last]
        for _ in range(M - 1):
            torch.minimum(mind, D_rows.index_select(0, last + offset), out=mind)
            last = mind.amax(1) & low  # the max key carries its column
            picks.append(last)
    else:
        offset = torch.arange(B, device=mask.device) * N
        mind = torch.full((B, N), math.inf, dtype=D.dtype, device=D.device).masked_fill_(~mask, -math.inf)
        picks = [last]
        for _ in range(M - 1):
            flat = last + offset
            torch.minimum(mind, D_rows.index_select(0, flat), out=mind)
            mind.view(-1).index_fill_(0, flat, -math.inf)
            last = mind.max(1).indices  # ~2x faster than argmax
            picks.append(last)
    index = torch.stack(picks, 1).long()
    keep = torch.arange(M, device=mask.device) < m.unsqueeze(1)
    return index, keep


# --------------------------------------------------------------------------
# PyG-style wrappers on flat node lists
# --------------------------------------------------------------------------
def _dist(dense: Tensor, mask: Tensor, exact: bool) -> Tensor:
    D = pairwise_sqdist(dense, mask, exact=exact)
    return D if exact or D.dtype != torch.float32 else sqdist_keys_(D)


def knn_graph(
    pos: Tensor,
    batch: Tensor | None = None,
    k: int = 3,
    loop: bool = False,
    batch_size: int | None = None,
    exact: bool = True,
) -> Tensor:
    """kNN graph of a flat batch of point clouds (PyG convention).

    Each node i receives edges ``j -> i`` from its k nearest nodes j of the
    same graph (all other nodes if the graph has fewer than k + 1).
    ``exact=False`` uses the fast path (see module docstring).

    Shapes:
        - **input:** ``pos (V, 3)``, ``batch (V,)`` sorted
        - **output:** ``edge_index (2, E)``; edges grouped by target in node
          order, nearest source first.
    """
    dense, mask = to_dense(pos, batch, batch_size)
    index, valid = dense_knn(dense, mask, k, loop=loop, dist=_dist(dense, mask, exact))
    B, N, K = index.shape
    offset = flat_offsets(mask).view(B, 1, 1)
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
    exact: bool = True,
) -> Tensor:
    """Farthest point sampling of a flat batch (like ``torch_geometric.nn.fps``).

    Keeps ``ceil(ratio * n_g)`` nodes of every graph, starting at its first
    node, or a random one if ``random_start``; ``start`` (see
    :data:`FPS_STARTS`) overrides both. ``exact=False``: fast path.

    Shapes:
        - **input:** ``pos (V, 3)``, ``batch (V,)`` sorted
        - **output:** ``index (M,)`` into ``pos``, grouped by graph, in
          sampling order within each graph.
    """
    if start is None:
        start = "random" if random_start else "first"
    dense, mask = to_dense(pos, batch, batch_size)
    dist = _dist(dense, mask, exact) if dense.shape[1] > 0 else None
    index, keep = dense_fps(dense, mask, ratio, start=start, dist=dist, generator=generator)
    return (index + flat_offsets(mask).unsqueeze(1))[keep]
