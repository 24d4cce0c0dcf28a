"""TactileCNN: readings packed into an image."""

import pytest
import torch
import torch.nn.functional as F

from tacgnn.perception.models import PerceptionModelConfig, TactileCNN, build_model

T = 653


def test_matches_relu_before_pool(rest, blobs):
    """Max-pooling before the ReLU on channels-last images computes the CNN of the old layer
    order (conv, ReLU, pool), so checkpoints written before the change mean the same."""
    torch.manual_seed(0)
    model = build_model(PerceptionModelConfig(name="cnn"))
    readings, positions, _ = blobs(rest, 4, seed=3)
    img = torch.zeros(4, 36 * 36)
    img[:, model.pixel] = readings
    conv1, conv2 = model.features[0], model.features[3]
    x = F.max_pool2d(torch.relu(F.conv2d(img.view(4, 1, 36, 36), conv1.weight.contiguous(), conv1.bias)), 2)
    x = F.max_pool2d(torch.relu(F.conv2d(x, conv2.weight.contiguous(), conv2.bias)), 2)
    with torch.no_grad():
        torch.testing.assert_close(model(readings, positions), model.head(x.flatten(1)))


def test_layout_packing(rest):
    layout = torch.stack([torch.arange(T) % 36, torch.arange(T) // 36], 1)  # column-major
    model = TactileCNN(layout=layout)
    readings = torch.zeros(1, T)
    readings[0, 40] = 1.0  # taxel 40 -> row 4, col 1
    img = torch.zeros(1, 36 * 36)
    img[:, model.pixel] = readings
    assert img.view(36, 36)[4, 1] == 1.0 and img.sum() == 1.0
    assert model(readings, rest.unsqueeze(0)).shape == (1, 6)
    with pytest.raises(ValueError, match="same pixel"):
        TactileCNN(layout=torch.zeros(T, 2, dtype=torch.long))
    with pytest.raises(ValueError, match="layout"):
        TactileCNN(layout=layout + 36)
