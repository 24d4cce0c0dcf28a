"""Perception trained in the loop: the policy sees the ball positions the skin predicts.

The paper's two-stage workflow, as one object handed to the env and the PPO loop:

    act: BaodingEnv(obs_mode='perceived', perception=p) asks p(readings, taxel_pos) for the
         ball positions of every env at every step (no gradient reaches the policy);
    record: p.record(info) keeps the newest `buffer_size` skin frames with their true
         ball positions (a ring buffer);
    learn: every `update_every_steps` env steps, p.update() trains the perception model for
         `epochs` epochs on the buffer (Adam, MSE, permutation-invariant over the balls).

The model may start from a perception checkpoint trained offline (`pretrained`, the
"privileged route": rollouts of a ground-truth policy make its dataset) or from scratch.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import torch

from tacgnn.config import ConfigError, check, from_dict, to_dict
from tacgnn.datasets.store import DatasetError
from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.perception.checkpoint import load_checkpoint as load_perception_checkpoint
from tacgnn.perception.checkpoint import make_model
from tacgnn.perception.data import load_tactile
from tacgnn.perception.models import PerceptionModelConfig
from tacgnn.perception.objectives import Objective
from tacgnn.perception.rest_positions import rest_positions_cm
from tacgnn.perception.training import backward_checked

InputArray = np.ndarray | torch.Tensor
"""A skin array as the env hands it out: numpy (C engine) or a tensor on the Warp engine's device."""


def model_input(array: InputArray, scale: float = 1.0) -> torch.Tensor:
    """`array` x `scale` as a float32 tensor on the CPU, where the perception runs: numpy without a
    copy where it can (scaled in its own precision, as before tensors came in), a tensor from any
    device (on the CPU, as it is)."""
    if isinstance(array, torch.Tensor):
        t = array.to("cpu", torch.float32)
        return t * scale if scale != 1.0 else t
    return torch.from_numpy(np.ascontiguousarray(array * scale if scale != 1.0 else array, np.float32))


@dataclass(frozen=True)
class OnlinePerceptionConfig:
    model: PerceptionModelConfig = field(default_factory=PerceptionModelConfig)
    update_every_steps: int = 100
    """Env steps (per env) between perception updates: 100 x 256 envs = 25,600 new frames."""
    epochs: int = 10
    """Passes over the buffer per update (the paper: 10)."""
    buffer_size: int = 25_600
    batch_size: int = 32
    lr: float = 1e-3
    weight_decay: float = 1e-5
    pretrained: str = ""
    """A perception checkpoint (from `tacgnn train-perception`) to start from; '' = from scratch."""
    record_every: int = 1
    """Keep every k-th step's frames (neighbouring frames are near duplicates)."""
    threads: int = 1
    """CPU threads for torch during perception updates."""
    match_balls: bool = True
    """Permutation-invariant loss over the two balls (True) or balls by identity (False)."""
    warmup_rounds: int = 0
    """Before PPO first updates the policy: rounds of (the starting policy acts on the perceived
    balls for `update_every_steps` env steps, then one perception update). Not in the paper;
    see `tacgnn.learning.runner.Runner.warm_up_perception`."""
    temporal: bool = False
    """A temporal perception (`tacgnn.learning.online_temporal`): `model` is its per-frame encoder,
    a filter carries the balls through frames without contact, its state kept per env and reset
    at each episode's start; it learns from windows of consecutive recorded frames."""
    window: int = 16
    """temporal: frames per training window (truncated back-propagation through time)."""
    burn_in: int = 64
    """temporal: recorded frames before a window that bring the state up without gradient."""
    temporal_feature: int = 64
    """temporal: width of the per-frame feature."""
    temporal_hidden: int = 128
    """temporal: width of the GRU state."""
    anchor_dataset: str = ""
    """A Baoding dataset (e.g. the teacher's frames, `tacgnn make-dataset baoding`) mixed into
    every update, so that the model keeps fitting frames other than the blind policy's own,
    which alone it fits at the cost of others (docs/results.md, section 6); '' = the buffer alone."""
    anchor_share: float = 0.5
    """With `anchor_dataset`: the share of each update's samples drawn from it."""

    def __post_init__(self) -> None:
        check(self.model.out_dim == 6, "perception.model.out_dim", "ball positions are 6 values")
        if self.temporal:
            check(self.record_every == 1, "perception.record_every", "must be 1 with temporal (windows of consecutive "
                  f"steps), got {self.record_every}")
            check(self.model.joint_inputs == 0, "perception.model.joint_inputs",
                  "must be 0 with temporal: the temporal model reads the joint angles itself")
            check(self.model.name in ("tacgnn", "mlp", "cnn"), "perception.model.name",
                  f"a temporal model's frame encoder is tacgnn, mlp or cnn, got {self.model.name!r}")
            check(1 <= self.window <= self.buffer_size, "perception.window",
                  f"must be in 1..buffer_size ({self.buffer_size}), got {self.window}")
            check(self.burn_in >= 0, "perception.burn_in", f"must be >= 0, got {self.burn_in}")
            check(self.temporal_feature >= 1 and self.temporal_hidden >= 1, "perception.temporal_feature",
                  "temporal_feature and temporal_hidden must be >= 1")
        check(self.update_every_steps >= 1, "perception.update_every_steps", "must be >= 1")
        check(self.epochs >= 0, "perception.epochs", "must be >= 0")
        check(self.buffer_size >= self.batch_size >= 1, "perception.buffer_size", "must be >= batch_size >= 1")
        check(self.record_every >= 1, "perception.record_every", "must be >= 1")
        check(self.warmup_rounds >= 0, "perception.warmup_rounds", "must be >= 0")
        check(1 <= self.threads <= 1024, "perception.threads", f"must be in [1, 1024], got {self.threads}")
        check(self.lr > 0, "perception.lr", f"must be positive, got {self.lr}")
        check(self.weight_decay >= 0, "perception.weight_decay", f"must be >= 0, got {self.weight_decay}")
        check(0 < self.anchor_share < 1, "perception.anchor_share", f"must be in (0, 1), got {self.anchor_share}")
        if self.anchor_dataset:
            check(not self.temporal and self.model.joint_inputs == 0, "perception.anchor_dataset",
                  "mixes single frames of skin alone: not with temporal or joint_inputs")
        check(self.buffer_size <= 1_000_000, "perception.buffer_size",  # 16 bytes per taxel and frame: 10 GB
              f"must be <= 1,000,000, got {self.buffer_size}")


class OnlinePerception:
    """Callable perception for `BaodingEnv(perception=...)` that learns from what it records."""

    def __init__(self, cfg: OnlinePerceptionConfig, skin: dict, seed: int = 0):
        num_taxels = from_dict(SkinLayout, skin).num_taxels
        payload = load_perception_checkpoint(cfg.pretrained) if cfg.pretrained else None
        if payload is not None:
            task = payload["config"].get("task")
            if task != "baoding":
                raise ConfigError(f"perception.pretrained {cfg.pretrained}: a perception trained for the {task!r} "
                                  "task; the Baoding env needs one that predicts ball positions ('baoding')")
            trained_on = payload.get("dataset", {}).get("num_taxels")
            if trained_on is not None and trained_on != num_taxels:
                raise ConfigError(f"perception.pretrained {cfg.pretrained}: trained on a skin of {trained_on} "
                                  f"taxels, this env's skin has {num_taxels}")
            # the checkpoint defines the architecture; the config only has to agree on the model kind
            stored = from_dict(PerceptionModelConfig, payload["config"]["model"])
            if stored.name != cfg.model.name:
                raise ConfigError(f"perception.pretrained {cfg.pretrained}: a {stored.name} model, "
                                  f"perception.model.name asks for {cfg.model.name}")
            cfg = dataclasses.replace(cfg, model=stored)
        self.cfg = cfg
        model_cfg = dataclasses.replace(cfg.model, num_taxels=num_taxels)
        self._rest = rest_positions_cm(skin) if model_cfg.name == "gcn" else None
        torch.manual_seed(seed)
        self.model = make_model(model_cfg, self._rest)
        if payload is not None:
            self.model.load_state_dict(payload["model"])
        self.optim = torch.optim.Adam(self.model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        self.objective = Objective("baoding", cfg.match_balls)
        n = cfg.buffer_size
        self.readings = torch.zeros(n, num_taxels)
        self.positions = torch.zeros(n, num_taxels, 3)
        self.labels = torch.zeros(n, 6)
        self.joint_inputs = model_cfg.joint_inputs
        self.joints = torch.zeros(n, self.joint_inputs)  # (n, 0) for a skin-only model
        self.size, self.head, self.steps_seen, self.updates = 0, 0, 0, 0
        self._gen = torch.Generator().manual_seed(seed)
        self.anchor = self._load_anchor(cfg.anchor_dataset, num_taxels) if cfg.anchor_dataset else None
        self._anchor_batch = round(cfg.batch_size * cfg.anchor_share / (1 - cfg.anchor_share))

    @torch.inference_mode()
    def __call__(self, readings: InputArray, taxel_pos: InputArray, joints: np.ndarray | None = None) -> np.ndarray:
        """(N, 6) ball positions in metres from (N, T) readings, (N, T, 3) positions in metres
        and, for a model with `joint_inputs`, (N, 16) joint angles in rad; numpy, or tensors as the
        Warp skin leaves them on its device."""
        self._to_eval()
        inputs = [model_input(readings), model_input(taxel_pos, 100.0)]
        if joints is not None:
            inputs.append(model_input(joints))
        return self.model(*inputs).cpu().numpy().astype(np.float64) / 100.0

    def _to_eval(self) -> None:
        """Put the model in eval mode to act. Only when it is not: eval() walks every submodule, a
        tenth to a fifth of a one-frame call."""
        if self.model.training:
            self.model.eval()

    def _inputs(self, idx: torch.Tensor) -> tuple[torch.Tensor, ...]:
        inputs = (self.readings[idx], self.positions[idx])
        return (*inputs, self.joints[idx]) if self.joint_inputs else inputs

    @staticmethod
    def _load_anchor(path: str, num_taxels: int):
        """The anchor frames, or a `ConfigError` naming the key when the dataset is missing, broken
        or of another skin."""
        try:
            anchor = load_tactile(path, "baoding")
        except DatasetError as err:
            raise ConfigError(f"perception.anchor_dataset: {err}") from None
        if anchor.readings.shape[1] != num_taxels:
            raise ConfigError(f"perception.anchor_dataset {path}: frames of "
                              f"{anchor.readings.shape[1]} taxels, this env's skin has {num_taxels}")
        return anchor

    def _with_anchor(self, inputs: tuple[torch.Tensor, ...], labels: torch.Tensor
                     ) -> tuple[tuple[torch.Tensor, ...], torch.Tensor]:
        """A batch of the buffer with `anchor_share` of anchor frames added (unchanged without)."""
        if self.anchor is None:
            return inputs, labels
        a = torch.randint(len(self.anchor), (self._anchor_batch,), generator=self._gen)
        readings, positions = inputs
        return ((torch.cat([readings, self.anchor.readings[a]]), torch.cat([positions, self.anchor.positions[a]])),
                torch.cat([labels, self.anchor.targets[a]]))

    def record(self, info: dict) -> None:
        """Keep this step's frames of envs whose episode goes on (a fall's last frame is noise)."""
        self.steps_seen += 1
        if self.steps_seen % self.cfg.record_every:
            return
        keep = ~(info["fall"] | info["diverged"])
        rows = torch.from_numpy(np.flatnonzero(keep))
        r = model_input(info["tactile"])[rows]
        p = model_input(info["taxel_pos"], 100.0)[rows]
        y = torch.from_numpy((info["ball_pos"][keep].reshape(-1, 6) * 100.0).astype(np.float32))
        idx = (self.head + torch.arange(len(y))) % self.cfg.buffer_size
        self.readings[idx], self.positions[idx], self.labels[idx] = r, p, y
        if self.joint_inputs:
            self.joints[idx] = torch.from_numpy(info["joint_pos"][keep]).float()
        self.head = int((self.head + len(y)) % self.cfg.buffer_size)
        self.size = min(self.cfg.buffer_size, self.size + len(y))

    def update(self) -> dict[str, float]:
        """Train `epochs` epochs on the buffer; return the buffer RMSE (cm) before and after."""
        torch.set_num_threads(self.cfg.threads)
        n = self.size
        if n < self.cfg.batch_size:
            return {}
        before = self._rmse(n)
        self.model.train()
        for _ in range(self.cfg.epochs):
            order = torch.randperm(n, generator=self._gen)
            for i in range(0, n, self.cfg.batch_size):
                idx = order[i:i + self.cfg.batch_size]
                inputs, labels = self._with_anchor(self._inputs(idx), self.labels[idx])
                loss = self.objective.loss(self.model(*inputs), labels)
                backward_checked(self.optim, loss, f"in perception update {self.updates + 1} (in-loop training)")
                self.optim.step()
        self.updates += 1
        return {"perception/rmse_cm_before": before, "perception/rmse_cm_after": self._rmse(n),
                "perception/buffer": float(n)}

    @torch.inference_mode()
    def _rmse(self, n: int) -> float:
        self.model.eval()
        idx = torch.randperm(n, generator=torch.Generator().manual_seed(0))[:4096]
        # in chunks of the rollout's batch size: a GCN builds (and caches) one adjacency per size
        pred = torch.cat([self.model(*self._inputs(chunk)) for chunk in idx.split(256)])
        return self.objective.metrics(pred, self.labels[idx])["position_rmse_cm"]

    def state_dict(self) -> dict:
        """Model, optimiser, counters and random stream; the frame buffer is `frames_state_dict`."""
        return {"config": to_dict(self.cfg), "model": self.model.state_dict(),
                "optimizer": self.optim.state_dict(), "updates": self.updates,
                "rest_positions_cm": self._rest, "steps_seen": self.steps_seen,
                "generator": self._gen.get_state()}

    def load_state_dict(self, state: dict) -> None:
        self.model.load_state_dict(state["model"])
        self.optim.load_state_dict(state["optimizer"])
        self.updates = state["updates"]
        if "generator" in state:  # checkpoints of older versions lack these; the resume is then not exact
            self.steps_seen = state["steps_seen"]
            self._gen.set_state(state["generator"])

    def frames_state_dict(self) -> dict:
        """The filled part of the frame buffer and its ring position (up to ~270 MB at 25,600 frames)."""
        n = self.size
        # torch.save writes a view's whole storage: copy a part, keep a full buffer as it is
        filled = {name: t if n == len(t) else t[:n].clone() for name in ("readings", "positions", "labels", "joints")
                  for t in [getattr(self, name)]}
        return {"buffer_size": self.cfg.buffer_size, "size": n, "head": self.head, **filled}

    def load_frames_state_dict(self, frames: dict) -> None:
        if frames["buffer_size"] != self.cfg.buffer_size or frames["readings"].shape[1:] != self.readings.shape[1:]:
            raise ValueError(f"saved frame buffer holds {frames['buffer_size']} frames of "
                             f"{tuple(frames['readings'].shape[1:])}, this perception "
                             f"{self.cfg.buffer_size} of {tuple(self.readings.shape[1:])}")
        n = frames["size"]
        for name in ("readings", "positions", "labels", "joints"):
            getattr(self, name).zero_()[:n] = frames[name]
        self.size, self.head = n, frames["head"]
