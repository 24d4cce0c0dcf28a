"""Perception checkpoints: what a training run writes after every epoch and how it is read back.

A checkpoint is a dict of tensors and plain data (``torch.load(weights_only=True)`` reads
it, so no code runs from a file): ``format_version`` (``CHECKPOINT_VERSION``), ``kind``
("perception"), ``config`` (the whole :class:`PerceptionTrainConfig` as a dict, every key),
``epoch``, ``model`` and ``optimizer`` state, ``history`` (per-epoch metrics), ``dataset``
(path, taxel count, kind, object, frames) and ``rest_positions_cm`` (the GCN's fixed graph;
None for the other models). Single-frame and temporal models share the format; ``config.temporal``
tells them apart.

A file of another format version is refused, naming both versions:
``experiments/convert_checkpoints.py`` converts older files once.
"""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path
from typing import Any

import torch
from torch import nn

from tacgnn.config import ConfigError, from_dict, to_dict
from tacgnn.files import atomic_write, read_weights
from tacgnn.perception.models import PerceptionModelConfig, build_model
from tacgnn.perception.models.temporal import MemoryConfig, TemporalModelConfig, TemporalPerception
from tacgnn.perception.train_config import PerceptionTrainConfig

CHECKPOINT_VERSION = 3  # 3: the training config holds val_fraction and mix
KIND = "perception"
CHECKPOINT_KEYS = ("config", "epoch", "model", "optimizer", "history", "dataset", "rest_positions_cm")
CONVERTER = "experiments/convert_checkpoints.py"


class CheckpointError(ValueError):
    """A file that is not a perception checkpoint, or whose weights do not fit its config; names the file."""


def save_checkpoint(path: Path, payload: dict) -> None:
    """Write `payload` (with the format version and kind) atomically: a killed run leaves the
    previous checkpoint, never half of one."""
    buffer = io.BytesIO()
    torch.save({"format_version": CHECKPOINT_VERSION, "kind": KIND, **payload}, buffer)
    atomic_write(path, lambda fh: fh.write(buffer.getbuffer()))


def check_version(data: Any, path: str | Path, what: str, version: int) -> None:
    """Raise CheckpointError naming the file unless `data` is a dict of format `version`."""
    if not isinstance(data, dict) or "format_version" not in data:
        raise CheckpointError(f"{path}: not a tacgnn {what} (no format_version)")
    if data["format_version"] != version:
        raise CheckpointError(f"{path}: a {what} of format version {data['format_version']!r}, this code reads "
                              f"version {version}; convert it once with `python {CONVERTER} {path}`")


def missing_keys(default: Any, stored: Any, prefix: str = "") -> list[str]:
    """Dotted keys of the config tree `default` (``to_dict`` of a config) that `stored` lacks."""
    if not isinstance(default, dict) or not isinstance(stored, dict):
        return []
    out = []
    for key, value in default.items():
        name = f"{prefix}{key}"
        out += [name] if key not in stored else missing_keys(value, stored[key], f"{name}.")
    return out


def stored_config(cls: type, data: Any, path: str | Path, what: str):
    """Config `cls` from a checkpoint's dict, which must hold every key (none is filled in)."""
    lacking = missing_keys(to_dict(cls()), data) if isinstance(data, dict) else []
    if lacking:
        raise CheckpointError(f"{path}: its {what} lacks keys {lacking}; convert it once with `python {CONVERTER} "
                              f"{path}`")
    try:
        return from_dict(cls, data)
    except ConfigError as err:
        raise CheckpointError(f"{path}: its {what} does not fit this code: {err}") from None


NETWORK_KEYS = ("model", "temporal", "memory")
"""The perception config keys that make the network: weights load only between configs equal in them."""


def network_differences(stored: dict, ours: dict) -> list[str]:
    """The `NETWORK_KEYS` in which a stored perception config (a checkpoint's or a policy's, as a dict)
    and `ours` (``to_dict`` form) make different networks; a key the stored config's version did not
    have yet counts with the default it ran with."""
    defaults = to_dict(PerceptionTrainConfig())
    return [k for k in NETWORK_KEYS if stored.get(k, defaults[k]) != ours[k]]


def load_checkpoint(path: str | Path) -> dict:
    """Read and check a perception checkpoint.

    Raises FileNotFoundError (missing), :class:`tacgnn.files.FileProblem` (empty, truncated,
    not a torch file, or holding objects other than tensors and plain data) and
    :class:`CheckpointError` (a torch file that is not a perception checkpoint of this
    format version), each naming the file.
    """
    payload = read_weights(Path(path), "perception checkpoint")
    if isinstance(payload, dict) and (payload.get("kind") not in (None, KIND) or "actor_state_dict" in payload):
        raise CheckpointError(f"{path}: not a tacgnn perception checkpoint but a {payload.get('kind') or 'policy'} "
                              "file (a policy holds its perception inside)")  # another file of ours: say which
    check_version(payload, path, "perception checkpoint", CHECKPOINT_VERSION)
    if payload.get("kind") != KIND:
        raise CheckpointError(f"{path}: not a tacgnn perception checkpoint (kind {payload.get('kind')!r}; a policy "
                              "holds its perception inside)")
    lacking = [k for k in CHECKPOINT_KEYS if k not in payload]
    if lacking:
        raise CheckpointError(f"{path}: perception checkpoint lacking {lacking}")
    return payload


def build_perception(model: PerceptionModelConfig, temporal: bool, memory: MemoryConfig,
                     rest_positions_cm: torch.Tensor | None = None) -> nn.Module:
    """The frame model of `model`, or (`temporal`) it under a `memory`. The rest positions (cm) are
    read by the GCN only."""
    if temporal:
        return TemporalPerception(TemporalModelConfig.of(model, memory))
    return build_model(model, rest_positions=rest_positions_cm if model.name == "gcn" else None)


def load_model(path: str | Path, temporal: bool | None = None) -> tuple[nn.Module, PerceptionTrainConfig, dict]:
    """The trained model (eval mode), its training config, and the dataset metadata it saw.

    `temporal` = True refuses a single-frame model, False a temporal one (None takes either).
    """
    payload = load_checkpoint(path)
    cfg = stored_config(PerceptionTrainConfig, payload["config"], path, "config")
    if temporal is not None and cfg.temporal != temporal:
        have, want = ("temporal", "single-frame") if cfg.temporal else ("single-frame", "temporal")
        raise CheckpointError(f"{path}: a {have} {cfg.model.name} model (temporal={str(cfg.temporal).lower()}); "
                              f"this needs a {want} one")
    rest = payload["rest_positions_cm"]
    if cfg.model.name == "gcn" and not cfg.temporal and (
            not isinstance(rest, torch.Tensor) or rest.shape != (cfg.model.num_taxels, 3)):
        raise CheckpointError(f"{path}: a GCN checkpoint without the rest positions ({cfg.model.num_taxels}, 3) "
                              "its graph was built from")
    model = build_perception(cfg.model, cfg.temporal, cfg.memory, rest)
    try:
        model.load_state_dict(payload["model"])
    except RuntimeError as err:  # weights of another architecture than the stored config
        first = str(err).strip().splitlines()[0]
        raise CheckpointError(f"{path}: the weights do not fit the model of its config ({first})") from None
    return model.eval(), cfg, payload["dataset"]


def with_taxels(cfg: PerceptionTrainConfig, num_taxels: int) -> PerceptionTrainConfig:
    """`cfg` with its model reading `num_taxels` taxels (a dataset's skin)."""
    if cfg.model.num_taxels == num_taxels:
        return cfg
    return dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, num_taxels=num_taxels))
