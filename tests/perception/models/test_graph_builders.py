"""Graph builders: canonical node order, kNN tables and sampling, numba and torch alike."""

import pytest
import torch

from tacgnn.perception import graph_numba
from tacgnn.perception.graph_ops import dense_fps, to_dense
from tacgnn.perception.models import graphs
from tacgnn.perception.models.graphs import CompiledGraphs, TorchGraphs, canonical_order, prefix_rows


def grid_nodes(seed):
    """Graphs of integer grid points (many exact distance ties) with repeated coordinates."""
    g = torch.Generator().manual_seed(seed)
    counts = torch.tensor([0, 1, 2, 7, 15, 40])
    pos = torch.randint(0, 5, (int(counts.sum()), 3), generator=g).float()
    force = torch.randint(1, 4, (int(counts.sum()),), generator=g).float()
    batch = torch.repeat_interleave(torch.arange(len(counts)), counts)
    return pos, force, batch, counts


def sorted_keys(pos, force, batch, order):
    return torch.cat([batch[order, None].float(), pos[order], force[order, None]], 1)


@pytest.mark.parametrize("compiled", [True, False])
def test_canonical_order_sorts_each_graph_lexicographically(compiled, monkeypatch):
    if compiled and not graph_numba.available():
        pytest.skip("numba is not installed")
    if not compiled:
        monkeypatch.setattr(graphs, "compiled_graphs_apply", lambda *a, **k: False)
    pos, force, batch, _ = grid_nodes(0)
    keys = sorted_keys(pos, force, batch, canonical_order(pos, batch, force))
    expected = sorted(map(tuple, sorted_keys(pos, force, batch, torch.arange(len(pos))).tolist()))
    assert list(map(tuple, keys.tolist())) == expected
    # any listing of the same nodes (within their graphs) gives the same sorted nodes
    perm = torch.cat([torch.randperm(int(c)) + int(s) for c, s in
                      zip(torch.bincount(batch), torch.cumsum(torch.bincount(batch), 0) - torch.bincount(batch))])
    p, f, b = pos[perm], force[perm], batch[perm]
    assert torch.equal(sorted_keys(p, f, b, canonical_order(p, b, f)), keys)


def test_canonical_order_groups_nodes_given_in_any_graph_order():
    pos, force, batch, _ = grid_nodes(1)
    shuffled = torch.randperm(len(pos), generator=torch.Generator().manual_seed(2))
    order = canonical_order(pos[shuffled], batch[shuffled], force[shuffled])
    assert torch.equal(batch[shuffled][order], batch)


def test_prefix_rows():
    counts, kept = torch.tensor([3, 0, 4]), torch.tensor([2, 0, 2])
    assert prefix_rows(counts, kept).tolist() == [0, 1, 3, 4]


def random_nodes(sizes, seed):
    g = torch.Generator().manual_seed(seed)
    counts = torch.tensor(sizes)
    return torch.rand(int(counts.sum()), 3, generator=g) * 5, counts


def levels(builder, ks=(3, 4, 3), sample=(True, False, True)):
    return [builder.level(k, s) for k, s in zip(ks, sample)]


@pytest.mark.parametrize("loop", [False, True])
def test_compiled_and_torch_builders_build_the_same_graphs(loop):
    """Random clouds (no ties): same neighbour sets, same sampled rows, level by level."""
    if not graph_numba.available():
        pytest.skip("numba is not installed")
    pos, counts = random_nodes([0, 1, 2, 3, 9, 30, 60], seed=3)
    for exact in (True, False):
        a = levels(CompiledGraphs(pos, counts, 0.5, loop))
        b = levels(TorchGraphs(pos, counts, 0.5, loop, exact=exact))
        for la, lb in zip(a, b):
            assert la.neighbours.shape == lb.neighbours.shape
            assert torch.equal(la.neighbours.sort(0).values, lb.neighbours.sort(0).values)
            assert torch.equal(la.counts, lb.counts)
            assert (la.keep is None) == (lb.keep is None)
            if la.keep is not None:
                assert torch.equal(la.keep, lb.keep)


def test_neighbours_are_the_nearest_nodes_and_small_graphs_repeat_them():
    pos, counts = random_nodes([1, 3, 20], seed=4)
    level = TorchGraphs(pos, counts, 0.5).level(3, sample=False)
    assert level.neighbours.shape == (3, 24)
    assert level.neighbours[:, 0].tolist() == [0, 0, 0]  # a lone node is its own neighbour
    for i in (1, 2, 3):  # two others, the nearest repeated in the third slot
        others = {1, 2, 3} - {i}
        assert set(level.neighbours[:, i].tolist()) == others
    for i in range(4, 24):
        d = (pos[4:24] - pos[i]).norm(dim=1)
        d[i - 4] = float("inf")
        assert set(level.neighbours[:, i].tolist()) == set((d.argsort()[:3] + 4).tolist())


def test_hierarchical_fps_is_a_prefix(rest, blobs):
    """The builders sample once and keep prefixes; that equals FPS rerun on each level."""
    readings, positions, _ = blobs(rest, 6, seed=5, sizes=(1, 60))
    b, t = (readings > 0).nonzero(as_tuple=True)
    pos, mask = to_dense(positions[b, t], b, batch_size=6)
    idx, keep = dense_fps(pos, mask, 0.5, start="centroid")
    level = pos.gather(1, idx.unsqueeze(-1).expand(-1, -1, 3))
    for _ in range(2):
        idx2, keep2 = dense_fps(level, keep, 0.5, start="first")
        M = idx2.shape[1]
        assert torch.equal(idx2[keep2], torch.arange(M).expand_as(idx2)[keep2])
        level, keep = level[:, :M], keep2
