"""Errors of a trained perception model, single-frame or temporal: on its test split, with dead
taxels, without a whole patch, split by whether the skin touches each ball, and against the
steps since a ball last touched the skin.

A temporal model reads each episode from its first frame with a fresh state, as in the env; a
single-frame model reads every frame alone.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import torch
from torch import Tensor, nn

from tacgnn.config import ConfigError, from_dict
from tacgnn.datasets.store import DatasetError, read_manifest
from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.perception.checkpoint import load_model
from tacgnn.perception.data import TactileData, load_tactile, split
from tacgnn.perception.models.temporal import TemporalPerception
from tacgnn.perception.objectives import Objective
from tacgnn.perception.sequences import (
    SequenceData,
    as_sequence,
    join_episodes,
    load_sequences,
    split_by_episode,
    steps_since_touch,
    touched,
)
from tacgnn.perception.train_config import PerceptionTrainConfig

TOUCH_WITHIN_CM = 3.0
"""A ball is touched when an activated taxel lies within this distance of its centre (radius 2.625 cm)."""


def frame_inputs(model: nn.Module, frames: TactileData, rows) -> tuple[Tensor, ...]:
    """A frame model's inputs for rows `rows`: (readings, positions[, joints if it reads them])."""
    inputs = (frames.readings[rows], frames.positions[rows])
    return (*inputs, frames.joints[rows]) if getattr(model, "joint_inputs", 0) and frames.joints is not None \
        else inputs


@torch.no_grad()
def predict_frames(model: nn.Module, frames: TactileData, batch: int = 1024) -> Tensor:
    """A frame model's outputs for every frame, in eval mode, `batch` frames at a time."""
    model.eval()
    if not len(frames):
        return torch.zeros(0, getattr(model, "out_dim", 6))
    return torch.cat([model(*frame_inputs(model, frames, slice(i, i + batch))) for i in range(0, len(frames), batch)])


@torch.no_grad()
def predict(model: nn.Module, data: SequenceData, episodes_per_batch: int = 32, frames_per_batch: int = 1024) -> Tensor:
    """(N, D) outputs for every frame of `data`; a temporal model reads each episode from its first
    frame with a fresh state, as in the env."""
    if not isinstance(model, TemporalPerception):
        return predict_frames(model, data.frames, frames_per_batch)
    model.eval()
    f = data.frames
    starts = data.run_starts().nonzero().squeeze(1)
    if len(starts) != len(data.episodes()):
        raise DatasetError("the frames of an episode are not consecutive steps (a dataset made with keep_every > 1?): "
                           "a temporal model needs every step")
    lengths = torch.diff(torch.cat([starts, torch.tensor([len(data)])]))
    out = torch.zeros(len(data), model.out_dim)
    mcfg = model.cfg
    for i in range(0, len(starts), episodes_per_batch):
        s, n = starts[i:i + episodes_per_batch], lengths[i:i + episodes_per_batch]
        offsets = torch.arange(int(n.max()))
        valid = offsets < n.unsqueeze(1)
        rows = torch.where(valid, s.unsqueeze(1) + offsets, s.unsqueeze(1))
        joints = f.joints[rows] if mcfg.joints and f.joints is not None else None
        pred, _ = model(f.readings[rows], f.positions[rows], joints,
                        data.actions[rows] if mcfg.actions else None, valid=valid)
        out[rows[valid]] = pred[valid]
    return out


def ball_errors(pred: Tensor, frames: TactileData, match_balls: bool = True,
                within_cm: float = TOUCH_WITHIN_CM) -> tuple[Tensor, Tensor, Tensor]:
    """Per frame and ball: squared position error (mean over x, y, z; cm^2) and touched; and per frame
    whether the balls' labels were swapped.

    With `match_balls` each frame's targets take the ball order nearer the prediction (the
    loss's permutation invariance), and the balls' flags follow their targets.
    """
    touch = touched(frames, within_cm)
    t = frames.targets
    swap = torch.zeros(len(t), dtype=torch.bool)
    if match_balls:
        swapped = t[:, [3, 4, 5, 0, 1, 2]]
        swap = ((pred - swapped) ** 2).sum(1) < ((pred - t) ** 2).sum(1)
        t = torch.where(swap[:, None], swapped, t)
        touch = torch.where(swap[:, None], touch.flip(1), touch)
    return ((pred - t) ** 2).view(-1, 2, 3).mean(2), touch, swap


def ball_errors_since_touch(pred: Tensor, data: SequenceData,
                            match_balls: bool = True) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`ball_errors` (squared error, touched) and per frame and ball the steps since it last
    touched the skin, the balls' flags following their matched targets."""
    se, touch, swap = ball_errors(pred, data.frames, match_balls)
    since = steps_since_touch(data, touched(data.frames, TOUCH_WITHIN_CM))
    return se, touch, torch.where(swap[:, None], since.flip(1), since)


def _rmse(se: Tensor) -> float:
    return float(se.mean().sqrt()) if se.numel() else float("nan")


def scored(cfg: PerceptionTrainConfig, data: SequenceData) -> Tensor:
    """(N,) bool: the frames errors count (by episode, from ``eval_from_step`` on; by frame, all)."""
    return data.step >= cfg.eval_from_step if cfg.split == "episode" else torch.ones(len(data), dtype=torch.bool)


def metrics(pred: Tensor, cfg: PerceptionTrainConfig, data: SequenceData) -> dict[str, float]:
    """The task's errors of predictions `pred` (N, D) of `data`'s scored frames; Baoding adds the
    position RMSE (cm) of touched and of untouched balls (resting on the other ball or on a part of
    the hand without skin: only indirect cues place them) and the untouched share."""
    keep = scored(cfg, data)
    if not keep.all():
        pred, data = pred[keep], data.subset(keep.nonzero().squeeze(1))
    out = Objective(cfg.task, cfg.match_balls).metrics(pred, data.frames.targets)
    if cfg.task == "baoding":
        se, touch, _ = ball_errors(pred, data.frames, cfg.match_balls)
        out.update({"touched_rmse_cm": _rmse(se[touch]), "untouched_rmse_cm": _rmse(se[~touch]),
                    "untouched_fraction": float((~touch).float().mean()) if touch.numel() else float("nan")})
    return out


def model_metrics(model: nn.Module, cfg: PerceptionTrainConfig, data: SequenceData) -> dict[str, float]:
    return metrics(predict(model, data), cfg, data)


def load_data(cfg: PerceptionTrainConfig, dataset: str | Path, max_samples: int) -> SequenceData:
    """A dataset as the config's split reads it: frames of any task, or Baoding episodes (with the
    episodes of the config's `mix` datasets joined after them)."""
    if cfg.split == "episode":
        main = load_sequences(dataset, max_samples)
        parts = [main, *(load_sequences(path) for path in cfg.mix)]
        for path, part in zip(cfg.mix, parts[1:], strict=True):
            if part.frames.readings.shape[1] != main.frames.readings.shape[1]:
                raise DatasetError(f"{path} (mix): has {part.frames.readings.shape[1]} taxels, "
                                   f"{dataset} {main.frames.readings.shape[1]}")
        return join_episodes(parts) if cfg.mix else main
    joints = cfg.model.joint_inputs > 0
    return as_sequence(load_tactile(dataset, cfg.task, max_samples, joints=joints))


def split_data(cfg: PerceptionTrainConfig,
               data: SequenceData) -> tuple[SequenceData, SequenceData | None, SequenceData]:
    """(train, validation or None, test) by the config's split and seed. The test split does not
    depend on `val_fraction`: validation is drawn from the training side."""
    divide = split_by_episode if cfg.split == "episode" else split
    rest, test = divide(data, cfg.train_fraction, cfg.seed)
    if cfg.val_fraction == 0:
        return rest, None, test
    train, val = divide(rest, 1 - cfg.val_fraction, cfg.seed + 1)
    return train, val, test


def test_data(cfg: PerceptionTrainConfig, dataset: str | Path, whole: bool = False) -> SequenceData:
    """The frames a training run never saw: its test split (same max_samples; the `mix` datasets'
    test episodes too), or all frames of `dataset` alone."""
    data = load_data(replace(cfg, mix=()) if whole else cfg, dataset, 0 if whole else cfg.max_samples)
    if data.frames.readings.shape[1] != cfg.model.num_taxels:
        raise DatasetError(f"{dataset}: has {data.frames.readings.shape[1]} taxels, the model was trained on "
                           f"{cfg.model.num_taxels}")
    return data if whole else split_data(cfg, data)[2]


def patch_taxels(skin: SkinLayout | dict, patch: str) -> Tensor:
    """Indices of one patch's taxels in the skin vector (e.g. ``"palm"``)."""
    if not isinstance(skin, SkinLayout):
        skin = from_dict(SkinLayout, skin)
    names = [p.name for p in skin.patches]
    if patch not in names:
        raise ConfigError(f"no skin patch named {patch!r}; the skin has {', '.join(names)}")
    i = names.index(patch)
    start, stop = skin.offsets()[i:i + 2]
    return torch.arange(int(start), int(stop))


def dead_taxels(num_taxels: int, fraction: float, seed: int) -> Tensor:
    """A seeded random ``round(fraction * T)`` of the taxels, as a broken skin would lose them."""
    if not 0.0 <= fraction <= 1.0:
        raise ConfigError(f"the dead taxel fraction must be in [0, 1], got {fraction}")
    gen = torch.Generator().manual_seed(seed)
    return torch.randperm(num_taxels, generator=gen)[:int(round(fraction * num_taxels))]


def without_taxels(data: SequenceData, taxels: Tensor) -> SequenceData:
    """The frames with these taxels reading 0 in every frame."""
    readings = data.frames.readings.clone()
    readings[:, taxels] = 0.0
    return data.with_frames(data.frames.with_readings(readings))


def evaluate(checkpoint: str | Path, dataset: str | Path, dead_fraction: float = 0.0, seed: int = 0,
             whole: bool = False, lost_patch: str | None = None) -> dict[str, float]:
    """Errors of a trained model on a dataset's test split (or all of it with `whole`).

    `dead_fraction` zeroes that share of the taxels (the same ones in every frame), as a
    real skin with broken taxels would read; `lost_patch` zeroes every taxel of one patch
    of the dataset's skin (e.g. "palm").
    """
    model, cfg, _ = load_model(checkpoint)
    test = test_data(cfg, dataset, whole)
    if dead_fraction > 0:
        test = without_taxels(test, dead_taxels(test.frames.readings.shape[1], dead_fraction, seed))
    if lost_patch is not None:
        test = without_taxels(test, patch_taxels(read_manifest(dataset)["metadata"]["skin"], lost_patch))
    torch.set_num_threads(cfg.threads)
    return model_metrics(model, cfg, test)


def patch_loss(checkpoint: str | Path, dataset: str | Path, patch: str, whole: bool = False) -> dict[str, float]:
    """Errors with and without one whole patch of the skin, and their ratio.

    Returns the intact metrics, the same metrics with every taxel of `patch` reading 0
    (keys suffixed ``_without_<patch>``), and ``rmse_ratio`` = position RMSE without the
    patch / intact position RMSE.
    """
    model, cfg, _ = load_model(checkpoint)
    test = test_data(cfg, dataset, whole)
    lost = without_taxels(test, patch_taxels(read_manifest(dataset)["metadata"]["skin"], patch))
    torch.set_num_threads(cfg.threads)
    intact, without = model_metrics(model, cfg, test), model_metrics(model, cfg, lost)
    before, after = intact["position_rmse_cm"], without["position_rmse_cm"]
    return {**intact, **{f"{k}_without_{patch}": v for k, v in without.items()},
            "rmse_ratio": after / before if before > 0 else float("nan")}


def error_by_steps_since_touch(checkpoint: str | Path, dataset: str | Path, bins: list[int],
                               whole: bool = False) -> dict[str, list[int] | list[float]]:
    """Ball position RMSE (cm) by steps since the ball last touched the skin (see :func:`since_touch_curve`)."""
    model, cfg, _ = load_model(checkpoint)
    if cfg.split != "episode":
        raise ConfigError(f"{checkpoint}: trained on a split by frame; steps since a touch need episodes")
    torch.set_num_threads(cfg.threads)
    data = test_data(cfg, dataset, whole)
    return since_touch_curve(predict(model, data), cfg, data, bins)


def since_touch_curve(pred: Tensor, cfg: PerceptionTrainConfig, data: SequenceData,
                      bins: list[int]) -> dict[str, list[int] | list[float]]:
    """RMSE (cm) of predictions `pred` (N, 6) by steps since the ball last touched the skin.

    `bins` are the lower edges (e.g. [0, 1, 2, 4, 8, 16, 32]); bin i holds balls with
    bins[i] <= steps < bins[i + 1] (the last bin is open). Returns the edges, RMSE and count
    per bin, over frames from the run's ``eval_from_step`` on.
    """
    se, _, since = ball_errors_since_touch(pred, data, cfg.match_balls)
    keep = scored(cfg, data)
    se, since = se[keep].reshape(-1), since[keep].reshape(-1)
    uppers: list[int | None] = [*bins[1:], None]
    rmse, count = [], []
    for lo, hi in zip(bins, uppers):
        sel = (since >= lo) & (since < hi if hi is not None else torch.ones_like(since, dtype=torch.bool))
        rmse.append(_rmse(se[sel]))
        count.append(int(sel.sum()))
    return {"bins": list(bins), "rmse_cm": rmse, "count": count}
