"""Train and evaluate a perception model on a tactile dataset.

    split 80/20 (seeded) -> Adam(lr 3e-3, weight decay 1e-5, x0.8 per epoch), batch 32, MSE
    -> RMSE (cm, deg); the output bias starts at the mean training label

The paper's loop (Adam, constant lr 1e-3, default init) and TacGNN are
``lr=0.001 lr_schedule=constant init_output_bias=false model.use_force=false
model.force_feature=raw model.pool=last``. Why the defaults differ (measurements in
experiments/perception_accuracy/NOTES.md): the labels are world positions ~4 cm from 0, and
with the default init the output bias has to walk there at <= lr per Adam step, which costs
a good part of a 10-epoch budget; the model is far from converged after 10 epochs at 1e-3,
so a larger lr that then decays trains it further in the same time. ``lr_schedule=cosine`` is slightly better
for a fixed budget, but depends on ``epochs``; the default ``exp`` does not, so a run
resumed with a larger ``epochs`` still equals one trained that long from the start.

A run folder holds `checkpoint.pt` (written atomically after every epoch, loadable with
``torch.load(weights_only=True)``), `history.json` (per-epoch metrics) and TensorBoard
events. ``resume=True`` continues from the checkpoint; the batch order of epoch e is
drawn from seed + e, so a resumed run equals an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from tacgnn.config import check, from_dict, to_dict
from tacgnn.datasets.store import load, read_manifest
from tacgnn.perception.models import PerceptionModel, PerceptionModelConfig, build_model
from tacgnn.perception.objectives import OUT_DIM, Objective, TaskName, targets

CHECKPOINT_VERSION = 1
LR_SCHEDULES = ("constant", "cosine", "step", "exp")
#: Values of config keys added after format version 1 was fixed, as checkpoints without them
#: were trained (the paper's setup); filled in on loading, so old checkpoints keep working.
LEGACY_TRAIN_VALUES = {"lr_schedule": "constant", "lr_final": 0.01, "lr_decay": 0.8, "warmup_epochs": 0.0,
                       "init_output_bias": False}
LEGACY_MODEL_VALUES = {"force_feature": "raw", "pos_scale": 1.0, "message_layers": 2, "head_layers": 2,
                       "head_hidden": 0, "residual": False, "pool": "last", "joint_inputs": 0}


def lr_factor(cfg: "PerceptionTrainConfig", step: int, total_steps: int, steps_per_epoch: int) -> float:
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


#: Model settings offline training starts from, over PerceptionModelConfig's defaults (the paper's
#: TacGNN, kept there for old checkpoints): force as a log node feature and a readout from every
#: layer (TacGNN only; other models ignore them). Paper: use_force=false force_feature=raw pool=last.
TRAIN_MODEL_DEFAULTS = {"use_force": True, "force_feature": "log", "pool": "jk"}


def default_model_config(**kw) -> PerceptionModelConfig:
    return PerceptionModelConfig(**{**TRAIN_MODEL_DEFAULTS, **kw})


@dataclass(frozen=True)
class PerceptionTrainConfig:
    task: TaskName = "baoding"
    model: PerceptionModelConfig = field(default_factory=default_model_config)
    epochs: int = 10
    batch_size: int = 32
    lr: float = 3e-3
    """Peak learning rate (the paper: 1e-3, constant)."""
    weight_decay: float = 1e-5
    train_fraction: float = 0.8
    max_samples: int = 0
    """Use only the first this-many samples of the dataset (0: all), for learning curves."""
    seed: int = 0
    threads: int = 1
    """torch threads; 1 is robust when the other core is busy (2 threads stall under load)."""
    match_balls: bool = True
    """baoding: permutation-invariant loss (True) or balls by identity (False)."""
    lr_schedule: str = "exp"
    """Learning rate over the run, set every step: 'constant' (the paper), 'cosine' (from lr down
    to lr * lr_final, half a cosine), 'step' (x0.1 at 50% and 75% of the steps) or 'exp'
    (x lr_decay per epoch; the only one that does not depend on `epochs`, so a run resumed
    with a larger `epochs` equals a longer run)."""
    lr_final: float = 0.01
    """cosine: the last learning rate as a fraction of lr."""
    lr_decay: float = 0.8
    """exp: the learning rate is multiplied by this every epoch (smoothly, every step)."""
    warmup_epochs: float = 0.0
    """Linear warm-up of the learning rate from 0 over this many epochs."""
    init_output_bias: bool = True
    """Start the output layer's bias at the mean training label (labels are ~4 cm off 0)."""

    def __post_init__(self) -> None:
        check(self.epochs >= 1, "epochs", "must be >= 1")
        check(self.batch_size >= 1, "batch_size", "must be >= 1")
        check(self.lr > 0, "lr", "must be positive")
        check(0 < self.train_fraction < 1, "train_fraction", "must be in (0, 1)")
        check(self.max_samples >= 0, "max_samples", "must be >= 0")
        check(self.lr_schedule in LR_SCHEDULES, "lr_schedule", f"must be one of {LR_SCHEDULES}")
        check(0 <= self.lr_final <= 1, "lr_final", "must be in [0, 1]")
        check(self.warmup_epochs >= 0, "warmup_epochs", "must be >= 0")
        check(0 < self.lr_decay <= 1, "lr_decay", "must be in (0, 1]")
        check(self.model.out_dim == OUT_DIM[self.task], "model.out_dim",
              f"task '{self.task}' predicts {OUT_DIM[self.task]} values, got {self.model.out_dim}")

    @classmethod
    def for_task(cls, task: TaskName, model: str = "tacgnn", **kw) -> "PerceptionTrainConfig":
        model_kw = kw.pop("model_kw", {})
        return cls(task=task, model=default_model_config(name=model, out_dim=OUT_DIM[task], **model_kw), **kw)


@dataclass
class TactileData:
    """A dataset in memory as tensors: readings (N, T) N, positions (N, T, 3) cm, targets (N, D),
    and joint angles (N, 16) rad for models that read them (else None)."""

    readings: torch.Tensor
    positions: torch.Tensor
    targets: torch.Tensor
    joints: torch.Tensor | None = None

    def __len__(self) -> int:
        return len(self.targets)

    def subset(self, idx) -> "TactileData":
        joints = None if self.joints is None else self.joints[idx]
        return TactileData(self.readings[idx], self.positions[idx], self.targets[idx], joints)

    def batch(self, idx) -> tuple[torch.Tensor, ...]:
        """A model's inputs for rows `idx`: (readings, positions) or (readings, positions, joints)."""
        inputs = (self.readings[idx], self.positions[idx])
        return inputs if self.joints is None else (*inputs, self.joints[idx])


def load_tactile(root: str | Path, task: TaskName, max_samples: int = 0, joints: bool = False) -> TactileData:
    """Read a dataset for `task` (checks that its kind matches); `joints` also reads the joint angles."""
    meta = read_manifest(root)["metadata"]
    kind = "baoding" if task == "baoding" else "grasp"
    if meta.get("kind") != kind or (kind == "grasp" and meta.get("object") != task):
        raise ValueError(f"{root}: dataset is kind={meta.get('kind')!r} object={meta.get('object')!r}, "
                         f"task '{task}' needs kind={kind!r}" + ("" if kind == "baoding" else f" object={task!r}"))
    fields = ["tactile", "taxel_pos", "ball_pos"] if kind == "baoding" else \
        ["tactile", "taxel_pos", "object_pos", "object_rot"]
    data = load(root, fields + (["joint_pos"] if joints else []))
    if max_samples:
        data = {k: v[:max_samples] for k, v in data.items()}
    return TactileData(torch.from_numpy(data["tactile"]), torch.from_numpy(data["taxel_pos"] * 100.0),
                       torch.from_numpy(targets(data, task)),
                       torch.from_numpy(data["joint_pos"]).float() if joints else None)


def split(data: TactileData, train_fraction: float, seed: int) -> tuple[TactileData, TactileData]:
    order = torch.randperm(len(data), generator=torch.Generator().manual_seed(seed))
    cut = int(round(train_fraction * len(data)))
    return data.subset(order[:cut]), data.subset(order[cut:])


@torch.no_grad()
def predict(model: PerceptionModel, data: TactileData, batch: int = 1024) -> torch.Tensor:
    model.eval()
    return torch.cat([model(*data.batch(slice(i, i + batch))) for i in range(0, len(data), batch)])


def make_model(cfg: PerceptionModelConfig, rest_positions_cm: torch.Tensor | None) -> PerceptionModel:
    return build_model(cfg, rest_positions=rest_positions_cm if cfg.name == "gcn" else None)


def rest_positions_cm(skin_dict: dict) -> torch.Tensor:
    """Taxel positions (cm) of the skin on the hand at zero joint angles: the GCN's fixed graph."""
    import mujoco

    from tacgnn.hand.allegro import HandConfig
    from tacgnn.hand.skin_layout import SkinLayout
    from tacgnn.sim.scene import SimConfig, compile_with_skin, hand_scene
    from tacgnn.sim.tactile import TactileModel

    skin = from_dict(SkinLayout, skin_dict)
    sim = SimConfig()
    model = compile_with_skin(hand_scene(HandConfig(), sim), skin, sim)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    pos = TactileModel(skin, model).positions(data.xpos[None], data.xmat[None])[0]
    return torch.from_numpy(pos * 100.0)


# --- checkpoints ---------------------------------------------------------------------------

def save_checkpoint(path: Path, payload: dict) -> None:
    """torch.save to a temp file in the same folder, then rename: never a half-written file."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    os.close(fd)
    torch.save(payload, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: str | Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such checkpoint")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # truncated, corrupt, or not a torch file
        raise ValueError(f"{path}: not a readable checkpoint ({type(err).__name__}: {err})") from None
    if not isinstance(payload, dict) or payload.get("format_version") != CHECKPOINT_VERSION:
        raise ValueError(f"{path}: not a tacgnn perception checkpoint of version {CHECKPOINT_VERSION}")
    if not {"config", "model", "dataset"} <= payload.keys():  # e.g. a policy checkpoint
        raise ValueError(f"{path}: not a tacgnn perception checkpoint (no model, config and dataset)")
    config = payload.get("config")
    if isinstance(config, dict):  # written before these keys existed: it was trained with their old values
        for key, value in LEGACY_TRAIN_VALUES.items():
            config.setdefault(key, value)
        if isinstance(config.get("model"), dict):
            for key, value in LEGACY_MODEL_VALUES.items():
                config["model"].setdefault(key, value)
    return payload


def load_model(path: str | Path) -> tuple[PerceptionModel, PerceptionTrainConfig, dict]:
    """The trained model (eval mode), its training config, and the dataset metadata it saw."""
    payload = load_checkpoint(path)
    cfg = from_dict(PerceptionTrainConfig, payload["config"])
    rest = payload.get("rest_positions_cm")
    model = make_model(cfg.model, rest)
    model.load_state_dict(payload["model"])
    return model.eval(), cfg, payload["dataset"]


def backward_checked(optim: torch.optim.Optimizer, loss: torch.Tensor, where: str) -> None:
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


def make_optimizer(model: torch.nn.Module, lr: float, weight_decay: float) -> torch.optim.Adam:
    """Adam; the fused kernel where this torch has it (~5x faster steps on CPU, same algorithm)."""
    try:
        return torch.optim.Adam(model.parameters(), lr=lr, weight_decay=weight_decay, fused=True)
    except (RuntimeError, TypeError, ValueError):
        return torch.optim.Adam(model.parameters(), lr=lr, weight_decay=weight_decay)


# --- training --------------------------------------------------------------------------------

def train(cfg: PerceptionTrainConfig, dataset: str | Path, run_dir: str | Path, resume: bool = False,
          log=print) -> dict:
    """Train on `dataset`; return the final metrics (train and test)."""
    from torch.utils.tensorboard import SummaryWriter

    torch.set_num_threads(cfg.threads)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    ckpt_path = run_dir / "checkpoint.pt"
    meta = read_manifest(dataset)["metadata"]
    data = load_tactile(dataset, cfg.task, cfg.max_samples, joints=cfg.model.joint_inputs > 0)
    num_taxels = data.readings.shape[1]
    if cfg.model.num_taxels != num_taxels:
        cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, num_taxels=num_taxels))
    train_set, test_set = split(data, cfg.train_fraction, cfg.seed)
    objective = Objective(cfg.task, cfg.match_balls)
    rest = rest_positions_cm(meta["skin"]) if cfg.model.name == "gcn" else None

    torch.manual_seed(cfg.seed)
    model = make_model(cfg.model, rest)
    if cfg.init_output_bias:
        last = [m for m in model.modules() if isinstance(m, torch.nn.Linear)][-1]
        with torch.no_grad():
            last.bias.copy_(train_set.targets.mean(0))
    optim = make_optimizer(model, cfg.lr, cfg.weight_decay)
    history: list[dict] = []
    start_epoch = 0
    if resume and ckpt_path.exists():
        payload = load_checkpoint(ckpt_path)
        if payload["config"] != to_dict(cfg):
            diff = [k for k in payload["config"] if payload["config"][k] != to_dict(cfg).get(k)]
            raise ValueError(f"{ckpt_path}: was trained with another config (differs in {diff})")
        model.load_state_dict(payload["model"])
        optim.load_state_dict(payload["optimizer"])
        history, start_epoch = payload["history"], payload["epoch"] + 1
        log(f"resumed from {ckpt_path} after epoch {payload['epoch']}")

    writer = SummaryWriter(run_dir)
    steps_per_epoch = -(-len(train_set) // cfg.batch_size)
    total_steps = cfg.epochs * steps_per_epoch
    for epoch in range(start_epoch, cfg.epochs):
        model.train()
        start = time.perf_counter()
        order = torch.randperm(len(train_set), generator=torch.Generator().manual_seed(cfg.seed * 1000 + epoch))
        total, batches = 0.0, 0
        for i in range(0, len(order), cfg.batch_size):
            idx = order[i:i + cfg.batch_size]
            loss = objective.loss(model(*train_set.batch(idx)), train_set.targets[idx])
            backward_checked(optim, loss, f"at epoch {epoch}, batch {batches} of {run_dir}")
            if cfg.lr_schedule != "constant" or cfg.warmup_epochs > 0:
                lr = cfg.lr * lr_factor(cfg, epoch * steps_per_epoch + batches, total_steps, steps_per_epoch)
                for group in optim.param_groups:
                    group["lr"] = lr
            optim.step()
            total += loss.item()
            batches += 1
        seconds = time.perf_counter() - start
        train_m = objective.metrics(predict(model, train_set), train_set.targets)
        test_m = objective.metrics(predict(model, test_set), test_set.targets)
        row = {"epoch": epoch, "loss": total / batches, "seconds": seconds, "lr": optim.param_groups[0]["lr"],
               **{f"train/{k}": v for k, v in train_m.items()}, **{f"test/{k}": v for k, v in test_m.items()}}
        history.append(row)
        for key, value in row.items():
            if key != "epoch":
                writer.add_scalar(key if "/" in key else f"train/{key}", value, epoch)
        log(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()))
        save_checkpoint(ckpt_path, {
            "format_version": CHECKPOINT_VERSION, "config": to_dict(cfg), "epoch": epoch,
            "model": model.state_dict(), "optimizer": optim.state_dict(), "history": history,
            "dataset": {"path": str(dataset), "num_taxels": num_taxels, "kind": meta.get("kind"),
                        "object": meta.get("object")},
            "rest_positions_cm": rest,
        })
        (run_dir / "history.json").write_text(json.dumps(history, indent=1))
    writer.close()
    return history[-1]


def evaluate(checkpoint: str | Path, dataset: str | Path, dead_fraction: float = 0.0, seed: int = 0,
             whole: bool = False) -> dict:
    """Errors of a trained model on a dataset's test split (or all of it with `whole`).

    `dead_fraction` zeroes that share of the taxels (the same ones in every frame), as a
    real skin with broken taxels would read.
    """
    model, cfg, _ = load_model(checkpoint)
    # the training run's frames (max_samples), so that its test split is the one it never saw
    data = load_tactile(dataset, cfg.task, 0 if whole else cfg.max_samples, joints=cfg.model.joint_inputs > 0)
    if data.readings.shape[1] != cfg.model.num_taxels:
        raise ValueError(f"{dataset}: has {data.readings.shape[1]} taxels, the model was trained on "
                         f"{cfg.model.num_taxels}")
    test = data if whole else split(data, cfg.train_fraction, cfg.seed)[1]
    if dead_fraction > 0:
        gen = torch.Generator().manual_seed(seed)
        dead = torch.randperm(test.readings.shape[1], generator=gen)[:int(round(dead_fraction * test.readings.shape[1]))]
        readings = test.readings.clone()
        readings[:, dead] = 0.0
        test = TactileData(readings, test.positions, test.targets, test.joints)
    torch.set_num_threads(cfg.threads)
    pred = predict(model, test)
    metrics = Objective(cfg.task, cfg.match_balls).metrics(pred, test.targets)
    if cfg.task == "baoding":
        metrics.update(ball_visibility_errors(pred, test, cfg.match_balls))
    return metrics


def ball_visibility_errors(pred: torch.Tensor, data: TactileData, match_balls: bool,
                           seen_within_cm: float = 3.0) -> dict:
    """Baoding: position RMSE (cm) of balls the skin touches and of balls it does not.

    A ball is "seen" when an activated taxel lies within `seen_within_cm` of its centre
    (the balls' radius is 2.6 cm), "blind" otherwise: it rests on the other ball or on
    a part of the hand without skin, and only indirect cues place it. With the
    permutation-invariant loss the better ball assignment of each frame is used.
    """
    t = data.targets
    if match_balls:
        swapped = t[:, [3, 4, 5, 0, 1, 2]]
        use = ((pred - swapped) ** 2).sum(1) < ((pred - t) ** 2).sum(1)
        t = torch.where(use[:, None], swapped, t)
    active = data.readings > 0
    se = {True: [], False: []}
    for b in range(2):
        centre = t[:, None, 3 * b:3 * b + 3]
        nearest = (data.positions - centre).norm(dim=-1).masked_fill(~active, float("inf")).amin(1)
        err = ((pred[:, 3 * b:3 * b + 3] - t[:, 3 * b:3 * b + 3]) ** 2).mean(1)
        seen = nearest < seen_within_cm
        se[True].append(err[seen])
        se[False].append(err[~seen])
    seen_err, blind_err = torch.cat(se[True]), torch.cat(se[False])
    rmse = lambda e: float(e.mean().sqrt()) if len(e) else float("nan")  # noqa: E731
    return {"seen_rmse_cm": rmse(seen_err), "blind_rmse_cm": rmse(blind_err),
            "blind_fraction": len(blind_err) / (len(seen_err) + len(blind_err))}
