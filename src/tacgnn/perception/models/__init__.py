"""Perception models: one tactile frame -> object state (e.g. the two ball centres).

* :class:`TacGNN` (``tacgnn.py``): hierarchical dynamic-graph network on the activated
  taxels, built from :class:`EdgeMaxConv` layers (``edge_conv.py``) over graphs from a
  graph builder (``graphs.py``).
* :class:`TactileMLP` (``mlp.py``), :class:`TactileCNN` (``cnn.py``),
  :class:`TactileGCN` (``gcn.py``): the paper's baselines.

All share :class:`PerceptionModel`'s call signature (``base.py``) and are built from a
:class:`PerceptionModelConfig` (``config.py``) by :func:`build_model` (``build.py``).
"""

from tacgnn.perception.models.base import PerceptionModel, reading_input
from tacgnn.perception.models.build import build_model
from tacgnn.perception.models.cnn import TactileCNN
from tacgnn.perception.models.config import MODEL_NAMES, PerceptionModelConfig
from tacgnn.perception.models.edge_conv import EdgeMaxConv
from tacgnn.perception.models.gcn import TactileGCN
from tacgnn.perception.models.mlp import TactileMLP
from tacgnn.perception.models.tacgnn import TacGNN

__all__ = [
    "MODEL_NAMES",
    "PerceptionModelConfig",
    "PerceptionModel",
    "TacGNN",
    "EdgeMaxConv",
    "TactileMLP",
    "TactileCNN",
    "TactileGCN",
    "build_model",
    "reading_input",
]
