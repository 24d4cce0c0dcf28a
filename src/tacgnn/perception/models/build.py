"""One entry point from a config to a model."""

from __future__ import annotations

from torch import Tensor

from tacgnn.perception.models.base import PerceptionModel
from tacgnn.perception.models.cnn import TactileCNN
from tacgnn.perception.models.config import PerceptionModelConfig
from tacgnn.perception.models.gcn import TactileGCN
from tacgnn.perception.models.mlp import TactileMLP
from tacgnn.perception.models.tacgnn import TacGNN


def build_model(cfg: PerceptionModelConfig, *, rest_positions: Tensor | None = None,
                cnn_layout: Tensor | None = None) -> PerceptionModel:
    """The model ``cfg.name`` with the settings of ``cfg``.

    The GCN needs the taxels' ``rest_positions (T, 3)`` (cm), the other models ignore
    them; the CNN accepts an optional ``cnn_layout (T, 2)`` of (row, col) pixels.
    """
    if not isinstance(cfg, PerceptionModelConfig):
        raise TypeError(f"build_model takes a PerceptionModelConfig, got {type(cfg).__name__}")
    if cfg.name == "tacgnn":
        return TacGNN(cfg)
    if cfg.name == "mlp":
        return TactileMLP(cfg.out_dim, cfg.num_taxels, cfg.mlp_hidden, cfg.joint_inputs, cfg.reading_feature)
    if cfg.name == "cnn":
        return TactileCNN(cfg.out_dim, cfg.num_taxels, cfg.image_size, cnn_layout, cfg.reading_feature)
    if rest_positions is None:
        raise ValueError("rest_positions (T, 3) is required for the gcn model")
    if tuple(rest_positions.shape) != (cfg.num_taxels, 3):
        raise ValueError(f"rest_positions must be ({cfg.num_taxels}, 3), got {tuple(rest_positions.shape)}")
    return TactileGCN(rest_positions, cfg.out_dim, cfg.gcn_k, cfg.gcn_channels, cfg.reading_feature,
                      cfg.gcn_node_positions)
