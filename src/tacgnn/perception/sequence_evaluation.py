"""Errors of sequence-trained perception models: whole test episodes, touched and untouched balls,
and the error against the steps since a ball last touched the skin."""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor, nn

from tacgnn.datasets.store import DatasetError
from tacgnn.perception.models.temporal import TemporalPerception
from tacgnn.perception.objectives import Objective
from tacgnn.perception.sequence_checkpoint import load_sequence_model
from tacgnn.perception.sequence_train_config import SequenceTrainConfig
from tacgnn.perception.sequences import SequenceData, load_sequences, split_by_episode, steps_since_touch, touched

TOUCH_WITHIN_CM = 3.0
"""A ball is touched when an activated taxel lies within this distance of its centre (radius 2.625 cm)."""


@torch.no_grad()
def sequence_predictions(model: nn.Module, cfg: SequenceTrainConfig, data: SequenceData,
                         episodes_per_batch: int = 32, frames_per_batch: int = 1024) -> Tensor:
    """(N, 6) outputs for every frame; a temporal model reads each episode from its first frame
    with a fresh state, as in the env."""
    model.eval()
    f = data.frames
    if not cfg.temporal:
        return torch.cat([model(f.readings[i:i + frames_per_batch], f.positions[i:i + frames_per_batch])
                          for i in range(0, len(data), frames_per_batch)]) if len(data) else torch.zeros(0, 6)
    first = data.run_starts()
    starts = first.nonzero().squeeze(1)
    if len(starts) != len(data.episodes()):
        raise DatasetError("the frames of an episode are not consecutive steps (a dataset made with keep_every > 1?): "
                           "a temporal model needs every step")
    lengths = torch.diff(torch.cat([starts, torch.tensor([len(data)])]))
    out = torch.zeros(len(data), cfg.model.out_dim)
    assert isinstance(model, TemporalPerception)
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


def matched_ball_errors(pred: Tensor, data: SequenceData, match_balls: bool = True,
                        within_cm: float = TOUCH_WITHIN_CM) -> tuple[Tensor, Tensor, Tensor]:
    """Per frame and ball: squared position error (mean over x, y, z; cm^2), touched, steps since touch.

    With `match_balls` each frame's targets take the ball order nearer the prediction (the
    loss's permutation invariance), and the balls' flags follow their targets.
    """
    touch = touched(data.frames, within_cm)
    since = steps_since_touch(data, touch)
    t = data.frames.targets
    if match_balls:
        swapped = t[:, [3, 4, 5, 0, 1, 2]]
        use = ((pred - swapped) ** 2).sum(1) < ((pred - t) ** 2).sum(1)
        t = torch.where(use[:, None], swapped, t)
        touch = torch.where(use[:, None], touch.flip(1), touch)
        since = torch.where(use[:, None], since.flip(1), since)
    se = ((pred - t) ** 2).view(-1, 2, 3).mean(2)
    return se, touch, since


def _rmse(se: Tensor) -> float:
    return float(se.mean().sqrt()) if se.numel() else float("nan")


def sequence_metrics(model: nn.Module, cfg: SequenceTrainConfig, data: SequenceData) -> dict[str, float]:
    """Position RMSE (cm) over the frames from ``cfg.eval_from_step`` on: all, touched and untouched balls."""
    return prediction_metrics(sequence_predictions(model, cfg, data), cfg, data)


def prediction_metrics(pred: Tensor, cfg: SequenceTrainConfig, data: SequenceData) -> dict[str, float]:
    """The metrics of :func:`sequence_metrics` from predictions `pred` (N, 6) of `data`'s frames."""
    keep = data.step >= cfg.eval_from_step
    se, touch, _ = matched_ball_errors(pred, data, cfg.match_balls)
    se, touch = se[keep], touch[keep]
    overall = Objective("baoding", cfg.match_balls).metrics(pred[keep], data.frames.targets[keep])
    return {**overall, "touched_rmse_cm": _rmse(se[touch]), "untouched_rmse_cm": _rmse(se[~touch]),
            "untouched_fraction": float((~touch).float().mean()) if touch.numel() else float("nan")}


def test_split(cfg: SequenceTrainConfig, dataset: str | Path) -> SequenceData:
    """The episodes a training run never saw (its split, same max_frames)."""
    data = load_sequences(dataset, cfg.max_frames)
    return split_by_episode(data, cfg.train_fraction, cfg.seed)[1]


def evaluate_sequence(checkpoint: str | Path, dataset: str | Path, whole: bool = False) -> dict[str, float]:
    """Errors of a sequence checkpoint on its test episodes (all episodes with `whole`)."""
    model, cfg, _ = load_sequence_model(checkpoint)
    torch.set_num_threads(cfg.threads)
    data = load_sequences(dataset) if whole else test_split(cfg, dataset)
    if data.frames.readings.shape[1] != cfg.model.frame.num_taxels:
        raise DatasetError(f"{dataset}: has {data.frames.readings.shape[1]} taxels, the model was trained on "
                           f"{cfg.model.frame.num_taxels}")
    return sequence_metrics(model, cfg, data)


def error_by_steps_since_touch(checkpoint: str | Path, dataset: str | Path, bins: list[int],
                               whole: bool = False) -> dict[str, list[int] | list[float]]:
    """Ball position RMSE (cm) by steps since the ball last touched the skin (see :func:`since_touch_curve`)."""
    model, cfg, _ = load_sequence_model(checkpoint)
    torch.set_num_threads(cfg.threads)
    data = load_sequences(dataset) if whole else test_split(cfg, dataset)
    return since_touch_curve(sequence_predictions(model, cfg, data), cfg, data, bins)


def since_touch_curve(pred: Tensor, cfg: SequenceTrainConfig, data: SequenceData,
                      bins: list[int]) -> dict[str, list[int] | list[float]]:
    """RMSE (cm) of predictions `pred` (N, 6) by steps since the ball last touched the skin.

    `bins` are the lower edges (e.g. [0, 1, 2, 4, 8, 16, 32]); bin i holds balls with
    bins[i] <= steps < bins[i + 1] (the last bin is open). Returns the edges, RMSE and count
    per bin, over frames from the run's ``eval_from_step`` on.
    """
    se, _, since = matched_ball_errors(pred, data, cfg.match_balls)
    keep = data.step >= cfg.eval_from_step
    se, since = se[keep].reshape(-1), since[keep].reshape(-1)
    uppers: list[int | None] = [*bins[1:], None]
    rmse, count = [], []
    for lo, hi in zip(bins, uppers):
        sel = (since >= lo) & (since < hi if hi is not None else torch.ones_like(since, dtype=torch.bool))
        rmse.append(_rmse(se[sel]))
        count.append(int(sel.sum()))
    return {"bins": list(bins), "rmse_cm": rmse, "count": count}
