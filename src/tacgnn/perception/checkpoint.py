"""Perception checkpoints: what a training run writes after every epoch and how it is read back.

A checkpoint is a dict of tensors and plain data (``torch.load(weights_only=True)`` reads
it, so no code runs from a file): ``format_version``, ``config`` (the training config as a
dict), ``epoch``, ``model`` and ``optimizer`` state, ``history`` (per-epoch metrics),
``dataset`` (path, taxel count, kind, object) and ``rest_positions_cm`` (the GCN's fixed
graph; None for the other models).
"""

from __future__ import annotations

import io
from pathlib import Path

import torch

from tacgnn.config import from_dict
from tacgnn.files import atomic_write, read_weights
from tacgnn.perception.models import PerceptionModel, PerceptionModelConfig, build_model
from tacgnn.perception.train_config import PerceptionTrainConfig

CHECKPOINT_VERSION = 1


class CheckpointError(ValueError):
    """A file that is not a perception checkpoint, or whose weights do not fit its config; names the file."""

#: Values of config keys added after format version 1 was fixed, as checkpoints without them
#: were trained (the paper's setup); filled in on loading, so old checkpoints keep working.
LEGACY_TRAIN_VALUES = {"lr_schedule": "constant", "lr_final": 0.01, "lr_decay": 0.8, "warmup_epochs": 0.0,
                       "init_output_bias": False}
LEGACY_MODEL_VALUES = {"force_feature": "raw", "pos_scale": 1.0, "message_layers": 2, "head_layers": 2,
                       "head_hidden": 0, "residual": False, "pool": "last", "joint_inputs": 0}


def save_checkpoint(path: Path, payload: dict) -> None:
    """Write `payload` atomically: a killed run leaves the previous checkpoint, never half of one."""
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    atomic_write(path, lambda fh: fh.write(buffer.getbuffer()))


def load_checkpoint(path: str | Path) -> dict:
    """Read and check a perception checkpoint.

    Raises FileNotFoundError (missing), :class:`tacgnn.files.FileProblem` (empty, truncated,
    not a torch file, or holding objects other than tensors and plain data) and
    :class:`CheckpointError` (a torch file that is not a perception checkpoint of this
    format), each naming the file.
    """
    path = Path(path)
    payload = read_weights(path, "perception checkpoint")
    if not isinstance(payload, dict) or payload.get("format_version") != CHECKPOINT_VERSION:
        raise CheckpointError(f"{path}: not a tacgnn perception checkpoint of version {CHECKPOINT_VERSION}")
    if payload.get("kind") == "sequence":  # tacgnn.perception.sequence_checkpoint
        temporal = isinstance(payload.get("config"), dict) and payload["config"].get("temporal", True)
        raise CheckpointError(f"{path}: a {'temporal' if temporal else 'sequence-trained'} perception checkpoint "
                              "(train-perception --temporal/--by-episode); this needs a single-frame one")
    if not {"config", "model", "dataset"} <= payload.keys():  # e.g. a policy checkpoint
        raise CheckpointError(f"{path}: not a tacgnn perception checkpoint (no model, config and dataset)")
    config = payload.get("config")
    if isinstance(config, dict):  # written before these keys existed: it was trained with their old values
        for key, value in LEGACY_TRAIN_VALUES.items():
            config.setdefault(key, value)
        if isinstance(config.get("model"), dict):
            for key, value in LEGACY_MODEL_VALUES.items():
                config["model"].setdefault(key, value)
    return payload


def make_model(cfg: PerceptionModelConfig, rest_positions_cm: torch.Tensor | None) -> PerceptionModel:
    """The model of `cfg`; the rest positions (cm) are read by the GCN only."""
    return build_model(cfg, rest_positions=rest_positions_cm if cfg.name == "gcn" else None)


def load_model(path: str | Path) -> tuple[PerceptionModel, PerceptionTrainConfig, dict]:
    """The trained model (eval mode), its training config, and the dataset metadata it saw."""
    payload = load_checkpoint(path)
    cfg = from_dict(PerceptionTrainConfig, payload["config"])
    rest = payload.get("rest_positions_cm")
    if cfg.model.name == "gcn" and (not isinstance(rest, torch.Tensor) or rest.shape != (cfg.model.num_taxels, 3)):
        raise CheckpointError(f"{path}: a GCN checkpoint without the rest positions ({cfg.model.num_taxels}, 3) "
                              "its graph was built from")
    model = make_model(cfg.model, rest)
    try:
        model.load_state_dict(payload["model"])
    except RuntimeError as err:  # weights of another architecture than the stored config
        first = str(err).strip().splitlines()[0]
        raise CheckpointError(f"{path}: the weights do not fit the model of its config ({first})") from None
    return model.eval(), cfg, payload["dataset"]
