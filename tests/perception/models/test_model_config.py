"""PerceptionModelConfig: every field validated by name, lists become tuples, frozen."""

import dataclasses

import pytest

from tacgnn.config import ConfigError, from_dict
from tacgnn.perception.models import PerceptionModelConfig


@pytest.mark.parametrize(
    "field, value",
    [
        ("name", "transformer"),
        ("channels", 0),
        ("channels", 32.0),
        ("channels", 32_000_000),
        ("mlp_hidden", (64, 64_000_000)),
        ("k", (3,) * 17),
        ("num_taxels", 653_000),
        ("k", (3, 0, 3)),
        ("k", ()),
        ("sample_ratio", 0.0),
        ("sample_ratio", 1.5),
        ("sample_ratio", float("nan")),
        ("downsample_layers", (0, 3)),
        ("downsample_layers", (1, 1)),
        ("use_force", 1),
        ("exact_graph", "yes"),
        ("out_dim", -1),
        ("num_taxels", 0),
        ("fps_start", "middle"),
        ("gcn_k", 0),
        ("gcn_channels", (32, 0)),
        ("mlp_hidden", 64),
        ("pool", "mean"),
        ("force_feature", "sqrt"),
        ("message_layers", 1),
        ("head_hidden", -1),
        ("pos_scale", 0.0),
        ("pos_scale", float("inf")),
        ("pos_scale", 1e300),  # accepted once, then the model's outputs were NaN (found by the config fuzz test)
        ("residual", "yes"),
        ("reading_feature", "log"),
        ("gcn_node_positions", "mean"),
    ],
)
def test_config_validation_names_the_field(field, value):
    with pytest.raises(ConfigError, match=f"'{field}'"):
        PerceptionModelConfig(**{field: value})


def test_nested_keys_are_named_in_full():
    """Inside another config the error names the dotted key, as the command line spells it."""
    with pytest.raises(ConfigError, match="'model.channels'"):
        from_dict(PerceptionModelConfig, {"channels": 0}, prefix="model.")


def test_cross_field_rules():
    with pytest.raises(ConfigError, match="'image_size'.*num_taxels=653"):
        PerceptionModelConfig(name="cnn", image_size=10)
    assert PerceptionModelConfig(name="tacgnn", num_taxels=6530).num_taxels == 6530  # only the CNN has an image
    with pytest.raises(ConfigError, match="force_feature"):
        PerceptionModelConfig(name="tacgnn", reading_feature="log1p")
    assert PerceptionModelConfig(name="mlp", reading_feature="log1p").reading_feature == "log1p"
    with pytest.raises(ConfigError, match="joint_inputs"):
        PerceptionModelConfig(name="gcn", joint_inputs=16)


def test_lists_become_tuples_and_the_config_is_frozen():
    cfg = PerceptionModelConfig(k=[6, 4, 3], downsample_layers=[0, 1])
    assert cfg.k == (6, 4, 3) and cfg.downsample_layers == (0, 1)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.channels = 64
