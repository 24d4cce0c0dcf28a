"""How a perception model is trained on sequences (``tacgnn train-perception --temporal``).

    split by episode 80/20 (seeded) -> windows of `window` consecutive frames of one episode,
    the state warmed up over the `burn_in` frames before each window without gradient
    (truncated back-propagation through time) -> Adam(lr 3e-3, weight decay 1e-5, x0.8 per
    epoch), MSE over the two balls (permutation-invariant per frame)

``temporal=false`` trains the temporal model's frame encoder alone, frame by frame, with its
own head on the same split: the single-frame comparison on the same data and budget. An
epoch puts every training frame into the loss once on average for both.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from tacgnn.config import check, check_seed
from tacgnn.perception.models.temporal import TemporalModelConfig

MAX_THREADS = 256


@dataclass(frozen=True)
class SequenceTrainConfig:
    model: TemporalModelConfig = field(default_factory=TemporalModelConfig)
    temporal: bool = True
    """False: the single-frame model ``model.frame`` (out_dim 6) on the same split and budget."""
    window: int = 16
    """Frames per window with gradient (the length of truncated back-propagation through time)."""
    burn_in: int = 16
    """Frames before each window run without gradient to bring the state to where it would be
    (fewer at an episode's start, where the state starts fresh as in the env)."""
    epochs: int = 10
    batch_size: int = 8
    """Windows per step (temporal) or frames per step (single-frame)."""
    lr: float = 3e-3
    weight_decay: float = 1e-5
    lr_decay: float = 0.8
    """The learning rate is multiplied by this every epoch (smoothly, every step)."""
    train_fraction: float = 0.8
    max_frames: int = 0
    """Use only the first episodes of the dataset, up to this many frames (0: all)."""
    extra_train: tuple[str, ...] = ()
    """Datasets whose episodes all go to training, added after the split by episode: the
    test episodes stay those of the main dataset (e.g. more data of rare long holds)."""
    seed: int = 0
    threads: int = 1
    match_balls: bool = True
    """Permutation-invariant loss over the two balls in every frame."""
    eval_from_step: int = 6
    """Test errors count frames from this step of an episode on (the balls drop from the spawn
    before; Table II datasets skip those 5 steps). Every model still reads the earlier frames."""

    def __post_init__(self) -> None:
        check(isinstance(self.model, TemporalModelConfig), "model", "must be a temporal model config")
        check(self.window >= 1, "window", f"must be >= 1, got {self.window}")
        check(self.burn_in >= 0, "burn_in", f"must be >= 0, got {self.burn_in}")
        check(self.epochs >= 1, "epochs", f"must be >= 1, got {self.epochs}")
        check_seed(self.seed)
        check(self.batch_size >= 1, "batch_size", f"must be >= 1, got {self.batch_size}")
        check(self.lr > 0, "lr", f"must be positive, got {self.lr}")
        check(self.weight_decay >= 0, "weight_decay", f"must be >= 0, got {self.weight_decay}")
        check(0 < self.lr_decay <= 1, "lr_decay", f"must be in (0, 1], got {self.lr_decay}")
        check(0 < self.train_fraction < 1, "train_fraction", f"must be in (0, 1), got {self.train_fraction}")
        check(self.max_frames >= 0, "max_frames", f"must be >= 0, got {self.max_frames}")
        check(all(isinstance(p, str) and p for p in self.extra_train), "extra_train",
              f"must be a list of dataset folders, got {self.extra_train!r}")
        check(1 <= self.threads <= MAX_THREADS, "threads", f"must be in 1..{MAX_THREADS}, got {self.threads}")
        check(self.eval_from_step >= 0, "eval_from_step", f"must be >= 0, got {self.eval_from_step}")
        check(self.model.out_dim == 6, "model.out_dim", f"ball positions are 6 values, got {self.model.out_dim}")
