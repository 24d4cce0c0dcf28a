"""Training a perception model on sequences: windows of consecutive frames, truncated BPTT.

One step of a temporal model, for `batch_size` windows drawn from the training episodes:

    burn-in   the `burn_in` frames before each window, without gradient: the state the
              model would carry into the window (fresh where the episode starts inside)
    window    `window` frames with gradient from that (detached) state; the loss is the
              mean over all frames of the permutation-invariant ball MSE

The episodes of `extra_train` datasets join the training episodes after the split, so the
test episodes stay the main dataset's.

A run folder holds `checkpoint.pt` (after every epoch, atomically; kind "sequence", see
:mod:`tacgnn.perception.sequence_checkpoint`) and `history.json`. The windows of epoch e
are drawn from seed + e, so a resumed run (with as many or more epochs) equals an uninterrupted one.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path

import torch
from torch import Tensor, nn

from tacgnn.config import to_dict
from tacgnn.datasets.store import DatasetError, read_manifest
from tacgnn.files import atomic_write_text
from tacgnn.perception.checkpoint import CHECKPOINT_VERSION, CheckpointError, save_checkpoint
from tacgnn.perception.models.temporal import TemporalPerception
from tacgnn.perception.objectives import Objective
from tacgnn.perception.sequence_checkpoint import KIND, build_sequence_model, load_sequence_checkpoint
from tacgnn.perception.sequence_evaluation import sequence_metrics
from tacgnn.perception.sequence_train_config import SequenceTrainConfig
from tacgnn.perception.sequences import (
    SequenceData,
    burn_in_rows,
    check_windows,
    join_episodes,
    load_sequences,
    split_by_episode,
    window_starts,
)
from tacgnn.perception.training import backward_checked, make_optimizer


def init_output_bias(model: nn.Module, mean: Tensor) -> None:
    """Start a model's output at the mean label: the temporal model's own way, else the last layer's bias."""
    if isinstance(model, TemporalPerception):
        model.init_output(mean)
        return
    last = [m for m in model.modules() if isinstance(m, nn.Linear)][-1]
    with torch.no_grad():
        last.bias.copy_(mean)


def window_inputs(data: SequenceData, rows: Tensor,
                  model: nn.Module) -> tuple[Tensor, Tensor, Tensor | None, Tensor | None]:
    """(readings, positions, joints, actions) of window rows (B, L), as the temporal model reads them."""
    assert isinstance(model, TemporalPerception)
    cfg = model.cfg
    f = data.frames
    return (f.readings[rows], f.positions[rows], f.joints[rows] if cfg.joints and f.joints is not None else None,
            data.actions[rows] if cfg.actions else None)


def window_loss(model: nn.Module, data: SequenceData, starts: Tensor, cfg: SequenceTrainConfig,
                objective: Objective) -> Tensor:
    """The loss of windows starting at rows `starts`, the state warmed up over their burn-in."""
    rows = starts.unsqueeze(1) + torch.arange(cfg.window)
    check_windows(data, rows)
    state = None
    if cfg.burn_in:
        burn, valid = burn_in_rows(data, starts, cfg.burn_in)
        with torch.no_grad():
            _, state = model(*window_inputs(data, burn, model), valid=valid)
    out, _ = model(*window_inputs(data, rows, model), state=state)
    return objective.loss(out.reshape(-1, out.shape[-1]), data.frames.targets[rows].reshape(-1, out.shape[-1]))


def frame_loss(model: nn.Module, data: SequenceData, rows: Tensor, objective: Objective) -> Tensor:
    return objective.loss(model(data.frames.readings[rows], data.frames.positions[rows]), data.frames.targets[rows])


def load_extra(path: str, cfg: SequenceTrainConfig) -> SequenceData:
    """An `extra_train` dataset (every frame), checked against the model's taxels."""
    data = load_sequences(path)
    if data.frames.readings.shape[1] != cfg.model.frame.num_taxels:
        raise DatasetError(f"{path} (extra_train): has {data.frames.readings.shape[1]} taxels, "
                           f"model.frame.num_taxels is {cfg.model.frame.num_taxels}")
    return data


def train_sequence(cfg: SequenceTrainConfig, dataset: str | Path, run_dir: str | Path, resume: bool = False,
                   log: Callable[[str], object] = print) -> dict:
    """Train on `dataset` (episode and step indices needed); return the last epoch's metrics."""
    torch.set_num_threads(cfg.threads)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    ckpt_path = run_dir / "checkpoint.pt"
    meta = read_manifest(dataset)["metadata"]
    data = load_sequences(dataset, cfg.max_frames)
    if data.frames.readings.shape[1] != cfg.model.frame.num_taxels:
        raise DatasetError(f"{dataset}: has {data.frames.readings.shape[1]} taxels, model.frame.num_taxels is "
                           f"{cfg.model.frame.num_taxels}")
    train_set, test_set = split_by_episode(data, cfg.train_fraction, cfg.seed)
    extra = [load_extra(path, cfg) for path in cfg.extra_train]
    if extra:
        train_set = join_episodes([train_set, *extra])
        log(f"training episodes: {len(train_set.episodes())} ({sum(len(e.episodes()) for e in extra)} from "
            f"{', '.join(cfg.extra_train)}, {sum(len(e) for e in extra)} frames)")
    starts = window_starts(train_set, cfg.window) if cfg.temporal else torch.arange(len(train_set))
    objective = Objective("baoding", cfg.match_balls)

    torch.manual_seed(cfg.seed)
    model = build_sequence_model(cfg)
    init_output_bias(model, train_set.frames.targets.mean(0))  # the labels are ~4 cm from 0: start there
    optim = make_optimizer(model, cfg.lr, cfg.weight_decay)
    history: list[dict] = []
    start_epoch = 0
    if resume and ckpt_path.exists():
        payload = load_sequence_checkpoint(ckpt_path)
        # more epochs continue the run (the learning rate's decay does not depend on their number)
        diff = [k for k in payload["config"] if k != "epochs" and payload["config"][k] != to_dict(cfg).get(k)]
        if diff:
            raise CheckpointError(f"{ckpt_path}: was trained with another config (differs in {diff})")
        model.load_state_dict(payload["model"])
        optim.load_state_dict(payload["optimizer"])
        history, start_epoch = payload["history"], payload["epoch"] + 1
        log(f"resumed from {ckpt_path} after epoch {payload['epoch']}")

    per_step = cfg.batch_size * (cfg.window if cfg.temporal else 1)  # frames in the loss per step
    steps_per_epoch = max(1, math.ceil(len(train_set) / per_step))
    if cfg.temporal:
        log(f"{len(train_set)} training frames in {len(train_set.episodes())} episodes, {len(starts)} window "
            f"starts; {steps_per_epoch} steps of {cfg.batch_size} windows x {cfg.window} frames per epoch")
    for epoch in range(start_epoch, cfg.epochs):
        model.train()
        begin = time.perf_counter()
        gen = torch.Generator().manual_seed(cfg.seed * 1000 + epoch)
        # as many loss frames as training frames: starts drawn without replacement, repeated if too few
        draws = steps_per_epoch * cfg.batch_size
        order = torch.cat([torch.randperm(len(starts), generator=gen) for _ in range(-(-draws // len(starts)))])
        chosen = starts[order[:draws]]
        total = 0.0
        for b in range(steps_per_epoch):
            batch = chosen[b * cfg.batch_size:(b + 1) * cfg.batch_size]
            loss = (window_loss(model, train_set, batch, cfg, objective) if cfg.temporal
                    else frame_loss(model, train_set, batch, objective))
            backward_checked(optim, loss, f"at epoch {epoch}, step {b} of {run_dir}")
            lr = cfg.lr * cfg.lr_decay ** ((epoch * steps_per_epoch + b) / steps_per_epoch)
            for group in optim.param_groups:
                group["lr"] = lr
            optim.step()
            total += loss.item()
        seconds = time.perf_counter() - begin
        test_m = sequence_metrics(model, cfg, test_set)
        row = {"epoch": epoch, "loss": total / steps_per_epoch, "seconds": seconds, "lr": optim.param_groups[0]["lr"],
               **{f"test/{k}": v for k, v in test_m.items()}}
        history.append(row)
        log(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()))
        save_checkpoint(ckpt_path, {
            "format_version": CHECKPOINT_VERSION, "kind": KIND, "config": to_dict(cfg), "epoch": epoch,
            "model": model.state_dict(), "optimizer": optim.state_dict(), "history": history,
            "dataset": {"path": str(dataset), "num_taxels": cfg.model.frame.num_taxels, "kind": meta.get("kind"),
                        "frames": len(data), "episodes": len(data.episodes()),
                        "extra_train_frames": sum(len(e) for e in extra)},
        })
        atomic_write_text(run_dir / "history.json", json.dumps(history, indent=1))
    return history[-1]
