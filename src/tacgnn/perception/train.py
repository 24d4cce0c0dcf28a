"""Train and evaluate a perception model on a tactile dataset (the paper's setup).

    split 80/20 (seeded) -> Adam(lr 1e-3, weight decay 1e-5), batch 32, MSE -> RMSE (cm, deg)

A run folder holds `checkpoint.pt` (written atomically after every epoch, loadable with
``torch.load(weights_only=True)``), `history.json` (per-epoch metrics) and TensorBoard
events. ``resume=True`` continues from the checkpoint; the batch order of epoch e is
drawn from seed + e, so a resumed run equals an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import json
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


@dataclass(frozen=True)
class PerceptionTrainConfig:
    task: TaskName = "baoding"
    model: PerceptionModelConfig = field(default_factory=PerceptionModelConfig)
    epochs: int = 10
    batch_size: int = 32
    lr: float = 1e-3
    weight_decay: float = 1e-5
    train_fraction: float = 0.8
    max_samples: int = 0
    """Use only the first this-many samples of the dataset (0: all), for learning curves."""
    seed: int = 0
    threads: int = 1
    """torch threads; 1 is robust when the other core is busy (2 threads stall under load)."""
    match_balls: bool = True
    """baoding: permutation-invariant loss (True) or balls by identity (False)."""

    def __post_init__(self) -> None:
        check(self.epochs >= 1, "epochs", "must be >= 1")
        check(self.batch_size >= 1, "batch_size", "must be >= 1")
        check(self.lr > 0, "lr", "must be positive")
        check(0 < self.train_fraction < 1, "train_fraction", "must be in (0, 1)")
        check(self.max_samples >= 0, "max_samples", "must be >= 0")
        check(self.model.out_dim == OUT_DIM[self.task], "model.out_dim",
              f"task '{self.task}' predicts {OUT_DIM[self.task]} values, got {self.model.out_dim}")

    @classmethod
    def for_task(cls, task: TaskName, model: str = "tacgnn", **kw) -> "PerceptionTrainConfig":
        model_kw = kw.pop("model_kw", {})
        return cls(task=task, model=PerceptionModelConfig(name=model, out_dim=OUT_DIM[task], **model_kw), **kw)


@dataclass
class TactileData:
    """A dataset in memory as tensors: readings (N, T) N, positions (N, T, 3) cm, targets (N, D)."""

    readings: torch.Tensor
    positions: torch.Tensor
    targets: torch.Tensor

    def __len__(self) -> int:
        return len(self.targets)

    def subset(self, idx) -> "TactileData":
        return TactileData(self.readings[idx], self.positions[idx], self.targets[idx])


def load_tactile(root: str | Path, task: TaskName, max_samples: int = 0) -> TactileData:
    """Read a dataset for `task` (checks that its kind matches)."""
    meta = read_manifest(root)["metadata"]
    kind = "baoding" if task == "baoding" else "grasp"
    if meta.get("kind") != kind or (kind == "grasp" and meta.get("object") != task):
        raise ValueError(f"{root}: dataset is kind={meta.get('kind')!r} object={meta.get('object')!r}, "
                         f"task '{task}' needs kind={kind!r}" + ("" if kind == "baoding" else f" object={task!r}"))
    fields = ["tactile", "taxel_pos", "ball_pos"] if kind == "baoding" else \
        ["tactile", "taxel_pos", "object_pos", "object_rot"]
    data = load(root, fields)
    if max_samples:
        data = {k: v[:max_samples] for k, v in data.items()}
    return TactileData(torch.from_numpy(data["tactile"]), torch.from_numpy(data["taxel_pos"] * 100.0),
                       torch.from_numpy(targets(data, task)))


def split(data: TactileData, train_fraction: float, seed: int) -> tuple[TactileData, TactileData]:
    order = torch.randperm(len(data), generator=torch.Generator().manual_seed(seed))
    cut = int(round(train_fraction * len(data)))
    return data.subset(order[:cut]), data.subset(order[cut:])


@torch.no_grad()
def predict(model: PerceptionModel, data: TactileData, batch: int = 1024) -> torch.Tensor:
    model.eval()
    return torch.cat([model(data.readings[i:i + batch], data.positions[i:i + batch])
                      for i in range(0, len(data), batch)])


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
    return payload


def load_model(path: str | Path) -> tuple[PerceptionModel, PerceptionTrainConfig, dict]:
    """The trained model (eval mode), its training config, and the dataset metadata it saw."""
    payload = load_checkpoint(path)
    cfg = from_dict(PerceptionTrainConfig, payload["config"])
    rest = payload.get("rest_positions_cm")
    model = make_model(cfg.model, rest)
    model.load_state_dict(payload["model"])
    return model.eval(), cfg, payload["dataset"]


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
    data = load_tactile(dataset, cfg.task, cfg.max_samples)
    num_taxels = data.readings.shape[1]
    if cfg.model.num_taxels != num_taxels:
        cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, num_taxels=num_taxels))
    train_set, test_set = split(data, cfg.train_fraction, cfg.seed)
    objective = Objective(cfg.task, cfg.match_balls)
    rest = rest_positions_cm(meta["skin"]) if cfg.model.name == "gcn" else None

    torch.manual_seed(cfg.seed)
    model = make_model(cfg.model, rest)
    optim = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
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
    for epoch in range(start_epoch, cfg.epochs):
        model.train()
        start = time.perf_counter()
        order = torch.randperm(len(train_set), generator=torch.Generator().manual_seed(cfg.seed * 1000 + epoch))
        total, batches = 0.0, 0
        for i in range(0, len(order), cfg.batch_size):
            idx = order[i:i + cfg.batch_size]
            loss = objective.loss(model(train_set.readings[idx], train_set.positions[idx]), train_set.targets[idx])
            if not torch.isfinite(loss):
                raise FloatingPointError(f"non-finite loss at epoch {epoch}, batch {batches}; weights left unchanged")
            optim.zero_grad(set_to_none=True)
            loss.backward()
            optim.step()
            total += loss.item()
            batches += 1
        seconds = time.perf_counter() - start
        train_m = objective.metrics(predict(model, train_set), train_set.targets)
        test_m = objective.metrics(predict(model, test_set), test_set.targets)
        row = {"epoch": epoch, "loss": total / batches, "seconds": seconds,
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
    data = load_tactile(dataset, cfg.task)
    if data.readings.shape[1] != cfg.model.num_taxels:
        raise ValueError(f"{dataset}: has {data.readings.shape[1]} taxels, the model was trained on "
                         f"{cfg.model.num_taxels}")
    test = data if whole else split(data, cfg.train_fraction, cfg.seed)[1]
    if dead_fraction > 0:
        gen = torch.Generator().manual_seed(seed)
        dead = torch.randperm(test.readings.shape[1], generator=gen)[:int(round(dead_fraction * test.readings.shape[1]))]
        readings = test.readings.clone()
        readings[:, dead] = 0.0
        test = TactileData(readings, test.positions, test.targets)
    torch.set_num_threads(cfg.threads)
    return Objective(cfg.task, cfg.match_balls).metrics(predict(model, test), test.targets)
