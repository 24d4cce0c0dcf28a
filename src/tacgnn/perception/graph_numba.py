"""kNN tables and farthest point sampling on flat node lists, compiled with numba.

Why: TacGNN's graphs are tiny (tens of activated taxels) and rebuilt every forward. In
torch, each kNN or FPS step is a batched op over all graphs, but FPS needs one step per
sample and every op pays a fixed dispatch cost; most of a forward went into these small
ops. Here one compiled pass per layer walks the graphs one by one (``prange``: both cores)
and writes exactly what the network consumes: a ``(K, V)`` table of neighbour rows and the
FPS order as flat rows. One graph (a control tick's single frame) goes to a serial compile
of the same kernels: a parallel region has nothing to share out there, and entering it
costs thread wake-ups that on 2 loaded cores took far longer than the work. Both give the
same rows. Distances are float32 ``(dx^2 + dy^2) + dz^2``, as in the exact torch path
(:mod:`tacgnn.perception.graph_ops`); ties go to the lower index.

The torch versions in :mod:`graph_ops` stay the reference (and the fallback without numba);
the tests check both against brute force.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

_kernels: dict[bool, tuple] = {}  # parallel flavour -> (knn_table, fps_order, lex_order)
_numba_missing = False


def available() -> bool:
    return _compile() is not None


def _compile(parallel: bool = True):
    """The kernels, compiled once per process and flavour (cached on disk by numba); None without numba.

    ``parallel``: kNN and the sort walk the graphs with ``prange``; else the same source
    compiled serially (FPS is serial in both).
    """
    global _numba_missing
    if parallel not in _kernels and not _numba_missing:
        try:
            import numba
        except ImportError:
            _numba_missing = True
            return None
        # a closure over the loop: numba's disk cache keys a function by its code and closure
        # values, not by its compile flags, so the two flavours must differ in a value
        _kernels[parallel] = _build(numba, numba.prange if parallel else range, parallel)
    return _kernels.get(parallel)


def _build(numba, graphs_range, parallel: bool) -> tuple:
    # kNN: graphs in parallel (2x faster on 2 cores); FPS stays serial (measured 15x
    # slower with prange: its loop is short and the per-graph arrays were not hoisted)
    @numba.njit(cache=True, nogil=True, parallel=parallel)
    def knn_table(xt, ptr, K, loop):  # pragma: no cover (compiled)
        V = xt.shape[1]
        out = np.empty((K, V), np.int64)
        for g in graphs_range(ptr.shape[0] - 1):
            lo, hi = ptr[g], ptr[g + 1]
            n = hi - lo
            xs, ys, zs = xt[0, lo:hi], xt[1, lo:hi], xt[2, lo:hi]
            row = np.empty(n, np.float32)
            best_d = np.empty(K, np.float32)  # the K nearest so far, ascending (K <= k)
            best_j = np.empty(K, np.int64)
            for i in range(n):
                for j in range(n):  # a row of distances: a loop the compiler vectorises
                    d0, d1, d2 = xs[j] - xs[i], ys[j] - ys[i], zs[j] - zs[i]
                    row[j] = (d0 * d0 + d1 * d1) + d2 * d2
                found = 0
                for j in range(n):
                    if j == i and not loop:
                        continue
                    d = row[j]
                    if found == K:
                        if d >= best_d[K - 1]:  # the common case once K are found
                            continue
                        s = K - 1
                    else:
                        s = found
                        found += 1
                    while s > 0 and best_d[s - 1] > d:  # strict: on equal distances the lower j stays first
                        best_d[s], best_j[s] = best_d[s - 1], best_j[s - 1]
                        s -= 1
                    best_d[s], best_j[s] = d, j
                for s in range(K):
                    if found == 0:  # a lone node is its own neighbour
                        out[s, lo + i] = lo + i
                    else:  # missing slots repeat the nearest: the max over them is unchanged
                        out[s, lo + i] = lo + (best_j[s] if s < found else best_j[0])
        return out

    @numba.njit(cache=True, nogil=True)
    def fps_order(xt, ptr, m, centroid_start):  # pragma: no cover (compiled)
        """Per graph, the first m[g] FPS picks as flat rows, graph after graph."""
        B = ptr.shape[0] - 1
        start_out = np.zeros(B + 1, np.int64)
        for g in range(B):
            start_out[g + 1] = start_out[g] + m[g]
        out = np.empty(start_out[B], np.int64)
        for g in range(B):
            lo, hi = ptr[g], ptr[g + 1]
            n = hi - lo
            if m[g] == 0:
                continue
            xs, ys, zs = xt[0, lo:hi], xt[1, lo:hi], xt[2, lo:hi]
            last = 0
            if centroid_start:  # the node farthest from the centroid: independent of node order
                c0, c1, c2 = xs.sum() / n, ys.sum() / n, zs.sum() / n
                far = np.float32(-1.0)
                for j in range(n):
                    d0, d1, d2 = xs[j] - c0, ys[j] - c1, zs[j] - c2
                    d = (d0 * d0 + d1 * d1) + d2 * d2
                    if d > far:
                        far, last = d, j
            mind = np.full(n, np.inf, np.float32)  # squared distance to the chosen set
            out[start_out[g]] = lo + last
            for t in range(1, m[g]):
                mind[last] = -np.inf  # chosen: never picked again, even if duplicated
                px, py, pz = xs[last], ys[last], zs[last]
                for j in range(n):
                    d0, d1, d2 = xs[j] - px, ys[j] - py, zs[j] - pz
                    mind[j] = min(mind[j], (d0 * d0 + d1 * d1) + d2 * d2)
                best, best_d = 0, mind[0]
                for j in range(1, n):
                    if mind[j] > best_d:  # strict: the lowest index wins ties
                        best, best_d = j, mind[j]
                last = best
                out[start_out[g] + t] = lo + last
        return out

    @numba.njit(cache=True, nogil=True)
    def lex_greater(keys, a, b):  # pragma: no cover (compiled)
        """Row a after row b: the first key that differs decides."""
        for r in range(keys.shape[0]):
            if keys[r, a] != keys[r, b]:
                return keys[r, a] > keys[r, b]
        return False

    # binary insertion sort per graph: n log n comparisons (each reads up to m keys), and
    # shifts of a few hundred ints at most; no allocation per graph (graphs hold tens of nodes)
    @numba.njit(cache=True, nogil=True, parallel=parallel)
    def lex_order(keys, ptr):  # pragma: no cover (compiled)
        """Per graph, its rows sorted by keys[0], then keys[1], ... (stable), as flat rows."""
        out = np.empty(keys.shape[1], np.int64)
        for g in graphs_range(ptr.shape[0] - 1):
            lo, hi = ptr[g], ptr[g + 1]
            for i in range(lo, hi):
                cur = i
                left, right = lo, i  # first sorted row that comes after cur: equal rows stay first
                while left < right:
                    mid = (left + right) // 2
                    if lex_greater(keys, out[mid], cur):
                        right = mid
                    else:
                        left = mid + 1
                for j in range(i, left, -1):
                    out[j] = out[j - 1]
                out[left] = cur
        return out

    return knn_table, fps_order, lex_order


def _follow_torch_threads() -> None:
    """Run the parallel kernel on as many threads as torch may use (``torch.set_num_threads``).

    Why: a run set to 1 thread shares the cores with other work; there, OpenMP threads that
    wait for each other at every call made a training epoch 4-7x slower (measured with three
    jobs on two cores).
    """
    import numba

    # NUMBA_NUM_THREADS is set at import by numba.config from the environment, so no checker can see it
    max_threads = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]
    numba.set_num_threads(max(1, min(torch.get_num_threads(), max_threads)))


def _kernels_for(num_graphs: int) -> tuple:
    """Serial kernels for one graph (nothing to share out), the parallel ones for a batch."""
    if num_graphs <= 1:
        return _compile(parallel=False)
    _follow_torch_threads()
    return _compile()


def _coordinates(x: Tensor) -> np.ndarray:
    """(3, V) float32: one contiguous row per axis."""
    return np.ascontiguousarray(x.detach().numpy().T, np.float32)


def _ptr(counts: Tensor) -> np.ndarray:
    return np.concatenate([[0], np.cumsum(counts.numpy())]).astype(np.int64)


def knn_table(x: Tensor, counts: Tensor, k: int, loop: bool = False) -> Tensor:
    """``(K, V)`` flat rows of each node's k nearest nodes of its graph, nearest first.

    ``K = max(1, min(k, N - 1 + loop))`` for the largest graph N; slots a small graph
    cannot fill repeat its nearest neighbour, a lone node gets itself (as
    ``models.graphs.TorchGraphs``). ``x (V, 3)`` float32 on CPU, graphs as consecutive rows of
    ``counts (B,)`` nodes.
    """
    knn, _, _ = _kernels_for(len(counts))
    n_max = int(counts.max()) if len(counts) else 0
    K = max(1, min(k, n_max if loop else n_max - 1))
    table = knn(_coordinates(x), _ptr(counts), K, loop)
    return torch.from_numpy(table)


def fps_rows(x: Tensor, counts: Tensor, num_samples: Tensor, centroid_start: bool = True) -> Tensor:
    """Flat rows of the first ``num_samples[g]`` FPS picks of every graph, graph after graph.

    Start: the node farthest from the centroid (``centroid_start``) or the first node.
    """
    _, fps, _ = _compile(parallel=len(counts) > 1)  # FPS is serial in both flavours
    rows = fps(_coordinates(x), _ptr(counts),
               num_samples.numpy().astype(np.int64), centroid_start)
    return torch.from_numpy(rows)


def lexicographic_order(keys: Tensor, counts: Tensor) -> Tensor:
    """Flat rows of every graph's nodes sorted by ``keys[0]``, ties by ``keys[1]``, ... (stable).

    ``keys (m, V)`` float32 on CPU, graphs as consecutive rows of ``counts (B,)`` nodes.
    """
    *_, lex = _kernels_for(len(counts))
    return torch.from_numpy(lex(np.ascontiguousarray(keys.detach().numpy(), np.float32), _ptr(counts)))
