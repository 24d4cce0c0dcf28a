"""Convert perception checkpoints (format versions 1 and 2) and policy files (version 1) to the current format.

    .venv/bin/python experiments/convert_checkpoints.py FILE_OR_FOLDER... [--out-dir DIR] [--dry-run]

Takes `train-perception` checkpoints (single-frame, `--by-episode` or `--temporal`), PPO training
checkpoints (`model_*.pt`) and exported policies; a folder is searched for `*.pt` files (frame
buffers, `perception_frames_*.pt`, need no conversion and are left alone). A file already in the
current format is reported and left as it is. Writes are atomic; with `--out-dir` the converted
files go there (same names) and the originals stay.

Version 1 files left some config keys out and were read with the values those keys had before
they existed; here, and only here, those values are written into the file:

* a perception model config: the paper's TacGNN settings that were the model defaults then
  (``V1_MODEL_DEFAULTS``); a single-frame training config: ``V1_TRAIN_DEFAULTS``;
* a sequence checkpoint (`--temporal` / `--by-episode`) becomes a training config with
  ``split=episode`` (``window=1 burn_in=0`` for the single-frame model) and its memory widths;
* a policy's perception config: the in-loop defaults of version 1 (``V1_ONLINE_DEFAULTS``),
  ``temporal_feature`` / ``temporal_hidden`` as ``memory.feature`` / ``memory.hidden``, and its
  per-env state (empty for a single-frame perception).

A version 2 perception checkpoint lacks the training keys added since (``V2_TRAIN_ADDITIONS``: no
validation split, no mixed datasets, as it was trained). The weights are not touched.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import torch

import tacgnn.learning.checkpoint as ckpt
from tacgnn.config import ConfigError, from_dict, to_dict
from tacgnn.files import read_weights
from tacgnn.learning.online_perception import OnlinePerceptionConfig
from tacgnn.perception import checkpoint as pckpt
from tacgnn.perception.checkpoint import CheckpointError
from tacgnn.perception.train_config import PerceptionTrainConfig
from tacgnn.user_errors import run_script

#: PerceptionModelConfig's defaults in format version 1 (the paper's TacGNN).
V1_MODEL_DEFAULTS: dict[str, Any] = {
    "name": "tacgnn", "out_dim": 6, "num_taxels": 653, "channels": 32, "k": [3, 3, 3], "sample_ratio": 0.5,
    "downsample_layers": [0, 1, 2], "use_force": False, "self_loop": False, "fps_start": "centroid",
    "exact_graph": False, "force_feature": "raw", "pos_scale": 1.0, "message_layers": 2, "head_layers": 2,
    "head_hidden": 0, "residual": False, "pool": "last", "joint_inputs": 0, "reading_feature": "raw",
    "mlp_hidden": [64, 64], "image_size": 36, "gcn_k": 6, "gcn_channels": [32, 32, 32],
    "gcn_node_positions": "current"}
#: Single-frame training keys that version 1 files may lack, with the values such files were trained with.
V1_TRAIN_DEFAULTS: dict[str, Any] = {
    "task": "baoding", "epochs": 10, "batch_size": 32, "lr": 3e-3, "weight_decay": 1e-5, "train_fraction": 0.8,
    "max_samples": 0, "seed": 0, "threads": 1, "match_balls": True, "lr_schedule": "constant", "lr_final": 0.01,
    "lr_decay": 0.8, "warmup_epochs": 0.0, "init_output_bias": False}
#: The in-loop perception config's defaults in version 1.
V1_ONLINE_DEFAULTS: dict[str, Any] = {
    "update_every_steps": 100, "epochs": 10, "buffer_size": 25_600, "batch_size": 32, "lr": 1e-3,
    "weight_decay": 1e-5, "pretrained": "", "record_every": 1, "threads": 1, "match_balls": True,
    "warmup_rounds": 0, "temporal": False, "window": 16, "burn_in": 64, "temporal_feature": 64,
    "temporal_hidden": 128, "anchor_dataset": "", "anchor_share": 0.5}
#: A version 1 sequence checkpoint's config, for keys it may lack.
V1_SEQUENCE_DEFAULTS: dict[str, Any] = {
    "temporal": True, "window": 16, "burn_in": 16, "epochs": 10, "batch_size": 8, "lr": 3e-3, "weight_decay": 1e-5,
    "lr_decay": 0.8, "train_fraction": 0.8, "max_frames": 0, "extra_train": [], "seed": 0, "threads": 1,
    "match_balls": True, "eval_from_step": 6}
V1_MEMORY_DEFAULTS: dict[str, Any] = {"feature": 64, "hidden": 128, "joints": 16, "actions": 16}
#: Perception training keys added in version 3, with the values version 2 files were trained with.
V2_TRAIN_ADDITIONS: dict[str, Any] = {"val_fraction": 0.0, "mix": []}


def model_v2(model: dict) -> dict:
    return {**V1_MODEL_DEFAULTS, **model}


def perception_config_v2(config: dict, kind: str | None) -> dict:
    """A version 1 perception training config (single-frame, or of kind 'sequence') as version 2."""
    if kind != "sequence":
        old = {**V1_TRAIN_DEFAULTS, **config}
        return to_dict(from_dict(PerceptionTrainConfig, {**old, "model": model_v2(old.get("model", {}))}))
    old = {**V1_SEQUENCE_DEFAULTS, **config}
    model = old.pop("model", {})
    frame = {**model_v2(model.get("frame", {})), "out_dim": model.get("out_dim", 6)}
    temporal = old.pop("temporal")
    memory = {k: model.get(k, v) for k, v in V1_MEMORY_DEFAULTS.items()}
    window, burn_in, max_samples = old.pop("window"), old.pop("burn_in"), old.pop("max_frames")
    new = {**old, "task": "baoding", "model": frame, "temporal": temporal, "memory": memory, "split": "episode",
           "window": window if temporal else 1, "burn_in": burn_in if temporal else 0,
           "max_samples": max_samples, "lr_schedule": "exp", "lr_final": 0.01, "warmup_epochs": 0.0,
           "init_output_bias": True}
    return to_dict(from_dict(PerceptionTrainConfig, new))


def online_state_v2(state: dict) -> dict:
    """A policy's version 1 perception state (config, weights, counters) as version 2."""
    old = {**V1_ONLINE_DEFAULTS, **state["config"]}
    memory = {**V1_MEMORY_DEFAULTS, "feature": old.pop("temporal_feature"), "hidden": old.pop("temporal_hidden")}
    stored = state.get("temporal_model")
    if stored is not None:  # the temporal model it was built with: its widths and side inputs
        memory.update({k: stored[k] for k in V1_MEMORY_DEFAULTS if k in stored})
    config = to_dict(from_dict(OnlinePerceptionConfig, {**old, "model": model_v2(old.get("model", {})),
                                                        "memory": memory}))
    new = {k: v for k, v in state.items() if k != "temporal_model"}
    new["config"] = config
    if not config["temporal"]:
        new["env_state"], new["episode_of_env"] = torch.zeros(0, 0), torch.zeros(0, dtype=torch.long)
    elif "env_state" not in new:
        raise CheckpointError("a temporal perception state without its per-env state")
    if "optimizer" in new:  # a training checkpoint: what a resume reads; older ones lack the stream
        new.setdefault("steps_seen", 0)
        new.setdefault("generator", torch.Generator().manual_seed(0).get_state())
    return new


def convert(data: Any, path: Path) -> dict | None:
    """The current form of a file's contents, or None when it is already current."""
    if not isinstance(data, dict) or "format_version" not in data:
        raise CheckpointError(f"{path}: not a tacgnn perception checkpoint, training checkpoint or policy")
    if "actor_state_dict" in data:  # a PPO checkpoint or an exported policy
        if data["format_version"] == ckpt.FORMAT_VERSION:
            return None
        if data["format_version"] != 1:
            raise CheckpointError(f"{path}: policy format version {data['format_version']!r}, this script converts 1")
        new = {**data, "format_version": ckpt.FORMAT_VERSION}
        if "perception" in data:
            try:
                new["perception"] = online_state_v2(data["perception"])
            except (ValueError, KeyError, TypeError) as err:
                raise CheckpointError(f"{path}: its perception state does not convert: {err}") from None
        return new
    if data["format_version"] == pckpt.CHECKPOINT_VERSION and data.get("kind") == pckpt.KIND:
        return None
    if data["format_version"] == 2 and data.get("kind") == pckpt.KIND:
        return {**data, "format_version": pckpt.CHECKPOINT_VERSION, "config": {**V2_TRAIN_ADDITIONS, **data["config"]}}
    if data["format_version"] != 1 or not {"config", "model", "dataset"} <= data.keys():
        raise CheckpointError(f"{path}: not a perception checkpoint of format version 1 or 2")
    try:
        config = perception_config_v2(data["config"], data.get("kind"))
    except (ValueError, KeyError, TypeError) as err:
        raise CheckpointError(f"{path}: its config does not convert: {err}") from None
    new = {k: v for k, v in data.items() if k not in ("kind", "format_version")}
    new.update({"format_version": pckpt.CHECKPOINT_VERSION, "kind": pckpt.KIND, "config": config})
    new.setdefault("rest_positions_cm", None)
    for key in ("optimizer", "history", "epoch"):
        if key not in new:
            raise CheckpointError(f"{path}: perception checkpoint lacking {key!r}")
    return new


def files_of(paths: list[Path]) -> list[tuple[Path, Path]]:
    """(file, its name under --out-dir): a folder's files keep their place under the folder's name."""
    out: list[tuple[Path, Path]] = []
    for p in paths:
        if p.is_dir():
            out += [(f, p.name / f.relative_to(p)) for f in sorted(p.rglob("*.pt"))
                    if not f.name.startswith("perception_frames_")]
        elif p.is_file():
            out.append((p, Path(p.name)))
        else:
            raise FileNotFoundError(f"not found: {p}")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="+", type=Path, help="checkpoints, policies, or folders holding them")
    parser.add_argument("--out-dir", type=Path, help="write converted files here instead of in place")
    parser.add_argument("--dry-run", action="store_true", help="say what would be converted, write nothing")
    args = parser.parse_args(argv)
    files = files_of(args.paths)
    names = [name for _, name in files]
    clash = sorted({str(n) for n in names if names.count(n) > 1})
    if args.out_dir is not None and clash:  # two inputs would be written to one place
        raise ConfigError(f"--out-dir: several inputs are named {', '.join(clash)}; give their folders instead")
    for path, name in files:
        new = convert(read_weights(path, "checkpoint"), path)
        if new is None:
            print(f"{path}: already current")
            continue
        out = path if args.out_dir is None else args.out_dir / name
        if not args.dry_run:
            out.parent.mkdir(parents=True, exist_ok=True)
            ckpt.save(out, new)  # atomic
        print(f"{path}: converted to the current format" + ("" if out == path else f" -> {out}")
              + (" (dry run)" if args.dry_run else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
