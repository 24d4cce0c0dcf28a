"""Perception trained in the loop: the policy sees the ball positions the skin predicts.

The paper's two-stage workflow, as one object handed to the env and the PPO loop, for a
single-frame model or a temporal one (a filter per env that carries the balls through the
blind area):

    act: BaodingEnv(obs_mode='perceived', perception=p) asks p(readings, taxel_pos[, joints])
         for the ball positions of every env at every step (no gradient reaches the policy).
         A temporal p tells a step of all envs from the envs just reset by the env's step
         counters (a reset env is at step 0), steps those envs' state, starts a reset env's
         state fresh (the reset frame is read, not kept), and reads the joint angles and the
         previous action beside the skin;
    record: p.record(info) keeps the newest `buffer_size` skin frames with their true ball
         positions (a ring buffer); a temporal p keeps their episode and step too;
    learn: every `update_every_steps` env steps, p.update() trains the model for `epochs`
         passes over the buffer (Adam, MSE, permutation-invariant over the balls): windows of
         one frame, or for a temporal model windows of `window` consecutive frames with the
         state warmed up over up to `burn_in` earlier frames of the episode without gradient
         (`tacgnn.perception.training.window_loss`).

The model may start from a perception checkpoint trained offline (`pretrained`, the
"privileged route": rollouts of a ground-truth policy make its dataset) or from scratch. The
per-env state and episode counters are part of `state_dict`, so a resumed run continues bit
for bit. A temporal p must be bound (`bind_env`) to the envs it reads before they observe:
`BaodingEnv(perception=...)` binds it, and the real-hand `BlindController` binds it to the one
hand it drives.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
import torch

from tacgnn.config import ConfigError, check, from_dict, to_dict
from tacgnn.datasets.store import DatasetError
from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.perception.checkpoint import build_perception, load_checkpoint, stored_config
from tacgnn.perception.data import TactileData, load_tactile
from tacgnn.perception.evaluation import predict
from tacgnn.perception.models import PerceptionModelConfig
from tacgnn.perception.models.temporal import FRAME_MODELS, MemoryConfig, TemporalPerception
from tacgnn.perception.objectives import Objective
from tacgnn.perception.rest_positions import rest_positions_cm
from tacgnn.perception.sequences import SequenceData, as_sequence, load_sequences
from tacgnn.perception.train_config import PerceptionTrainConfig
from tacgnn.perception.training import backward_checked, epoch_order, window_loss, window_starts

InputArray = np.ndarray | torch.Tensor
"""A skin array as the env hands it out: numpy (C engine) or a tensor on the Warp engine's device."""
ACTIONS = 16
FRAME_FIELDS = ("readings", "positions", "labels", "joints")
SEQUENCE_FIELDS = ("actions", "episode", "step")


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
    """The frame model (with `temporal`, the encoder under the memory)."""
    update_every_steps: int = 100
    """Env steps (per env) between perception updates: 100 x 256 envs = 25,600 new frames."""
    epochs: int = 10
    """Passes over the buffer per update (the paper: 10)."""
    buffer_size: int = 25_600
    batch_size: int = 32
    """Frames in the loss per step (a temporal model: batch_size / window windows)."""
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
    """A GRU filter over the frame model (`memory`), its state kept per env and reset at each
    episode's start; it learns from windows of consecutive recorded frames."""
    memory: MemoryConfig = field(default_factory=MemoryConfig)
    """temporal: the filter's widths and side inputs."""
    window: int = 16
    """temporal: frames per training window (truncated back-propagation through time)."""
    burn_in: int = 64
    """temporal: recorded frames before a window that bring the state up without gradient."""
    anchor_dataset: str = ""
    """A Baoding dataset (e.g. the teacher's frames, `tacgnn make-dataset baoding`) mixed into
    every update, so that the model keeps fitting frames other than the blind policy's own,
    which alone it fits at the cost of others (docs/results.md, section 6); '' = the buffer alone.
    A temporal model draws windows of its episodes (a dataset made with ``--keep-every 1``)."""
    anchor_share: float = 0.5
    """With `anchor_dataset`: the share of each update's samples (frames or windows) drawn from it."""

    def __post_init__(self) -> None:
        check(self.model.out_dim == 6, "perception.model.out_dim", "ball positions are 6 values")
        if self.temporal:
            check(self.record_every == 1, "perception.record_every", "must be 1 with temporal (windows of consecutive "
                  f"steps), got {self.record_every}")
            check(self.model.joint_inputs == 0, "perception.model.joint_inputs",
                  "must be 0 with temporal: the temporal model reads the joint angles itself")
            check(self.model.name in FRAME_MODELS, "perception.model.name",
                  f"a temporal model's frame encoder is one of {FRAME_MODELS}, got {self.model.name!r}")
            check(1 <= self.window <= self.buffer_size, "perception.window",
                  f"must be in 1..buffer_size ({self.buffer_size}), got {self.window}")
            check(self.burn_in >= 0, "perception.burn_in", f"must be >= 0, got {self.burn_in}")
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
            check(self.temporal or self.model.joint_inputs == 0, "perception.anchor_dataset",
                  "mixes single frames of skin alone: not with joint_inputs")
        check(self.buffer_size <= 1_000_000, "perception.buffer_size",  # 16 bytes per taxel and frame: 10 GB
              f"must be <= 1,000,000, got {self.buffer_size}")


def with_pretrained(cfg: OnlinePerceptionConfig, num_taxels: int) -> tuple[OnlinePerceptionConfig, dict | None]:
    """`cfg` with the architecture of its `pretrained` checkpoint, and that checkpoint's weights (None
    without one); a checkpoint of another task, skin, model or kind is refused, naming the key."""
    if not cfg.pretrained:
        return cfg, None
    payload = load_checkpoint(cfg.pretrained)
    stored = stored_config(PerceptionTrainConfig, payload["config"], cfg.pretrained, "config")
    where = f"perception.pretrained {cfg.pretrained}"
    if stored.task != "baoding":
        raise ConfigError(f"{where}: a perception trained for the {stored.task!r} task; the Baoding env needs one "
                          "that predicts ball positions ('baoding')")
    if stored.temporal != cfg.temporal:
        have = "temporal" if stored.temporal else "single-frame"
        raise ConfigError(f"{where}: a {have} perception checkpoint; perception.temporal is "
                          f"{str(cfg.temporal).lower()}")
    trained_on = payload["dataset"].get("num_taxels")
    if trained_on is not None and trained_on != num_taxels:
        raise ConfigError(f"{where}: trained on a skin of {trained_on} taxels, this env's skin has {num_taxels}")
    if stored.model.name != cfg.model.name:  # the checkpoint defines the architecture, the config names its kind
        raise ConfigError(f"{where}: a {stored.model.name} model, perception.model.name asks for {cfg.model.name}")
    return dataclasses.replace(cfg, model=stored.model, memory=stored.memory), payload["model"]


class OnlinePerception:
    """Callable perception for `BaodingEnv(perception=...)` that learns from what it records."""

    def __init__(self, cfg: OnlinePerceptionConfig, skin: dict, seed: int = 0):
        num_taxels = from_dict(SkinLayout, skin).num_taxels
        cfg, weights = with_pretrained(cfg, num_taxels)
        self.cfg = cfg
        model_cfg = dataclasses.replace(cfg.model, num_taxels=num_taxels)
        self._rest = rest_positions_cm(skin) if model_cfg.name == "gcn" and not cfg.temporal else None
        torch.manual_seed(seed)
        self.model = build_perception(model_cfg, cfg.temporal, cfg.memory, self._rest)
        if weights is not None:
            self.model.load_state_dict(weights)
        self.optim = torch.optim.Adam(self.model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        self.objective = Objective("baoding", cfg.match_balls)
        self.temporal = isinstance(self.model, TemporalPerception)
        # the env hands the joint angles to a perception that reads them
        self.joint_inputs = cfg.memory.joints if cfg.temporal else model_cfg.joint_inputs
        n = cfg.buffer_size
        self.readings, self.positions = torch.zeros(n, num_taxels), torch.zeros(n, num_taxels, 3)
        self.labels, self.joints = torch.zeros(n, 6), torch.zeros(n, self.joint_inputs)
        self.actions = torch.zeros(n, ACTIONS)
        self.episode, self.step = torch.full((n,), -1, dtype=torch.long), torch.zeros(n, dtype=torch.long)
        self.size, self.head, self.steps_seen, self.updates = 0, 0, 0, 0
        self._gen = torch.Generator().manual_seed(seed)
        self.env = None
        state_dim = self.model.state_dim if isinstance(self.model, TemporalPerception) else 0
        self.state = torch.zeros(0, state_dim)
        self.episode_of_env = torch.zeros(0, dtype=torch.long)
        self.window = cfg.window if self.temporal else 1
        self.burn_in = cfg.burn_in if self.temporal else 0
        self.windows_per_step = max(1, round(cfg.batch_size / cfg.window)) if self.temporal else cfg.batch_size
        self._anchor_starts = torch.zeros(0, dtype=torch.long)  # temporal: where anchor windows can start
        self.anchor = self._load_anchor(cfg.anchor_dataset, num_taxels) if cfg.anchor_dataset else None
        self._anchor_batch = round(cfg.batch_size * cfg.anchor_share / (1 - cfg.anchor_share))

    # --- acting --------------------------------------------------------------------------
    def bind_env(self, env) -> None:
        """Keep one state per env of `env` (a `BaodingEnv`), all fresh; its step counters and last
        actions tell a temporal model which envs a call is about and what they were commanded."""
        self.env = env
        if isinstance(self.model, TemporalPerception):
            self.state = self.model.initial_state(env.num_envs).detach()
            self.episode_of_env = torch.arange(env.num_envs, dtype=torch.long)

    @torch.inference_mode()
    def __call__(self, readings: InputArray, taxel_pos: InputArray, joints: np.ndarray | None = None) -> np.ndarray:
        """(M, 6) ball positions in metres from (M, T) readings, (M, T, 3) positions in metres and,
        for a model that reads them, (M, 16) joint angles in rad; numpy, or tensors as the Warp skin
        leaves them on its device. A temporal model answers for all N envs after a step, or for the
        M envs just reset (at step 0)."""
        if self.model.training:  # eval() walks every submodule, a tenth to a fifth of a one-frame call
            self.model.eval()
        inputs = [model_input(readings), model_input(taxel_pos, 100.0)]
        if not isinstance(self.model, TemporalPerception):
            out = self.model(*inputs, *([] if joints is None else [model_input(joints)]))
            return out.cpu().numpy().astype(np.float64) / 100.0
        env = self.env
        if env is None:
            raise RuntimeError("a temporal perception keeps one state per env: bind it first "
                               "(perception.bind_env(env)) before the env observes")
        if joints is None:
            raise ValueError("a temporal perception reads the joint angles: pass joints (M, 16)")
        rows, n = len(readings), env.num_envs
        fresh = np.flatnonzero(env.episode_steps == 0)
        if len(fresh) == rows:  # reset envs (all of them after env.reset()): start their state afresh
            ids, keep_state = fresh, False
            self.state[ids] = self.model.initial_state(len(ids))
        elif rows == n:
            ids, keep_state = np.arange(n), True
        else:
            raise RuntimeError(f"the env asked for the balls of {rows} envs, but {len(fresh)} of its {n} envs "
                               "are at their episode's start: a temporal perception cannot tell which envs "
                               "these frames belong to")
        out, new_state = self.model.step(*inputs, model_input(joints), model_input(env.last_action[ids]),
                                         self.state[ids])
        if keep_state:
            self.state[ids] = new_state
        return out.cpu().numpy().astype(np.float64) / 100.0

    # --- recording -----------------------------------------------------------------------
    def record(self, info: dict) -> None:
        """Keep this step's frames of envs whose episode goes on (a fall's last frame is noise).

        A temporal model keeps each frame's episode and step, counting episodes so that frames
        of two episodes of one env are never one window; an env that ended was reset in the
        same step, so its frame's command is gone: its last frame is left out (as the datasets
        leave it out).
        """
        self.steps_seen += 1
        if self.steps_seen % self.cfg.record_every:
            return
        done = info["fall"] | info["diverged"]
        if self.temporal:
            done = done | info["success"] | info["timeout"]
        ids = np.flatnonzero(~done)
        rows = torch.from_numpy(ids)
        idx = (self.head + torch.arange(len(ids))) % self.cfg.buffer_size
        self.readings[idx] = model_input(info["tactile"])[rows]
        self.positions[idx] = model_input(info["taxel_pos"], 100.0)[rows]
        self.labels[idx] = torch.from_numpy((info["ball_pos"][ids].reshape(-1, 6) * 100.0).astype(np.float32))
        if self.joint_inputs:
            self.joints[idx] = torch.from_numpy(info["joint_pos"][ids]).float()
        if self.temporal:
            if self.env is not None:  # the command of this step
                self.actions[idx] = torch.from_numpy(np.asarray(self.env.last_action)[ids]).float()
                self.episode[idx] = self.episode_of_env[ids]
                self.episode_of_env += torch.from_numpy(done) * len(self.episode_of_env)  # env e's k-th: e + k N
            else:  # recorded without an env bound: one env per row, episodes told apart by their steps
                self.actions[idx] = 0.0
                self.episode[idx] = torch.from_numpy(ids)
            self.step[idx] = torch.from_numpy(info["episode_steps"][ids])
        self.head = int((self.head + len(ids)) % self.cfg.buffer_size)
        self.size = min(self.cfg.buffer_size, self.size + len(ids))

    def _data(self) -> SequenceData:
        """The buffer's frames: in ring order, each its own episode; a temporal model's frames of
        live episodes sorted by (episode, step)."""
        n = self.size
        if not self.temporal:
            joints = self.joints[:n] if self.joint_inputs else None
            return as_sequence(TactileData(self.readings[:n], self.positions[:n], self.labels[:n], joints))
        live = (self.episode[:n] >= 0).nonzero().squeeze(1)
        order = live[torch.from_numpy(np.lexsort((self.step[live].numpy(), self.episode[live].numpy())))]
        frames = TactileData(self.readings[order], self.positions[order], self.labels[order], self.joints[order])
        return SequenceData(frames, self.actions[order], self.episode[order], self.step[order])

    def _load_anchor(self, path: str, num_taxels: int) -> TactileData | SequenceData:
        """The anchor frames (a temporal model's: its episodes), or a `ConfigError` naming the key when
        the dataset is missing, broken, of another skin or (temporal) without episodes of a window."""
        try:
            anchor = load_sequences(path) if self.temporal else load_tactile(path, "baoding")
            if isinstance(anchor, SequenceData):
                self._anchor_starts = window_starts(anchor, self.window)
        except (DatasetError, ConfigError) as err:
            raise ConfigError(f"perception.anchor_dataset: {err}") from None
        taxels = (anchor.frames if isinstance(anchor, SequenceData) else anchor).readings.shape[1]
        if taxels != num_taxels:
            raise ConfigError(f"perception.anchor_dataset {path}: frames of {taxels} taxels, this env's skin has "
                              f"{num_taxels}")
        return anchor

    def _loss(self, data: SequenceData, starts: torch.Tensor) -> torch.Tensor:
        """The loss of windows at `starts`, with `anchor_share` of the samples from the anchor: frames
        alone beside frames, or (temporal) windows of its episodes, weighted by their share."""
        if not isinstance(self.anchor, TactileData):  # no anchor, or an anchor of episodes
            own = window_loss(self.model, data, starts, self.window, self.burn_in, self.objective)
            if self.anchor is None:
                return own
            share = self.cfg.anchor_share
            k = max(1, round(len(starts) * share / (1 - share)))
            pick = self._anchor_starts[torch.randint(len(self._anchor_starts), (k,), generator=self._gen)]
            theirs = window_loss(self.model, self.anchor, pick, self.window, self.burn_in, self.objective)
            return (1 - share) * own + share * theirs
        a = torch.randint(len(self.anchor), (self._anchor_batch,), generator=self._gen)
        readings = torch.cat([data.frames.readings[starts], self.anchor.readings[a]])
        positions = torch.cat([data.frames.positions[starts], self.anchor.positions[a]])
        labels = torch.cat([data.frames.targets[starts], self.anchor.targets[a]])
        return self.objective.loss(self.model(readings, positions), labels)

    # --- learning ------------------------------------------------------------------------
    def update(self) -> dict[str, float]:
        """Train `epochs` passes over the buffer's windows; the RMSE (cm) on up to 4096 recorded frames
        (a temporal model reads them from their episode's first recorded frame), before and after."""
        torch.set_num_threads(self.cfg.threads)
        data = self._data()
        if len(data) < self.cfg.batch_size and not self.temporal:
            return {}
        try:
            starts = window_starts(data, self.window)
        except ConfigError:
            return {}  # no episode has `window` recorded frames yet
        if not len(starts):
            return {}
        before = self._rmse(data)
        self.model.train()
        per_pass = max(1, math.ceil(len(data) / (self.window * self.windows_per_step)))
        # frames alone: every frame once per pass (the last batch partial); windows: full batches
        draws = len(starts) if not self.temporal else per_pass * self.windows_per_step
        for _ in range(self.cfg.epochs):
            order = epoch_order(starts, draws, self._gen)
            for b in range(per_pass):
                loss = self._loss(data, order[b * self.windows_per_step:(b + 1) * self.windows_per_step])
                backward_checked(self.optim, loss, f"in perception update {self.updates + 1} (in-loop training)")
                self.optim.step()
        self.updates += 1
        return {"perception/rmse_cm_before": before, "perception/rmse_cm_after": self._rmse(data),
                "perception/buffer": float(len(data))}

    def _rmse(self, data: SequenceData) -> float:
        """Position RMSE (cm) on the frames of randomly chosen episodes, up to 4096 frames."""
        episodes = data.episodes()
        counts = torch.bincount(torch.searchsorted(episodes, data.episode), minlength=len(episodes))
        chosen = episodes[torch.randperm(len(episodes), generator=torch.Generator().manual_seed(0))]
        keep = chosen[:max(1, int((torch.cumsum(counts[torch.searchsorted(episodes, chosen)], 0) <= 4096).sum()))]
        part = data.subset(torch.isin(data.episode, keep).nonzero().squeeze(1))
        # in chunks of the rollout's batch size: a GCN builds (and caches) one adjacency per size
        pred = predict(self.model, part, frames_per_batch=256)
        return self.objective.metrics(pred, part.frames.targets)["position_rmse_cm"]

    # --- checkpoints ---------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Model, optimiser, counters, random stream and the per-env filter state; the frame buffer
        is `frames_state_dict`."""
        return {"config": to_dict(self.cfg), "model": self.model.state_dict(),
                "optimizer": self.optim.state_dict(), "updates": self.updates,
                "rest_positions_cm": self._rest, "steps_seen": self.steps_seen,
                "generator": self._gen.get_state(), "env_state": self.state.clone(),
                "episode_of_env": self.episode_of_env.clone()}

    def load_state_dict(self, state: dict) -> None:
        if tuple(state["env_state"].shape[1:]) != tuple(self.state.shape[1:]):
            raise ConfigError("the saved perception state is of a "
                              f"{'temporal' if state['env_state'].shape[1] else 'single-frame'} perception, this run's "
                              f"is {'temporal' if self.temporal else 'single-frame'} (perception.temporal differs)")
        if self.temporal and tuple(state["env_state"].shape) != tuple(self.state.shape):
            raise ValueError(f"saved temporal state {tuple(state['env_state'].shape)}, this perception's "
                             f"{tuple(self.state.shape)} (another num_envs or model)")
        self.model.load_state_dict(state["model"])
        self.optim.load_state_dict(state["optimizer"])
        self.updates, self.steps_seen = state["updates"], state["steps_seen"]
        self._gen.set_state(state["generator"])
        if self.temporal:
            self.state.copy_(state["env_state"])
            self.episode_of_env.copy_(state["episode_of_env"])

    def _fields(self) -> tuple[str, ...]:
        return FRAME_FIELDS + SEQUENCE_FIELDS if self.temporal else FRAME_FIELDS

    def frames_state_dict(self) -> dict:
        """The filled part of the frame buffer and its ring position (up to ~270 MB at 25,600 frames)."""
        n = self.size
        # torch.save writes a view's whole storage: copy a part, keep a full buffer as it is
        filled = {name: t if n == len(t) else t[:n].clone() for name in self._fields() for t in [getattr(self, name)]}
        return {"buffer_size": self.cfg.buffer_size, "size": n, "head": self.head, **filled}

    def load_frames_state_dict(self, frames: dict) -> None:
        if frames["buffer_size"] != self.cfg.buffer_size or frames["readings"].shape[1:] != self.readings.shape[1:]:
            raise ValueError(f"saved frame buffer holds {frames['buffer_size']} frames of "
                             f"{tuple(frames['readings'].shape[1:])}, this perception "
                             f"{self.cfg.buffer_size} of {tuple(self.readings.shape[1:])}")
        n = frames["size"]
        for name in self._fields():
            buffer = getattr(self, name)
            if name in FRAME_FIELDS:
                buffer.zero_()
            buffer[:n] = frames[name]
        self.size, self.head = n, frames["head"]
