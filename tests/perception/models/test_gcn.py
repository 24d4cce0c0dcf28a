"""TactileGCN: a fixed kNN graph of all taxels, the normalised adjacency precomputed."""

import torch

from tacgnn.perception.models import PerceptionModelConfig, build_model

T = 653


def make(rest, **kw):
    return build_model(PerceptionModelConfig(name="gcn", **kw), rest_positions=rest)


def test_matches_pyg_gcnconv_with_normalisation(rest, blobs):
    """The precomputed normalised adjacency equals GCNConv(normalize=True) on a batched graph,
    outputs and gradients (the model's backward pass reuses the symmetric adjacency)."""
    from torch_geometric.nn import GCNConv
    from torch_geometric.utils import to_undirected

    from tacgnn.perception.graph_ops import knn_graph

    torch.manual_seed(0)
    model = make(rest)
    readings, positions, _ = blobs(rest, 3, seed=7)
    edge_index = to_undirected(knn_graph(rest, k=6), num_nodes=T)
    assert edge_index.shape[1] >= 6 * T
    batched = torch.cat([edge_index + g * T for g in range(3)], 1)
    x = torch.cat([readings.unsqueeze(-1), positions], -1).reshape(3 * T, 4)
    refs = []
    for conv in model.convs:
        refs.append(ref := GCNConv(conv.in_channels, conv.out_channels))
        ref.lin.weight.data.copy_(conv.lin.weight)
        ref.bias.data.copy_(conv.bias)
        x = torch.relu(ref(x, batched))
    expected = model.head(x.view(3, T, -1).amax(1))
    out = model(readings, positions)
    torch.testing.assert_close(out, expected, atol=1e-5, rtol=1e-5)
    target = torch.randn_like(out)
    ((out - target) ** 2).sum().backward()
    head_grads = [p.grad.clone() for p in model.head.parameters()]
    model.head.zero_grad()
    ((expected - target) ** 2).sum().backward()
    for conv, ref in zip(model.convs, refs):
        torch.testing.assert_close(conv.lin.weight.grad, ref.lin.weight.grad, atol=1e-4, rtol=1e-4)
        torch.testing.assert_close(conv.bias.grad, ref.bias.grad, atol=1e-4, rtol=1e-4)
    for got, p in zip(head_grads, model.head.parameters()):
        torch.testing.assert_close(got, p.grad, atol=1e-4, rtol=1e-4)


def test_on_rest_positions_does_not_see_the_pose(rest, blobs):
    """gcn_node_positions=rest: moving the taxels (the hand's pose) leaves the output unchanged."""
    torch.manual_seed(0)
    current = make(rest)
    fixed = make(rest, gcn_node_positions="rest")
    fixed.load_state_dict(current.state_dict())
    readings, positions, _ = blobs(rest, 3, seed=9)
    moved = positions + 0.5 * torch.randn_like(positions)
    with torch.no_grad():
        assert torch.allclose(fixed(readings, positions), fixed(readings, moved))
        assert torch.allclose(fixed(readings, positions), current(readings, rest.expand(3, -1, -1)), atol=1e-6)
        assert not torch.allclose(current(readings, positions), current(readings, moved))
