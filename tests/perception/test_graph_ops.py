"""graph_ops against brute-force references (plain Python loops, one graph at a time)."""

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from tacgnn.perception.graph_ops import (
    dense_fps,
    farthest_point_sampling,
    fps_counts,
    from_dense,
    knn_graph,
    pairwise_sqdist,
    sqdist_keys_,
    to_dense,
)


def sqdist_to(p, q):
    """Squared distances from every row of p to point q, same float formula as graph_ops."""
    d = p - q
    return (d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2]


def random_batch(sizes, seed=0):
    g = torch.Generator().manual_seed(seed)
    pos = torch.rand(sum(sizes), 3, generator=g) * 10.0
    batch = torch.repeat_interleave(torch.arange(len(sizes)), torch.tensor(sizes, dtype=torch.long))
    return pos, batch


def naive_knn(pos, batch, k, loop=False):
    """Set of edges (j, i): for each i, the k nearest j of the same graph by full sort."""
    edges = set()
    for i in range(len(pos)):
        same = [j for j in range(len(pos)) if batch[j] == batch[i] and (loop or j != i)]
        d = sqdist_to(pos[same], pos[i]).tolist()
        for _, j in sorted(zip(d, same))[:k]:
            edges.add((j, i))
    return edges


def naive_fps(pos, batch, ratio, start_fn=lambda p: 0):
    """Textbook FPS, one graph at a time; returns flat indices."""
    out = []
    for g in batch.unique().tolist() if len(batch) else []:
        idx = (batch == g).nonzero().flatten().tolist()
        p = pos[idx]
        m = math.ceil(ratio * len(idx))
        chosen = [start_fn(p)]
        mind = sqdist_to(p, p[chosen[0]])
        while len(chosen) < m:
            best, best_d = None, -1.0
            for j in range(len(idx)):
                if j not in chosen and mind[j].item() > best_d:
                    best, best_d = j, mind[j].item()
            chosen.append(best)
            mind = torch.minimum(mind, sqdist_to(p, p[best]))
        out += [idx[j] for j in chosen]
    return out


SIZES = [[0], [1], [2], [1, 0, 2, 7], [5, 1, 1, 30, 0, 3], [17, 64, 2, 9]]


@pytest.mark.parametrize("sizes", SIZES)
@pytest.mark.parametrize("k", [1, 3, 6])
@pytest.mark.parametrize("loop", [False, True])
def test_knn_graph_matches_naive(sizes, k, loop):
    pos, batch = random_batch(sizes, seed=k)
    ei = knn_graph(pos, batch, k=k, loop=loop, batch_size=len(sizes))
    got = set(map(tuple, ei.t().tolist()))
    assert len(got) == ei.shape[1]  # no duplicate edges
    assert got == naive_knn(pos, batch, k, loop)


def test_knn_edges_sorted_by_target_then_distance():
    pos, batch = random_batch([12, 5])
    ei = knn_graph(pos, batch, k=4)
    assert torch.equal(ei[1], ei[1].sort(stable=True).values)
    d = ((pos[ei[0]] - pos[ei[1]]) ** 2).sum(1).view(-1, 4)
    assert bool((d[:, 1:] >= d[:, :-1]).all())


@pytest.mark.parametrize("sizes", SIZES)
@pytest.mark.parametrize("ratio", [0.5, 0.25, 0.3, 1.0])
def test_fps_matches_naive(sizes, ratio):
    pos, batch = random_batch(sizes, seed=3)
    got = farthest_point_sampling(pos, batch, ratio, batch_size=len(sizes)).tolist()
    assert got == naive_fps(pos, batch, ratio)


def test_fps_centroid_start_matches_naive_and_is_order_free():
    pos, batch = random_batch([20, 7, 1])

    def far_from_centroid(p):
        return int(((p - p.mean(0)) ** 2).sum(1).argmax())

    got = farthest_point_sampling(pos, batch, 0.5, start="centroid")
    assert got.tolist() == naive_fps(pos, batch, 0.5, far_from_centroid)
    perm = torch.cat([torch.randperm(20), 20 + torch.randperm(7), torch.tensor([27])])
    got_perm = farthest_point_sampling(pos[perm], batch, 0.5, start="centroid")
    assert torch.equal(perm[got_perm], got)  # same points, same order


def test_fps_random_start_is_valid_and_seeded():
    pos, batch = random_batch([10, 3, 0, 8])
    a = farthest_point_sampling(pos, batch, 0.5, random_start=True, batch_size=4,
                                generator=torch.Generator().manual_seed(1))
    b = farthest_point_sampling(pos, batch, 0.5, random_start=True, batch_size=4,
                                generator=torch.Generator().manual_seed(1))
    assert torch.equal(a, b)
    assert torch.equal(torch.bincount(batch[a], minlength=4), torch.tensor([5, 2, 0, 4]))
    for g in range(4):
        sel = a[batch[a] == g]
        assert len(set(sel.tolist())) == len(sel)  # distinct nodes


def test_fps_duplicate_points_are_not_repicked():
    pos = torch.zeros(4, 3)
    assert sorted(farthest_point_sampling(pos, ratio=1.0).tolist()) == [0, 1, 2, 3]


def test_ratio_rounding():
    n = torch.tensor([0, 1, 2, 3, 7, 10, 653])
    assert fps_counts(n, 0.5).tolist() == [0, 1, 1, 2, 4, 5, 327]
    assert fps_counts(n, 1.0).tolist() == n.tolist()
    assert fps_counts(n, 0.01).tolist() == [0, 1, 1, 1, 1, 1, 7]
    # same double-precision rule as Python's math.ceil(ratio * n)
    assert fps_counts(n, 0.3).tolist() == [math.ceil(0.3 * v) for v in n.tolist()]
    with pytest.raises(ValueError, match="ratio"):
        dense_fps(torch.zeros(1, 2, 3), torch.ones(1, 2, dtype=torch.bool), 0.0)


def test_to_dense_roundtrip_and_empty_graphs():
    x, batch = random_batch([3, 0, 2, 0])
    dense, mask = to_dense(x, batch, batch_size=4)
    assert dense.shape == (4, 3, 3) and mask.sum(1).tolist() == [3, 0, 2, 0]
    assert torch.equal(dense[0], x[:3]) and torch.equal(dense[2, :2], x[3:])
    x2, batch2 = from_dense(dense, mask)
    assert torch.equal(x2, x) and torch.equal(batch2, batch)
    with pytest.raises(ValueError, match="sorted"):
        to_dense(x, batch.flip(0))


@settings(max_examples=25, deadline=None)
@given(
    sizes=st.lists(st.integers(0, 12), min_size=1, max_size=5),
    k=st.integers(1, 5),
    ratio=st.floats(0.05, 1.0),
    seed=st.integers(0, 1000),
)
def test_property_knn_and_fps(sizes, k, ratio, seed):
    pos, batch = random_batch(sizes, seed)
    B = len(sizes)
    ei = knn_graph(pos, batch, k=k, batch_size=B)
    assert set(map(tuple, ei.t().tolist())) == naive_knn(pos, batch, k)
    idx = farthest_point_sampling(pos, batch, ratio, batch_size=B)
    assert idx.tolist() == naive_fps(pos, batch, ratio)


# --------------------------------------------------------------------------
# fast path: matmul distances + int32 keys (used by the model)
# --------------------------------------------------------------------------
@pytest.mark.parametrize("sizes", SIZES)
@pytest.mark.parametrize("k", [1, 3, 6])
@pytest.mark.parametrize("loop", [False, True])
def test_fast_knn_graph_matches_naive(sizes, k, loop):
    # far from the origin on purpose: the matmul expansion must not lose precision
    pos, batch = random_batch(sizes, seed=10 + k)
    pos = pos + torch.tensor([50.0, -30.0, 20.0])
    ei = knn_graph(pos, batch, k=k, loop=loop, batch_size=len(sizes), exact=False)
    assert set(map(tuple, ei.t().tolist())) == naive_knn(pos, batch, k, loop)


@pytest.mark.parametrize("sizes", SIZES)
@pytest.mark.parametrize("ratio", [0.5, 0.3, 1.0])
def test_fast_fps_matches_naive(sizes, ratio):
    pos, batch = random_batch(sizes, seed=20)
    got = farthest_point_sampling(pos, batch, ratio, batch_size=len(sizes), exact=False)
    assert got.tolist() == naive_fps(pos, batch, ratio)


def test_sqdist_keys_order_like_distances():
    pos, batch = random_batch([40, 9])
    dense, mask = to_dense(pos, batch)
    D = pairwise_sqdist(dense, mask, exact=False)
    keys = sqdist_keys_(D.clone())
    n = keys.shape[-1]
    low = (1 << (n - 1).bit_length()) - 1
    off = ~torch.eye(n, dtype=torch.bool) & mask.unsqueeze(1) & mask.unsqueeze(2)
    cols = torch.arange(n, dtype=torch.int32).expand_as(keys)
    assert torch.equal((keys & low)[off], cols[off])  # the column sits in the low bits
    order_keys = keys.masked_fill(~off, 2**31 - 1).argsort(-1)[..., :5]
    order_dist = D.masked_fill(~off, float("inf")).argsort(-1)[..., :5]
    assert torch.equal(order_keys[mask], order_dist[mask])
    assert (torch.diagonal(keys, dim1=1, dim2=2) == -(2**31)).all()  # "self" marker used by FPS


# --------------------------------------------------------------------------
# compiled path (numba): flat node lists, as TacGNN uses them
# --------------------------------------------------------------------------
def _edges_of_table(table, loop):
    return {(int(table[s, i]), i) for i in range(table.shape[1]) for s in range(table.shape[0])
            if loop or int(table[s, i]) != i}


@pytest.mark.parametrize("sizes", SIZES)
@pytest.mark.parametrize("k", [1, 3, 6])
@pytest.mark.parametrize("loop", [False, True])
def test_compiled_knn_table_matches_naive(sizes, k, loop):
    graph_numba = pytest.importorskip("tacgnn.perception.graph_numba")
    if not graph_numba.available():
        pytest.skip("numba is not installed")
    pos, batch = random_batch(sizes, seed=30 + k)
    table = graph_numba.knn_table(pos, torch.tensor(sizes), k, loop)
    n_max = max(sizes)
    assert table.shape == (max(1, min(k, n_max if loop else n_max - 1)), len(pos))
    assert _edges_of_table(table, loop) == naive_knn(pos, batch, k, loop)
    for i in range(len(pos)):  # every slot is a node of the same graph (itself only when alone)
        assert all(batch[int(j)] == batch[i] for j in table[:, i])


@pytest.mark.parametrize("sizes", SIZES)
@pytest.mark.parametrize("ratio", [0.5, 0.3, 1.0])
def test_compiled_fps_matches_naive(sizes, ratio):
    graph_numba = pytest.importorskip("tacgnn.perception.graph_numba")
    if not graph_numba.available():
        pytest.skip("numba is not installed")
    pos, batch = random_batch(sizes, seed=40)
    counts = torch.tensor(sizes)
    got = graph_numba.fps_rows(pos, counts, fps_counts(counts, ratio), centroid_start=False)
    assert got.tolist() == naive_fps(pos, batch, ratio)
    centroid = lambda p: int(((p - p.mean(0)) ** 2).sum(1).argmax())  # noqa: E731
    got = graph_numba.fps_rows(pos, counts, fps_counts(counts, ratio), centroid_start=True)
    assert got.tolist() == naive_fps(pos, batch, ratio, start_fn=centroid)


def test_one_graph_takes_the_serial_kernels_and_gets_the_same_rows():
    """A single graph (a control tick's frame) runs the serial compile: same tables, same order."""
    graph_numba = pytest.importorskip("tacgnn.perception.graph_numba")
    if not graph_numba.available():
        pytest.skip("numba is not installed")
    serial, parallel = graph_numba._compile(parallel=False), graph_numba._compile(parallel=True)
    assert serial is not parallel and graph_numba._kernels_for(1) is serial and graph_numba._kernels_for(2) is parallel
    g = torch.Generator().manual_seed(50)
    for n in (0, 1, 2, 9, 64):
        pos = torch.randint(0, 4, (n, 3), generator=g).float()  # a grid: many tied distances and keys
        counts = torch.tensor([n])
        xt, ptr = graph_numba._coordinates(pos), graph_numba._ptr(counts)
        for k, loop in ((1, False), (6, False), (6, True)):
            K = max(1, min(k, n if loop else n - 1))
            table = graph_numba.knn_table(pos, counts, k, loop)
            assert torch.equal(table, torch.from_numpy(parallel[0](xt, ptr, K, loop))), (n, k, loop)
        keys = torch.cat([pos.t(), torch.randint(1, 3, (1, n), generator=g).float()])
        expected = parallel[2](graph_numba._coordinates(keys.t()).copy(), ptr)
        assert torch.equal(graph_numba.lexicographic_order(keys, counts), torch.from_numpy(expected)), n
