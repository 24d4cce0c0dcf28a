"""EdgeMaxConv against the update rule written out edge by edge."""

import pytest
import torch

from tacgnn.perception.models import EdgeMaxConv


def naive(conv: EdgeMaxConv, h, pos, neighbours):
    """h_i' = ReLU(max_j phi([h_i, h_j, x_j - x_i])), one node and one edge at a time."""
    layers = [conv.lin1, *conv.hidden, conv.lin2]
    out = []
    for i in range(h.shape[0]):
        messages = []
        for j in neighbours[:, i].tolist():
            e = torch.cat([h[i], h[j], pos[j] - pos[i]])
            for n, lin in enumerate(layers):
                e = lin(e)
                if n < len(layers) - 1:
                    e = torch.relu(e)
            messages.append(e)
        out.append(torch.relu(torch.stack(messages).amax(0)))
    return torch.stack(out)


@pytest.mark.parametrize("layers", [2, 3])
def test_matches_the_update_rule(layers):
    torch.manual_seed(0)
    conv = EdgeMaxConv(5, 8, layers)
    h, pos = torch.randn(7, 5), torch.randn(7, 3)
    neighbours = torch.randint(0, 7, (3, 7))
    torch.testing.assert_close(conv(h, pos, neighbours), naive(conv, h, pos, neighbours), atol=1e-5, rtol=1e-5)


def test_chunking_does_not_change_results():
    torch.manual_seed(0)
    conv = EdgeMaxConv(4, 6)
    h, pos = torch.randn(50, 4), torch.randn(50, 3)
    neighbours = torch.randint(0, 50, (4, 50))
    expected = conv(h, pos, neighbours)
    conv.chunk_size = 7
    torch.testing.assert_close(conv(h, pos, neighbours), expected)


def test_repeated_neighbour_slots_do_not_change_the_max():
    """Graph builders fill missing slots with a repeated neighbour: the output is the same."""
    torch.manual_seed(0)
    conv = EdgeMaxConv(4, 6)
    h, pos = torch.randn(5, 4), torch.randn(5, 3)
    two = torch.tensor([[1, 0, 0, 1, 2], [2, 2, 4, 4, 3]])
    padded = torch.cat([two, two[:1]])
    torch.testing.assert_close(conv(h, pos, padded), conv(h, pos, two))


def test_empty_graph_reset_and_repr():
    conv = EdgeMaxConv(3, 4, layers=3)
    assert conv(torch.zeros(0, 3), torch.zeros(0, 3), torch.zeros(3, 0, dtype=torch.long)).shape == (0, 4)
    before = conv.lin1.weight.detach().clone()
    conv.reset_parameters()
    assert not torch.equal(before, conv.lin1.weight)
    assert repr(conv) == "EdgeMaxConv(3, 4, layers=3)"
    with pytest.raises(ValueError, match="layers"):
        EdgeMaxConv(3, 4, layers=1)
