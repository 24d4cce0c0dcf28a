"""The offline training loop of every perception model (``tacgnn train-perception``).

One step, for `batch_size` windows of `window` consecutive frames drawn from the training
episodes (a single-frame model: windows of one frame):

    burn-in   a temporal model: the `burn_in` frames before each window, without gradient:
              the state the model would carry into the window (fresh where the episode
              starts inside)
    window    the frames with gradient from that (detached) state; the loss is the mean over
              all frames of the task's loss (for the balls, permutation-invariant per frame)

A run folder holds `checkpoint.pt` (written atomically after every epoch, see
:mod:`tacgnn.perception.checkpoint`), `history.json` (per-epoch metrics) and TensorBoard
events. ``resume=True`` continues from the checkpoint; the windows of epoch e are drawn from
seed + e, so a resumed run (with as many or, with a schedule that does not depend on the
number of epochs, more epochs) equals an uninterrupted one.
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
from tacgnn.files import atomic_write_text, read_weights
from tacgnn.perception.checkpoint import (
    CheckpointError,
    build_perception,
    load_checkpoint,
    network_differences,
    save_checkpoint,
    with_taxels,
)
from tacgnn.perception.evaluation import frame_inputs, load_data, model_metrics, split_data
from tacgnn.perception.models.temporal import TemporalPerception
from tacgnn.perception.objectives import Objective
from tacgnn.perception.rest_positions import rest_positions_cm as skin_rest_positions_cm
from tacgnn.perception.sequences import SequenceData, burn_in_rows, check_windows, join_episodes, load_sequences
from tacgnn.perception.sequences import window_starts as sequence_window_starts
from tacgnn.perception.train_config import PerceptionTrainConfig


def lr_factor(cfg: PerceptionTrainConfig, step: int, total_steps: int, steps_per_epoch: int) -> float:
    """Learning rate of optimiser step `step` (0-based) of `total_steps`, as a fraction of cfg.lr."""
    t = step / max(1, total_steps)
    if cfg.lr_schedule == "cosine":
        f = cfg.lr_final + (1 - cfg.lr_final) * 0.5 * (1 + math.cos(math.pi * t))
    elif cfg.lr_schedule == "exp":  # does not depend on the run's length: a longer run extends it
        f = cfg.lr_decay ** (step / steps_per_epoch)
    elif cfg.lr_schedule == "step":
        f = 1.0 if t < 0.5 else 0.1 if t < 0.75 else 0.01
    else:
        f = 1.0
    warm = cfg.warmup_epochs * steps_per_epoch
    return f * min(1.0, (step + 1) / warm) if warm > 0 else f


def backward_checked(optim: torch.optim.Optimizer, loss: Tensor, where: str) -> None:
    """Fill the gradients of `loss`, or raise before the optimiser can step on NaN or Inf.

    A finite loss can still give an infinite gradient (an overflow in a layer); one such
    step would write NaN into every weight. Raising here leaves the weights as they were
    after the last good step, and the last checkpoint on disk intact.
    """
    if not torch.isfinite(loss):
        raise FloatingPointError(f"non-finite loss ({float(loss.detach())}) {where}; weights left unchanged")
    optim.zero_grad(set_to_none=True)
    loss.backward()
    grads = [p.grad for group in optim.param_groups for p in group["params"] if p.grad is not None]
    if grads and not torch.isfinite(torch.nn.utils.get_total_norm(grads)):
        raise FloatingPointError(f"non-finite gradient {where}; weights left unchanged")


def make_optimizer(model: nn.Module, lr: float, weight_decay: float) -> torch.optim.Adam:
    """Adam; the fused kernel where this torch has it (~5x faster steps on CPU, same algorithm)."""
    try:
        return torch.optim.Adam(model.parameters(), lr=lr, weight_decay=weight_decay, fused=True)
    except (RuntimeError, TypeError, ValueError):
        return torch.optim.Adam(model.parameters(), lr=lr, weight_decay=weight_decay)


def init_output_bias(model: nn.Module, mean: Tensor) -> None:
    """Start a model's output at the mean label: the temporal model's own way, else the last layer's bias."""
    if isinstance(model, TemporalPerception):
        model.init_output(mean)
        return
    last = [m for m in model.modules() if isinstance(m, nn.Linear)][-1]
    with torch.no_grad():
        last.bias.copy_(mean)


def window_loss(model: nn.Module, data: SequenceData, starts: Tensor, window: int, burn_in: int,
                objective: Objective) -> Tensor:
    """The loss of windows of `window` frames starting at rows `starts`; a temporal model's state is
    warmed up over their `burn_in` earlier frames, a frame model reads each frame alone."""
    if not isinstance(model, TemporalPerception):
        rows = starts if window == 1 else (starts.unsqueeze(1) + torch.arange(window)).reshape(-1)
        return objective.loss(model(*frame_inputs(model, data.frames, rows)), data.frames.targets[rows])
    rows = starts.unsqueeze(1) + torch.arange(window)
    check_windows(data, rows)
    state = None
    if burn_in:
        burn, valid = burn_in_rows(data, starts, burn_in)
        with torch.no_grad():
            _, state = model(*window_inputs(data, burn, model), valid=valid)
    out, _ = model(*window_inputs(data, rows, model), state=state)
    return objective.loss(out.reshape(-1, out.shape[-1]), data.frames.targets[rows].reshape(-1, out.shape[-1]))


def window_inputs(data: SequenceData, rows: Tensor,
                  model: TemporalPerception) -> tuple[Tensor, Tensor, Tensor | None, Tensor | None]:
    """(readings, positions, joints, actions) of window rows (B, L), as the temporal model reads them."""
    cfg, f = model.cfg, data.frames
    return (f.readings[rows], f.positions[rows], f.joints[rows] if cfg.joints and f.joints is not None else None,
            data.actions[rows] if cfg.actions else None)


def window_starts(data: SequenceData, window: int) -> Tensor:
    """Rows where a window can start (every row for a window of one)."""
    return torch.arange(len(data)) if window == 1 else sequence_window_starts(data, window)


def epoch_order(starts: Tensor, draws: int, gen: torch.Generator) -> Tensor:
    """`draws` window starts: permutations of `starts` one after another, cut to `draws`."""
    return starts[torch.cat([torch.randperm(len(starts), generator=gen) for _ in range(-(-draws // len(starts)))])
                  [:draws]]


def load_extra(path: str, num_taxels: int) -> SequenceData:
    """An `extra_train` dataset (every frame), checked against the model's taxels."""
    data = load_sequences(path)
    if data.frames.readings.shape[1] != num_taxels:
        raise DatasetError(f"{path} (extra_train): has {data.frames.readings.shape[1]} taxels, "
                           f"the training dataset {num_taxels}")
    return data


def start_from(model: torch.nn.Module, cfg: PerceptionTrainConfig, path: str) -> None:
    """Load the weights of `path` into `model`, refusing another network: a perception checkpoint,
    or a blind policy file (the perception it acts with, as its training in the loop left it)."""
    raw = read_weights(Path(path), "perception checkpoint or blind policy")
    if isinstance(raw, dict) and "actor_state_dict" in raw:  # a policy file (`tacgnn.learning.checkpoint`)
        if "perception" not in raw:
            raise CheckpointError(f"init_from {path}: a policy trained without a perception")
        stored, weights = raw["perception"]["config"], raw["perception"]["model"]
    else:
        payload = load_checkpoint(path)
        stored, weights = payload["config"], payload["model"]
    diff = network_differences(stored, to_dict(cfg))
    if diff:
        raise CheckpointError(f"init_from {path}: its network differs in {diff}")
    model.load_state_dict(weights)


def train(cfg: PerceptionTrainConfig, dataset: str | Path, run_dir: str | Path, resume: bool = False,
          log: Callable[[str], object] = print, rest_positions_cm: Tensor | None = None,
          init_from: str | Path | None = None) -> dict:
    """Train on `dataset`; return the last epoch's metrics (train with a split by frame, and test).

    The GCN's rest taxel positions (cm) are `rest_positions_cm` if given, else those of the
    dataset's skin on the hand at zero joint angles. `init_from`: a perception checkpoint of the
    same network whose weights start the run (fine-tuning a model on more data); the checkpoints
    name it. Not a config key, so checkpoints written before it existed still read.
    """
    from torch.utils.tensorboard import SummaryWriter

    torch.set_num_threads(cfg.threads)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    ckpt_path = run_dir / "checkpoint.pt"
    meta = read_manifest(dataset)["metadata"]
    data = load_data(cfg, dataset, cfg.max_samples)
    num_taxels = data.frames.readings.shape[1]
    cfg = with_taxels(cfg, num_taxels)
    train_set, val_set, test_set = split_data(cfg, data)
    extra = [load_extra(path, num_taxels) for path in cfg.extra_train]
    if extra:
        train_set = join_episodes([train_set, *extra])
        log(f"training episodes: {len(train_set.episodes())} ({sum(len(e.episodes()) for e in extra)} from "
            f"{', '.join(cfg.extra_train)}, {sum(len(e) for e in extra)} frames)")
    starts = window_starts(train_set, cfg.window)
    objective = Objective(cfg.task, cfg.match_balls)
    rest = None
    if cfg.model.name == "gcn" and not cfg.temporal:
        rest = rest_positions_cm if rest_positions_cm is not None else skin_rest_positions_cm(meta["skin"])

    torch.manual_seed(cfg.seed)
    model = build_perception(cfg.model, cfg.temporal, cfg.memory, rest)
    resuming = resume and ckpt_path.exists()
    started_from = str(init_from or "")
    if init_from:
        if not resuming:  # a resumed run's weights come from its own checkpoint
            start_from(model, cfg, started_from)
    elif cfg.init_output_bias:
        init_output_bias(model, train_set.frames.targets.mean(0))
    optim = make_optimizer(model, cfg.lr, cfg.weight_decay)
    history: list[dict] = []
    start_epoch = 0
    if resuming:
        payload = load_checkpoint(ckpt_path)
        started_from = payload.get("init_from", started_from)
        # more epochs continue the run where the learning rate does not depend on their number
        free = ("epochs",) if cfg.lr_schedule in ("exp", "constant") else ()
        diff = [k for k in payload["config"] if k not in free and payload["config"][k] != to_dict(cfg).get(k)]
        if diff:
            raise CheckpointError(f"{ckpt_path}: was trained with another config (differs in {diff})")
        model.load_state_dict(payload["model"])
        optim.load_state_dict(payload["optimizer"])
        history, start_epoch = payload["history"], payload["epoch"] + 1
        log(f"resumed from {ckpt_path} after epoch {payload['epoch']}")

    writer = SummaryWriter(run_dir)
    steps_per_epoch = max(1, math.ceil(len(train_set) / (cfg.batch_size * cfg.window)))
    # by frame, every frame once (the last batch partial); by episode, full batches of windows
    draws = len(starts) if cfg.split == "frame" else steps_per_epoch * cfg.batch_size
    if cfg.window > 1:
        log(f"{len(train_set)} training frames in {len(train_set.episodes())} episodes, {len(starts)} window "
            f"starts; {steps_per_epoch} steps of {cfg.batch_size} windows x {cfg.window} frames per epoch")
    for epoch in range(start_epoch, cfg.epochs):
        model.train()
        begin = time.perf_counter()
        chosen = epoch_order(starts, draws, torch.Generator().manual_seed(cfg.seed * 1000 + epoch))
        total = 0.0
        for b in range(steps_per_epoch):
            batch = chosen[b * cfg.batch_size:(b + 1) * cfg.batch_size]
            loss = window_loss(model, train_set, batch, cfg.window, cfg.burn_in, objective)
            backward_checked(optim, loss, f"at epoch {epoch}, batch {b} of {run_dir}")
            lr = cfg.lr * lr_factor(cfg, epoch * steps_per_epoch + b, cfg.epochs * steps_per_epoch, steps_per_epoch)
            for group in optim.param_groups:
                group["lr"] = lr
            optim.step()
            total += loss.item()
        seconds = time.perf_counter() - begin
        train_m = model_metrics(model, cfg, train_set) if cfg.split == "frame" else {}
        # with a validation split the test split waits for the end; without one it is scored every epoch
        held = ("val", model_metrics(model, cfg, val_set)) if val_set is not None else \
            ("test", model_metrics(model, cfg, test_set))
        row = {"epoch": epoch, "loss": total / steps_per_epoch, "seconds": seconds, "lr": optim.param_groups[0]["lr"],
               **{f"train/{k}": v for k, v in train_m.items()}, **{f"{held[0]}/{k}": v for k, v in held[1].items()}}
        history.append(row)
        for key, value in row.items():
            if key != "epoch":
                writer.add_scalar(key if "/" in key else f"train/{key}", value, epoch)
        log(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()))
        payload = {
            "config": to_dict(cfg), "epoch": epoch, "model": model.state_dict(), "optimizer": optim.state_dict(),
            "history": history, "rest_positions_cm": rest, "init_from": started_from,
            "dataset": {"path": str(dataset), "num_taxels": num_taxels, "kind": meta.get("kind"),
                        "object": meta.get("object"), "frames": len(data), "split": cfg.split,
                        "extra_train_frames": sum(len(e) for e in extra)},
        }
        if val_set is not None and epoch == best_epoch(history):
            save_checkpoint(run_dir / "best.pt", payload)  # before checkpoint.pt: a resume never misses it
        save_checkpoint(ckpt_path, payload)
        atomic_write_text(run_dir / "history.json", json.dumps(history, indent=1))
    writer.close()
    if val_set is None:
        return history[-1]
    return score_best(run_dir, cfg, model, test_set)


#: The validation figure that picks the best epoch, per task.
SELECT_BY = "val/position_rmse_cm"


def best_epoch(history: list[dict]) -> int:
    """The epoch with the lowest validation error (the first of equals)."""
    return min(history, key=lambda row: (row[SELECT_BY], row["epoch"]))["epoch"]


def score_best(run_dir: Path, cfg: PerceptionTrainConfig, model: nn.Module, test_set: SequenceData) -> dict:
    """Score the validation-chosen epoch (``best.pt``) on the test split, once; write ``test.json``."""
    best = load_checkpoint(run_dir / "best.pt")
    model.load_state_dict(best["model"])
    result = {"epoch": best["epoch"], SELECT_BY: best["history"][-1][SELECT_BY],
              **{f"test/{k}": v for k, v in model_metrics(model, cfg, test_set).items()}}
    atomic_write_text(run_dir / "test.json", json.dumps(result, indent=1))
    return result
