"""The one config all perception models are built from (:func:`tacgnn.perception.models.build_model`)."""

from __future__ import annotations

from dataclasses import dataclass

from tacgnn.config import check
from tacgnn.perception.graph_ops import FPS_STARTS

MODEL_NAMES = ("tacgnn", "mlp", "cnn", "gcn")
#: TacGNN force node feature (with ``use_force``): the reading in N, or ``log(f / 1 N)``.
FORCE_FEATURES = ("raw", "log")
#: MLP, CNN and GCN force input: the reading in N ("raw", the paper), or ``log(1 + f / 0.01 N)``
#: ("log1p": 0 where nothing presses, and a force scaled by a constant becomes nearly a shift,
#: as TacGNN's log force does; experiments/perception_inputs.sh).
READING_FEATURES = ("raw", "log1p")
#: GCN node positions: each taxel's current position ("current", our default; it carries the whole
#: hand's pose), or its fixed rest position ("rest": the nodes' inputs then vary with the forces only,
#: a GCN blind to the hand's pose as the paper describes it, sec. V-A and VI). facts.md gives the
#: node features as [force, xyz] without saying which xyz; docs/results.md compares both.
GCN_NODE_POSITIONS = ("current", "rest")
#: TacGNN readout input: global max pool of the last layer ("last", the paper), or of every
#: layer: concatenated ("all", L x C wide), concatenated and mapped to C by a linear layer
#: without bias ("jk", jumping knowledge; the head's input stays C wide) or summed ("sum").
POOLS = ("last", "all", "jk", "sum")
#: The paper's TacGNN over these defaults: ``PerceptionModelConfig(**PAPER_TACGNN)``.
PAPER_TACGNN = {"use_force": False, "force_feature": "raw", "pool": "last"}

_SEQUENCES = ("k", "downsample_layers", "mlp_hidden", "gcn_channels")
#: Upper bounds: far above any useful setting, low enough that a typo (channels=32000000)
#: is refused when the config loads instead of failing to allocate later.
_POSITIVE_INTS = {"out_dim": 1024, "num_taxels": 65536, "channels": 4096, "image_size": 512, "gcn_k": 64,
                  "message_layers": 16, "head_layers": 16}
_MAX_WIDTH, _MAX_K, _MAX_LAYERS = 4096, 64, 16
_MAX_POS_SCALE = 1e3  # taxel positions (cm) times it feed float32 layers: far beyond this they overflow
_BOOLS = ("use_force", "self_loop", "exact_graph", "residual")


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


@dataclass(frozen=True)
class PerceptionModelConfig:
    """Hyper-parameters of all perception models (each model reads its own fields).

    The one place of the models' defaults: offline training, the temporal model's frame
    encoder and the perception in the PPO loop all start from them. They differ from the
    paper's TacGNN in two settings that train better (experiments/perception_accuracy/NOTES.md):
    the force is a log node feature and the readout pools every layer (``use_force=true
    force_feature=log pool=jk``); the paper's is ``use_force=false force_feature=raw pool=last``
    (``PAPER_TACGNN``). A checkpoint stores every field, so these defaults never decide how a
    stored model is rebuilt.

    Lists (e.g. from YAML) become tuples; an invalid value raises
    :class:`tacgnn.config.ConfigError` naming the field.
    """

    name: str = "tacgnn"
    """One of MODEL_NAMES."""
    out_dim: int = 6
    num_taxels: int = 653
    # --- TacGNN
    channels: int = 32
    """C of every layer; the paper sweeps 16/32/64/128."""
    k: tuple[int, ...] = (3, 3, 3)
    """Neighbours per layer; len(k) = number of layers."""
    sample_ratio: float = 0.5
    """Farthest point sampling keeps ceil(ratio * n) nodes."""
    downsample_layers: tuple[int, ...] = (0, 1, 2)
    """Sample after these layers (0-based)."""
    use_force: bool = True
    """Node input [x, y, z, force] instead of [x, y, z] (the paper: false)."""
    self_loop: bool = False
    """Let a node be its own neighbour."""
    fps_start: str = "centroid"
    """First sample: see graph_ops.FPS_STARTS; 'centroid' does not depend on the taxel order."""
    exact_graph: bool = False
    """Torch graph building with exact distances (the reference; slower)."""
    force_feature: str = "log"
    """With use_force: the node's force input, see FORCE_FEATURES."""
    pos_scale: float = 1.0
    """Node positions (cm) are multiplied by this before the network."""
    message_layers: int = 2
    """Linear layers of the message MLP phi (paper: 2)."""
    head_layers: int = 2
    """Linear layers of the readout MLP (paper: 2)."""
    head_hidden: int = 0
    """Width of the head's hidden layers; 0 = width of all pooled features (C, or L*C with pool all/jk)."""
    residual: bool = False
    """h^l = conv(h^{l-1}) + h^{l-1} where the widths match."""
    pool: str = "jk"
    """Readout input: see POOLS (the paper: 'last')."""
    joint_inputs: int = 0
    """TacGNN and MLP: hand joint angles read beside the skin (0 = skin only, the paper)."""
    reading_feature: str = "raw"
    """MLP, CNN and GCN: force input, see READING_FEATURES."""
    # --- MLP
    mlp_hidden: tuple[int, ...] = (64, 64)
    # --- CNN
    image_size: int = 36
    """Side of the CNN's square image; it must hold num_taxels pixels."""
    # --- GCN
    gcn_k: int = 6
    gcn_channels: tuple[int, ...] = (32, 32, 32)
    gcn_node_positions: str = "current"
    """See GCN_NODE_POSITIONS."""

    def __post_init__(self) -> None:
        for f in _SEQUENCES:
            v = getattr(self, f)
            check(isinstance(v, (list, tuple)), f, f"must be a sequence of ints, got {v!r}")
            object.__setattr__(self, f, tuple(v))
        check(self.name in MODEL_NAMES, "name", f"must be one of {MODEL_NAMES}, got {self.name!r}")
        for f, most in _POSITIVE_INTS.items():
            v = getattr(self, f)
            check(_is_int(v) and 1 <= v <= most, f, f"must be an int in 1..{most}, got {v!r}")
        check(self.message_layers >= 2, "message_layers", f"must be >= 2, got {self.message_layers!r}")
        check(_is_int(self.head_hidden) and 0 <= self.head_hidden <= _MAX_WIDTH, "head_hidden",
              f"must be an int in 0..{_MAX_WIDTH}, got {self.head_hidden!r}")
        for f, most in (("k", _MAX_K), ("mlp_hidden", _MAX_WIDTH), ("gcn_channels", _MAX_WIDTH)):
            check(0 < len(getattr(self, f)) <= _MAX_LAYERS, f, f"must hold 1..{_MAX_LAYERS} values")
            for v in getattr(self, f):
                check(_is_int(v) and 1 <= v <= most, f, f"must hold ints in 1..{most}, got {v!r}")
        check(_is_number(self.sample_ratio) and 0.0 < self.sample_ratio <= 1.0, "sample_ratio",
              f"must be in (0, 1], got {self.sample_ratio!r}")
        layers = range(len(self.k))
        check(all(_is_int(i) and i in layers for i in self.downsample_layers), "downsample_layers",
              f"must be layer indices in {list(layers)} (one layer per entry of k), got {self.downsample_layers}")
        check(len(set(self.downsample_layers)) == len(self.downsample_layers), "downsample_layers",
              f"has duplicates: {self.downsample_layers}")
        check(self.force_feature in FORCE_FEATURES, "force_feature",
              f"must be one of {FORCE_FEATURES}, got {self.force_feature!r}")
        check(self.reading_feature in READING_FEATURES, "reading_feature",
              f"must be one of {READING_FEATURES}, got {self.reading_feature!r}")
        check(self.reading_feature == "raw" or self.name != "tacgnn", "reading_feature",
              "is the mlp, cnn and gcn input; TacGNN's force input is force_feature")
        check(self.gcn_node_positions in GCN_NODE_POSITIONS, "gcn_node_positions",
              f"must be one of {GCN_NODE_POSITIONS}, got {self.gcn_node_positions!r}")
        check(self.pool in POOLS, "pool", f"must be one of {POOLS}, got {self.pool!r}")
        check(_is_number(self.pos_scale) and 0 < self.pos_scale <= _MAX_POS_SCALE, "pos_scale",
              f"must be a positive number up to {_MAX_POS_SCALE:g}, got {self.pos_scale!r}")
        check(self.joint_inputs in (0, 16) and _is_int(self.joint_inputs), "joint_inputs",
              f"must be 0 (skin only) or 16 (the hand's joint angles), got {self.joint_inputs!r}")
        check(not self.joint_inputs or self.name in ("tacgnn", "mlp"), "joint_inputs",
              f"is supported by tacgnn and mlp, not {self.name!r}")
        for f in _BOOLS:
            check(isinstance(getattr(self, f), bool), f, f"must be a bool, got {getattr(self, f)!r}")
        check(self.fps_start in FPS_STARTS, "fps_start", f"must be one of {FPS_STARTS}, got {self.fps_start!r}")
        check(self.name != "cnn" or self.image_size**2 >= self.num_taxels, "image_size",
              f"a {self.image_size} x {self.image_size} image cannot hold num_taxels={self.num_taxels} taxels")
