"""Temporal perception in the loop: a filter per env that carries the balls through the blind area.

As `tacgnn.learning.online_perception` for a single-frame model, with three differences:

    act: the env asks for the balls of all envs after a step, or of the envs it has just reset;
         the perception tells the two apart by the env's step counters (a reset env is at step 0),
         steps the state of those envs, and starts a reset env's state fresh (the reset frame is
         read, not kept: the episode's first step is the state's first frame, as in the datasets);
         it reads the joint angles and the previous action (the step's command) beside the skin;
    record: frames with their episode and step, so windows of consecutive frames can be drawn;
    learn: windows of `window` frames, the state warmed up over up to `burn_in` earlier frames
         of the same episode without gradient (`tacgnn.perception.sequence_training`).

The per-env state and episode counters are part of `state_dict`, so a resumed run continues
bit for bit. It must be bound (`bind_env`) to the envs it reads before they observe:
`BaodingEnv(perception=...)` binds it, and the real-hand `BlindController` binds it to the
one hand it drives.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from tacgnn.config import ConfigError, from_dict, to_dict
from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.learning.online_perception import InputArray, OnlinePerception, OnlinePerceptionConfig, model_input
from tacgnn.perception.data import TactileData
from tacgnn.perception.models.temporal import TemporalModelConfig, TemporalPerception
from tacgnn.perception.objectives import Objective
from tacgnn.perception.sequence_checkpoint import load_sequence_checkpoint, load_sequence_model
from tacgnn.perception.sequence_evaluation import sequence_predictions
from tacgnn.perception.sequence_train_config import SequenceTrainConfig
from tacgnn.perception.sequence_training import window_loss
from tacgnn.perception.sequences import SequenceData, window_starts
from tacgnn.perception.training import backward_checked

ACTIONS = 16


def make_online_perception(cfg: OnlinePerceptionConfig, skin: dict, seed: int = 0) -> OnlinePerception:
    """The in-loop perception of `cfg`: temporal or single-frame."""
    return TemporalOnlinePerception(cfg, skin, seed) if cfg.temporal else OnlinePerception(cfg, skin, seed)


class TemporalOnlinePerception(OnlinePerception):
    """Callable temporal perception for `BaodingEnv(perception=...)`, one state per env."""

    def __init__(self, cfg: OnlinePerceptionConfig, skin: dict, seed: int = 0):  # noqa: D107 - the base's init is not run
        num_taxels = from_dict(SkinLayout, skin).num_taxels
        model_cfg = TemporalModelConfig(frame=dataclasses.replace(cfg.model, num_taxels=num_taxels),
                                        feature=cfg.temporal_feature, hidden=cfg.temporal_hidden)
        pretrained = None
        if cfg.pretrained:
            # a single-frame checkpoint is refused here, naming it (load_sequence_checkpoint)
            _, stored, meta = load_sequence_model(cfg.pretrained, temporal=True)
            if meta.get("num_taxels") not in (None, num_taxels):
                raise ConfigError(f"perception.pretrained {cfg.pretrained}: trained on a skin of "
                                  f"{meta.get('num_taxels')} taxels, this env's skin has {num_taxels}")
            if stored.model.frame.name != cfg.model.name:
                raise ConfigError(f"perception.pretrained {cfg.pretrained}: a temporal {stored.model.frame.name} "
                                  f"model, perception.model.name asks for {cfg.model.name}")
            model_cfg = stored.model  # the checkpoint defines the architecture
            cfg = dataclasses.replace(cfg, model=stored.model.frame, temporal_feature=stored.model.feature,
                                      temporal_hidden=stored.model.hidden)
            pretrained = load_sequence_checkpoint(cfg.pretrained)["model"]
        self.cfg = cfg
        self._rest = None
        torch.manual_seed(seed)
        self.filter = TemporalPerception(model_cfg)
        self.model = self.filter  # type: ignore[assignment]  # the base's optimiser and checkpoints use `model`
        if pretrained is not None:
            self.model.load_state_dict(pretrained)
        self.optim = torch.optim.Adam(self.model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        self.objective = Objective("baoding", cfg.match_balls)
        self.joint_inputs = model_cfg.joints  # the env hands the joint angles to a perception that reads them
        n = cfg.buffer_size
        self.readings = torch.zeros(n, num_taxels)
        self.positions = torch.zeros(n, num_taxels, 3)
        self.labels = torch.zeros(n, 6)
        self.joints = torch.zeros(n, model_cfg.joints)
        self.actions = torch.zeros(n, ACTIONS)
        self.episode = torch.full((n,), -1, dtype=torch.long)
        self.step = torch.zeros(n, dtype=torch.long)
        self.size, self.head, self.steps_seen, self.updates = 0, 0, 0, 0
        self._gen = torch.Generator().manual_seed(seed)
        self.env = None
        self.state = torch.zeros(0, self.filter.state_dim)
        self.episode_of_env = torch.zeros(0, dtype=torch.long)
        self.train_cfg = SequenceTrainConfig(model=model_cfg, window=cfg.window, burn_in=cfg.burn_in,
                                             batch_size=max(1, round(cfg.batch_size / cfg.window)),
                                             match_balls=cfg.match_balls)

    # --- acting --------------------------------------------------------------------------
    def bind_env(self, env) -> None:
        """Keep one state per env of `env` (a `BaodingEnv`), all fresh; its step counters and last
        actions tell which envs a call is about and what they were commanded."""
        self.env = env
        self.state = self.filter.initial_state(env.num_envs).detach()
        self.episode_of_env = torch.arange(env.num_envs, dtype=torch.long)

    @torch.inference_mode()
    def __call__(self, readings: InputArray, taxel_pos: InputArray, joints: np.ndarray | None = None) -> np.ndarray:
        """(M, 6) ball positions (m) of the envs this call is about: all N after a step, or the M
        envs just reset (at step 0). Inputs as `OnlinePerception.__call__`, joint angles required."""
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
            self.state[ids] = self.filter.initial_state(len(ids))
        elif rows == n:
            ids, keep_state = np.arange(n), True
        else:
            raise RuntimeError(f"the env asked for the balls of {rows} envs, but {len(fresh)} of its {n} envs "
                               "are at their episode's start: a temporal perception cannot tell which envs "
                               "these frames belong to")
        self._to_eval()
        out, new_state = self.filter.step(model_input(readings), model_input(taxel_pos, 100.0), model_input(joints),
                                          model_input(env.last_action[ids]), self.state[ids])
        if keep_state:
            self.state[ids] = new_state
        return out.cpu().numpy().astype(np.float64) / 100.0

    # --- recording -----------------------------------------------------------------------
    def record(self, info: dict) -> None:
        """Keep this step's frames (with episode and step) of envs whose episode goes on; count
        episodes so that frames of two episodes of one env are never one window.

        An env that ended was reset in the same step, so its frame's command is gone: its last
        frame is left out (as the datasets leave it out).
        """
        self.steps_seen += 1
        done = info["success"] | info["fall"] | info["timeout"] | info["diverged"]
        ids = np.flatnonzero(~done)
        idx = (self.head + torch.arange(len(ids))) % self.cfg.buffer_size
        rows = torch.from_numpy(ids)
        self.readings[idx] = model_input(info["tactile"])[rows]
        self.positions[idx] = model_input(info["taxel_pos"], 100.0)[rows]
        self.labels[idx] = torch.from_numpy((info["ball_pos"][ids].reshape(-1, 6) * 100.0).astype(np.float32))
        self.joints[idx] = torch.from_numpy(info["joint_pos"][ids]).float()
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

    def _sequences(self) -> SequenceData:
        """The buffer's frames of live episodes, sorted by (episode, step)."""
        n = self.size
        live = (self.episode[:n] >= 0).nonzero().squeeze(1)
        order = live[torch.from_numpy(np.lexsort((self.step[live].numpy(), self.episode[live].numpy())))]
        frames = TactileData(self.readings[order], self.positions[order], self.labels[order], self.joints[order])
        return SequenceData(frames, self.actions[order], self.episode[order], self.step[order])

    # --- learning ------------------------------------------------------------------------
    def update(self) -> dict[str, float]:
        """Train `epochs` passes over the buffer's windows; the RMSE (cm) on up to 4096 recorded frames,
        read from their episode's first recorded frame, before and after."""
        torch.set_num_threads(self.cfg.threads)
        data = self._sequences()
        try:
            starts = window_starts(data, self.cfg.window)
        except ConfigError:
            return {}  # no episode has `window` recorded frames yet
        before = self._sequence_rmse(data)
        self.model.train()
        cfg = self.train_cfg
        per_pass = max(1, math.ceil(len(data) / (cfg.window * cfg.batch_size)))
        for _ in range(self.cfg.epochs):
            order = starts[torch.randperm(len(starts), generator=self._gen)]
            order = order.repeat(-(-per_pass * cfg.batch_size // len(order)))
            for b in range(per_pass):
                batch = order[b * cfg.batch_size:(b + 1) * cfg.batch_size]
                loss = window_loss(self.filter, data, batch, cfg, self.objective)
                backward_checked(self.optim, loss, f"in perception update {self.updates + 1} (in-loop training)")
                self.optim.step()
        self.updates += 1
        return {"perception/rmse_cm_before": before, "perception/rmse_cm_after": self._sequence_rmse(data),
                "perception/buffer": float(len(data))}

    def _sequence_rmse(self, data: SequenceData) -> float:
        episodes = data.episodes()
        counts = torch.bincount(torch.searchsorted(episodes, data.episode), minlength=len(episodes))
        chosen = episodes[torch.randperm(len(episodes), generator=torch.Generator().manual_seed(0))]
        keep = chosen[:max(1, int((torch.cumsum(counts[torch.searchsorted(episodes, chosen)], 0) <= 4096).sum()))]
        part = data.subset(torch.isin(data.episode, keep).nonzero().squeeze(1))
        pred = sequence_predictions(self.filter, self.train_cfg, part)
        return self.objective.metrics(pred, part.frames.targets)["position_rmse_cm"]

    # --- checkpoints ---------------------------------------------------------------------
    def state_dict(self) -> dict:
        """As `OnlinePerception.state_dict`, plus the per-env filter state and episode counters."""
        return {**super().state_dict(), "temporal_model": to_dict(self.filter.cfg), "env_state": self.state.clone(),
                "episode_of_env": self.episode_of_env.clone()}

    def load_state_dict(self, state: dict) -> None:
        if "env_state" not in state:
            raise ConfigError("the saved perception state is of a single-frame perception; this run's is temporal "
                              "(perception.temporal differs)")
        super().load_state_dict(state)
        if tuple(state["env_state"].shape) != tuple(self.state.shape):
            raise ValueError(f"saved temporal state {tuple(state['env_state'].shape)}, this perception's "
                             f"{tuple(self.state.shape)} (another num_envs or model)")
        self.state.copy_(state["env_state"])
        self.episode_of_env.copy_(state["episode_of_env"])

    def frames_state_dict(self) -> dict:
        frames = super().frames_state_dict()
        n = self.size
        for name in ("actions", "episode", "step"):
            t = getattr(self, name)
            frames[name] = t if n == len(t) else t[:n].clone()
        return frames

    def load_frames_state_dict(self, frames: dict) -> None:
        super().load_frames_state_dict(frames)
        n = frames["size"]
        for name in ("actions", "episode", "step"):
            getattr(self, name)[:n] = frames[name]
