"""The training checkpoint: its format, writing, reading, and the checks before it is used.

A checkpoint ``model_<iterations>.pt`` holds, after that many PPO updates:

* ``format_version``, ``iteration``, ``env_config`` and ``ppo_config`` (plain dicts),
  ``obs_dim`` and ``num_actions``: self-describing, checked before any tensor is loaded;
* ``actor_state_dict``, ``critic_state_dict`` (observation normalisers included) and
  ``optimizer_state_dict`` (with the adaptive learning rate);
* ``rng`` (torch's global generator: rsl_rl draws actions and mini-batches from it) and
  ``env_state`` (`RslBaodingEnv.state_dict`: physics, per-env episode state, random streams,
  the last observations);
* in 'perceived' mode ``perception`` (model, optimiser, counters, its generator). Its frame
  buffer (up to ~270 MB) goes beside it in ``perception_frames_<iterations>.pt``; only the
  newest is kept, so that a resumed run continues bit for bit without every checkpoint
  carrying the buffer.

Files are written with `atomic_write` and read with `read_weights` (tensors and plain data
only: no code runs from a file).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import torch

from tacgnn.config import ConfigError, from_dict, to_dict
from tacgnn.envs.baoding import BaodingConfig
from tacgnn.files import atomic_write, read_weights
from tacgnn.learning.config import PPOConfig, architecture_differences

FORMAT_VERSION = 2
"""2: the perception inside holds its whole config (no key left to defaults) and its per-env state,
single-frame or temporal alike; `experiments/convert_checkpoints.py` converts version 1 files."""
CHECKPOINT_KEYS = ("format_version", "iteration", "env_config", "ppo_config", "obs_dim", "num_actions",
                   "actor_state_dict", "critic_state_dict", "optimizer_state_dict", "rng", "env_state")
# What acting needs: an exported policy holds these (and the perception, for a 'perceived' policy).
POLICY_KEYS = ("env_config", "ppo_config", "obs_dim", "num_actions", "actor_state_dict")


class CheckpointError(ValueError):
    """A checkpoint is not ours, or does not match the requested config; names the file."""


def checkpoint_path(run_dir: str | Path, iteration: int) -> Path:
    return Path(run_dir) / f"model_{iteration:06d}.pt"


def frames_path(run_dir: str | Path, iteration: int) -> Path:
    return Path(run_dir) / f"perception_frames_{iteration:06d}.pt"


def list_checkpoints(run_dir: str | Path) -> list[Path]:
    """Complete checkpoints in run_dir, oldest first (temp files of interrupted writes are skipped)."""
    return _numbered(run_dir, "model")


def _numbered(run_dir: str | Path, stem: str) -> list[Path]:
    found = [(int(m.group(1)), p) for p in Path(run_dir).glob(f"{stem}_*.pt")
             if (m := re.fullmatch(rf"{stem}_(\d+)\.pt", p.name))]
    return [p for _, p in sorted(found)]


def save(path: str | Path, data: dict[str, Any]) -> None:
    """`torch.save` through a temp file and a rename: a killed or failed write leaves no partial file."""
    atomic_write(path, lambda fh: torch.save(data, fh))


def save_frames(run_dir: Path, iteration: int, frames: dict[str, Any]) -> None:
    """Write the perception's frame buffer of `iteration` (before its checkpoint is written)."""
    save(frames_path(run_dir, iteration), {"iteration": iteration, "frames": frames})


def remove_frames_except(run_dir: Path, iteration: int) -> None:
    """Delete frame buffers of other iterations: only the newest checkpoint's is kept."""
    for path in _numbered(run_dir, "perception_frames"):
        if path != frames_path(run_dir, iteration):
            path.unlink(missing_ok=True)


def load_frames(run_dir: Path, iteration: int) -> dict[str, Any] | None:
    """The frame buffer saved with checkpoint `iteration`, or None if there is none."""
    path = frames_path(run_dir, iteration)
    if not path.is_file():
        return None
    data = read_weights(path, "perception frame buffer")
    if not isinstance(data, dict) or data.get("iteration") != iteration or "frames" not in data:
        raise CheckpointError(f"{path} is not the perception frame buffer of iteration {iteration}")
    return data["frames"]


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Read and check a training checkpoint (FileNotFoundError, FileProblem, CheckpointError)."""
    checkpoint = read_weights(path, "checkpoint")
    if not isinstance(checkpoint, dict) or "format_version" not in checkpoint:
        raise CheckpointError(f"{path} is not a tacgnn PPO checkpoint (no format_version)")
    if checkpoint["format_version"] != FORMAT_VERSION:
        raise CheckpointError(f"checkpoint {path} has format version {checkpoint['format_version']}, "
                              f"this code reads {FORMAT_VERSION}; convert it once with "
                              f"`python experiments/convert_checkpoints.py {path}`")
    if checkpoint.get("kind") == "policy":
        raise CheckpointError(f"{path} is an exported policy (no critic, optimiser or env state): it can be "
                              "evaluated, not resumed or used as init_from")
    missing = [k for k in CHECKPOINT_KEYS if k not in checkpoint]
    if missing:
        raise CheckpointError(f"checkpoint {path} lacks {missing}")
    return checkpoint


def load_policy_file(path: str | Path) -> dict[str, Any]:
    """A training checkpoint or an exported policy: what `load_policy` reads."""
    data = read_weights(path, "policy file")
    if isinstance(data, dict) and data.get("kind") == "policy":
        missing = [k for k in POLICY_KEYS if k not in data]
        if data.get("format_version") != FORMAT_VERSION:
            raise CheckpointError(f"{path}: an exported policy of format version {data.get('format_version')!r}, "
                                  f"this code reads {FORMAT_VERSION}; convert it once with "
                                  f"`python experiments/convert_checkpoints.py {path}`")
        if missing:
            raise CheckpointError(f"{path}: exported policy lacking {missing}")
        return data
    return load_checkpoint(path)


# Keys whose absence marks a checkpoint of the hand before it was made faithful (no torque limit,
# links that passed through each other, soft contacts): a policy of that hand relies on strength
# this one does not have, so it is refused rather than read with today's defaults.
FAITHFUL_HAND_KEYS = (("hand", "torque_limit"), ("sim", "contact_timeconst"))


def stored_env_config(checkpoint: dict[str, Any], path: str | Path) -> BaodingConfig:
    """The env config a checkpoint was trained in (keys added to the code since read as their defaults,
    except those of the faithful hand: a checkpoint without them is refused, naming them)."""
    stored = checkpoint.get("env_config", {})
    lacking = [f"{a}.{b}" for a, b in FAITHFUL_HAND_KEYS if b not in stored.get(a, {})]
    if lacking:
        raise CheckpointError(f"checkpoint {path} was trained on the earlier hand model (no {', '.join(lacking)}: "
                              "unlimited motor torque, no finger collisions, soft contacts); retrain it on this hand")
    try:
        return from_dict(BaodingConfig, checkpoint["env_config"])
    except ConfigError as err:
        raise CheckpointError(f"checkpoint {path}: its env config does not fit this code: {err}") from None


def check_compatible(checkpoint: dict[str, Any], env_cfg: BaodingConfig, ppo_cfg: PPOConfig,
                     path: str | Path = "<checkpoint>") -> None:
    """Raise CheckpointError naming every env key (and network-shape key) that differs.

    For resuming: the whole env config must match. Besides what changes the observation
    (obs_mode, skin, ...), the saved env state only fits the same envs, physics and task.
    """
    diffs = differences(to_dict(stored_env_config(checkpoint, path)), to_dict(env_cfg))
    diffs += [(f"ppo.{k}", old, new) for k, old, new in architecture_differences(checkpoint["ppo_config"], ppo_cfg)]
    _raise_on(diffs, f"checkpoint {path} does not match the requested config")


def check_policy_fits(checkpoint: dict[str, Any], env_cfg: BaodingConfig, path: str | Path = "<policy>") -> None:
    """Raise CheckpointError unless the policy in `checkpoint` can act on what an env of `env_cfg` observes.

    For acting, where other physics, tasks or skin noise are fine: the observation mode must
    match, a perceiving policy needs a skin of as many taxels as its perception reads, and a
    policy that sees the balls needs them shown as it was trained (`ball_order`, `ball_velocity`:
    another order is a silent wrong answer, velocities another observation width), and every policy
    its actions read as trained (`target_band_rad`). Compared on the configs, before any tensor is
    built, so a mismatch is named rather than failing as a tensor size error.
    """
    stored = stored_env_config(checkpoint, path)
    diffs: list[tuple[str, Any, Any]] = []
    if stored.obs_mode != env_cfg.obs_mode:
        diffs.append(("obs_mode", stored.obs_mode, env_cfg.obs_mode))
    elif env_cfg.obs_mode in ("perceived", "tactile") and stored.skin.num_taxels != env_cfg.skin.num_taxels:
        diffs.append(("skin (number of taxels)", stored.skin.num_taxels, env_cfg.skin.num_taxels))
    _raise_on(diffs, f"the policy in {path} cannot act in this env: it observes differently")
    shown = ("ball_order", "ball_velocity")  # a policy that sees the balls needs them shown as trained
    bare = stored.obs_mode in ("no_perception", "finger_torque", "tactile")  # its observation shows no balls
    for key in ("target_band_rad",) + (() if bare else shown):  # the band: what its actions mean
        trained, requested = getattr(stored, key), getattr(env_cfg, key)
        if trained != requested:
            raise CheckpointError(f"the policy in {path} was trained with {key}={trained}, this env has "
                                  f"{key}={requested}; add --set {key}={str(trained).lower()}")


def _raise_on(diffs: list[tuple[str, Any, Any]], what: str) -> None:
    if not diffs:
        return
    shown = "; ".join(f"{key}: checkpoint {old!r}, requested {new!r}" for key, old, new in diffs[:8])
    more = f"; and {len(diffs) - 8} more" if len(diffs) > 8 else ""
    raise CheckpointError(f"{what}: differing keys {[d[0] for d in diffs]} ({_short(shown)}{more})")


def _short(text: str, limit: int = 400) -> str:
    return text if len(text) <= limit else text[:limit] + "..."


def differences(old: Any, new: Any, prefix: str = "") -> list[tuple[str, Any, Any]]:
    """(dotted key, old, new) for every leaf of two plain config trees that differs."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for key in list(old) + [k for k in new if k not in old]:
            name = f"{prefix}.{key}" if prefix else str(key)
            if key not in old or key not in new:
                out.append((name, old.get(key, "<absent>"), new.get(key, "<absent>")))
            else:
                out += differences(old[key], new[key], name)
        return out
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        return [d for i, (a, b) in enumerate(zip(old, new)) for d in differences(a, b, f"{prefix}[{i}]")]
    return [] if old == new else [(prefix, old, new)]
