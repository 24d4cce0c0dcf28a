"""TactileMLP: the readings through an MLP."""

import torch

from tacgnn.perception.models import PerceptionModelConfig, build_model


def test_sizes():
    model = build_model(PerceptionModelConfig(name="mlp", mlp_hidden=(40, 20), joint_inputs=16, out_dim=9))
    widths = [(m.in_features, m.out_features) for m in model.mlp if isinstance(m, torch.nn.Linear)]
    assert widths == [(653 + 16, 40), (40, 20), (20, 9)]


def test_reads_the_readings_only(rest, blobs):
    """The paper's MLP is blind to where the taxels are: moving them changes nothing."""
    torch.manual_seed(0)
    model = build_model(PerceptionModelConfig(name="mlp"))
    readings, positions, _ = blobs(rest, 3, seed=1)
    with torch.no_grad():
        torch.testing.assert_close(model(readings, positions + 5.0), model(readings, positions))
