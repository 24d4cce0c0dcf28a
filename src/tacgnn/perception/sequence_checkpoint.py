"""Checkpoints of perception models trained on sequences, and the checks that keep the kinds apart.

A sequence checkpoint is a perception checkpoint (``format_version``, ``config``, ``epoch``,
``model``, ``optimizer``, ``history``, ``dataset``) marked ``kind: "sequence"``; its config is
a :class:`SequenceTrainConfig` (``temporal`` tells a temporal model from the single-frame
comparison). A single-frame checkpoint of ``tacgnn train-perception`` has no ``kind``.
Loading one kind where the other is needed fails with a line that says which is which.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch
from torch import nn

from tacgnn.config import ConfigError, from_dict
from tacgnn.files import read_weights
from tacgnn.perception.checkpoint import CHECKPOINT_VERSION, CheckpointError
from tacgnn.perception.models.build import build_model
from tacgnn.perception.models.temporal import TemporalPerception
from tacgnn.perception.sequence_train_config import SequenceTrainConfig

KIND = "sequence"


def build_sequence_model(cfg: SequenceTrainConfig) -> nn.Module:
    """The temporal model of `cfg`, or (``temporal=false``) its frame model with a 6-value output."""
    if cfg.temporal:
        return TemporalPerception(cfg.model)
    return build_model(dataclasses.replace(cfg.model.frame, out_dim=cfg.model.out_dim))


def load_sequence_checkpoint(path: str | Path) -> dict:
    """Read a sequence checkpoint; a single-frame one (or anything else) raises CheckpointError naming the file."""
    path = Path(path)
    payload = read_weights(path, "perception checkpoint")
    if not isinstance(payload, dict) or payload.get("format_version") != CHECKPOINT_VERSION:
        raise CheckpointError(f"{path}: not a tacgnn perception checkpoint of version {CHECKPOINT_VERSION}")
    if payload.get("kind") != KIND:
        if {"config", "model", "dataset"} <= payload.keys():
            name = (payload["config"].get("model") or {}).get("name", "?") if isinstance(payload["config"], dict) \
                else "?"
            raise CheckpointError(f"{path}: a single-frame perception checkpoint ({name}, from train-perception "
                                  "without --temporal); this needs a temporal one (train-perception --temporal)")
        raise CheckpointError(f"{path}: not a sequence perception checkpoint (no kind '{KIND}')")
    missing = [k for k in ("config", "model", "dataset", "epoch") if k not in payload]
    if missing:
        raise CheckpointError(f"{path}: sequence perception checkpoint lacking {missing}")
    return payload


def config_of(payload: dict, path: str | Path) -> SequenceTrainConfig:
    try:
        return from_dict(SequenceTrainConfig, payload["config"])
    except ConfigError as err:
        raise CheckpointError(f"{path}: its config does not fit this code: {err}") from None


def load_sequence_model(path: str | Path, temporal: bool | None = None) -> tuple[nn.Module, SequenceTrainConfig, dict]:
    """The trained model (eval mode), its config and dataset metadata.

    `temporal` = True refuses a single-frame model, False a temporal one (None takes either).
    """
    payload = load_sequence_checkpoint(path)
    cfg = config_of(payload, path)
    if temporal is not None and cfg.temporal != temporal:
        have, want = ("temporal", "single-frame") if cfg.temporal else ("single-frame", "temporal")
        raise CheckpointError(f"{path}: a {have} model ({cfg.model.frame.name}); this needs a {want} one")
    model = build_sequence_model(cfg)
    try:
        model.load_state_dict(payload["model"])
    except RuntimeError as err:
        first = str(err).strip().splitlines()[0]
        raise CheckpointError(f"{path}: the weights do not fit the model of its config ({first})") from None
    return model.eval(), cfg, payload["dataset"]


def is_sequence_checkpoint(path: str | Path) -> bool:
    """Whether `path` is a sequence checkpoint (False for a single-frame one or another file)."""
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # noqa: BLE001 - anything unreadable is not one; the real loader names the problem
        return False
    return isinstance(payload, dict) and payload.get("kind") == KIND
