"""A trained policy for acting: load it (with its perception), or export the small file the demo ships.

`load_policy` and `load_perception` read a training checkpoint or an exported policy;
evaluation, the demo, dataset recording and the real-hand controller all act through them
(`policy_from_checkpoint` and `perception_from_checkpoint` for a file already read).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from rsl_rl.models import MLPModel
from tensordict import TensorDict

from tacgnn.config import ConfigError, from_dict
from tacgnn.envs.baoding import BaodingConfig
from tacgnn.learning import checkpoint as ckpt
from tacgnn.learning.config import PPOConfig
from tacgnn.learning.online_perception import OnlinePerception, OnlinePerceptionConfig
from tacgnn.perception.checkpoint import load_checkpoint as load_perception_checkpoint
from tacgnn.perception.checkpoint import network_differences, stored_config

ASSETS = Path(__file__).resolve().parent.parent / "assets"
SHIPPED_POLICY = ASSETS / "baoding_policy.pt"
"""The blind policy the demo and the real-hand controller run: Beta actions, a temporal TacGNN in the
loop, trained on hands drawn as real ones differ and on the real skin (docs/results.md, section 11)."""
SHIPPED_GROUND_TRUTH = ASSETS / "baoding_gt_policy.pt"
"""The ground-truth policy shipped beside it: its actor reading the true ball positions
(`export_policy(..., ground_truth=True)`). The policy the blind one was trained from, trained by
PPO on the true positions, is results/real_hand/checkpoints/gt_ppo.pt (`experiments/real_hand/pipeline.sh`)."""


def load_policy(path: str | Path) -> tuple[Callable[[np.ndarray], np.ndarray], BaodingConfig]:
    """The deterministic policy (mean action) of a checkpoint, and the env config it was trained on.

    The policy maps (N, obs_dim) observations to (N, 16) float32 actions, normaliser included.
    Configs and shapes are checked before the weights are loaded; a mismatch raises
    CheckpointError naming the file.
    """
    data = ckpt.load_policy_file(path)
    env_cfg = ckpt.stored_env_config(data, path)
    return policy_from_checkpoint(data, path), env_cfg


def policy_from_checkpoint(data: dict, path: str | Path) -> Callable[[np.ndarray], np.ndarray]:
    """`load_policy`'s policy from a policy file already read (`checkpoint.load_policy_file(path)`),
    for callers that check its configs first; `path` names it in errors."""
    try:
        ppo_cfg = from_dict(PPOConfig, data["ppo_config"])
    except ConfigError as err:
        raise ckpt.CheckpointError(f"checkpoint {path}: its PPO config does not fit this code: {err}") from None
    actor_cfg = dict(ppo_cfg.rsl_rl_cfg()["actor"])
    actor_cfg.pop("class_name")
    example = TensorDict({"policy": torch.zeros(1, data["obs_dim"])}, batch_size=[1])
    actor = MLPModel(example, {"actor": ["policy"]}, "actor", data["num_actions"], **actor_cfg)
    try:
        actor.load_state_dict(data["actor_state_dict"])
    except RuntimeError as err:  # the weights do not fit the network its own config describes
        first = str(err).strip().splitlines()[0]
        raise ckpt.CheckpointError(f"checkpoint {path}: actor weights do not fit its config ({first})") from None
    actor.eval()
    obs_dim = data["obs_dim"]

    def policy(obs: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            x = torch.as_tensor(np.asarray(obs), dtype=torch.float32)
            if x.ndim != 2 or x.shape[1] != obs_dim:
                raise ValueError(f"policy {path} reads ({obs_dim},) observations, got shape {tuple(x.shape)}")
            return actor(TensorDict({"policy": x}, batch_size=[x.shape[0]])).numpy()

    return policy


def load_perception(path: str | Path) -> OnlinePerception | None:
    """The perception a 'perceived' policy was trained with (None for other observation modes)."""
    return perception_from_checkpoint(ckpt.load_policy_file(path), path)


def perception_from_checkpoint(data: dict, path: str | Path = "<policy>") -> OnlinePerception | None:
    """`load_perception` of a policy file already read (`checkpoint.load_policy_file`); its perception
    config must hold every key (a file of an earlier format is converted, not filled in)."""
    if "perception" not in data:
        return None
    state = data["perception"]
    cfg = stored_config(OnlinePerceptionConfig, state["config"], path, "perception config")
    # acting: no pretrained file or anchor to read, no frames to keep
    cfg = replace(cfg, pretrained="", anchor_dataset="",
                  buffer_size=max(cfg.batch_size, cfg.window if cfg.temporal else 1))
    perception = OnlinePerception(cfg, data["env_config"]["skin"])
    perception.model.load_state_dict(state["model"])
    perception.updates = state["updates"]
    return perception


def export_policy(path: str | Path, out: str | Path, perception_from: str | Path | None = None,
                  ground_truth: bool = False) -> Path:
    """Write a small file with what acting needs (actor, configs, perception), not training state.

    A training checkpoint holds the critic, the optimiser and the env state (~5 MB); the
    exported policy is what the demo ships (well under 1 MB) and `load_policy` reads both.
    `path` may be an exported policy too. With `perception_from` (a `train-perception`
    checkpoint of the same network, e.g. trained on the policy's own frames) a blind policy
    acts with that model's weights; its config's `pretrained` names the file. With
    `ground_truth` a blind policy's actor reads the true ball positions instead of its
    perception's (the observation's layout is the same): a ground-truth policy with the blind
    policy's grip (section 11 of the report: gentler than the teacher it was trained from).
    """
    data = ckpt.load_policy_file(path)
    if ground_truth and "perception" not in data:
        raise ConfigError(f"{path}: a policy trained without a perception; a ground-truth export needs a blind one")
    if ground_truth and perception_from is not None:
        raise ConfigError("a ground-truth export reads the true ball positions: it takes no perception")
    slim = {"format_version": ckpt.FORMAT_VERSION, "kind": "policy", "iteration": data["iteration"],
            **{k: data[k] for k in ckpt.POLICY_KEYS}}
    if "perception" in data and not ground_truth:  # a ground-truth export reads no perception
        perception = dict(data["perception"])
        for training_only in ("optimizer", "generator", "steps_seen"):
            perception.pop(training_only, None)
        slim["perception"] = perception
    if perception_from is not None:
        if "perception" not in slim:
            raise ConfigError(f"{path}: a policy trained without a perception; perception_from needs a blind one")
        payload = load_perception_checkpoint(perception_from)
        ours = slim["perception"]["config"]
        differ = network_differences(payload["config"], ours)
        if differ:
            raise ckpt.CheckpointError(f"{perception_from}: its network differs from the policy's perception "
                                       f"in {differ}")
        slim["perception"] = {**slim["perception"], "model": payload["model"],
                              "config": {**ours, "pretrained": str(perception_from)}}
    if ground_truth:
        slim["env_config"] = {**slim["env_config"], "obs_mode": "groundtruth", "tactile": False}
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    ckpt.save(out, slim)
    return out
