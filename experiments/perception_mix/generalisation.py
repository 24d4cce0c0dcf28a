"""Does a perception hold on frames of controllers it never saw? Its errors on each controller's frames.

Each perception (a `train-perception` checkpoint, or a blind policy, whose perception is read out)
reads every episode of each named dataset from its first frame, as in the env's loop; a dataset is
``name=folder``. The first dataset is the perception's own policy: every other row gives its
ratio to that one (target <= 1.5x). With ``--split-of RUN_CHECKPOINT`` the validation and test episodes
of that training run (its datasets and split) are added as two more columns: the variants are
chosen on validation, and the test column is read once. Writes JSON (errors in cm: all, touched, untouched balls;
provenance) and a Markdown table beside it.

    .venv/bin/python experiments/perception_mix/generalisation.py --out results/perception_mix/generalisation.json \\
        --perception mixed=results/perception_mix/checkpoints/tacgnn32_temporal_mix.pt \\
        --dataset own=data/fresh_teacher wave=data/heldout_wave teacher=data/heldout_teacher
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from tacgnn.config import ConfigError
from tacgnn.datasets.store import read_manifest
from tacgnn.files import atomic_write_text
from tacgnn.learning.checkpoint import load_policy_file
from tacgnn.learning.policy import perception_from_checkpoint
from tacgnn.perception.checkpoint import load_checkpoint, load_model, stored_config
from tacgnn.perception.evaluation import load_data, metrics, predict, split_data
from tacgnn.perception.sequences import load_sequences
from tacgnn.perception.train_config import PerceptionTrainConfig
from tacgnn.provenance import provenance
from tacgnn.user_errors import run_script

TARGET_RATIO = 1.5


def named(pairs: list[str], flag: str) -> dict[str, str]:
    out = {}
    for pair in pairs:
        name, sep, path = pair.partition("=")
        if not sep or not name or not path:
            raise ConfigError(f"{flag} {pair!r}: give name=path")
        if not Path(path).exists():
            raise ConfigError(f"{flag} {pair!r}: {path} does not exist")
        out[name] = path
    return out


def perception_model(path: str) -> tuple[torch.nn.Module, PerceptionTrainConfig]:
    """The model of a train-perception checkpoint, or the perception inside a blind policy file."""
    if torch.load(path, map_location="cpu", weights_only=True).get("kind") != "perception":
        online = perception_from_checkpoint(load_policy_file(path), path)
        if online is None:
            raise ConfigError(f"--perception {path}: a policy without a perception (not a blind policy)")
        return online.model, PerceptionTrainConfig(split="episode")  # how errors are counted: as train-perception
    model, cfg, _ = load_model(path)
    return model, cfg


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--perception", nargs="+", required=True, help="name=checkpoint or name=blind policy")
    parser.add_argument("--dataset", nargs="+", required=True, help="name=folder; the first: the own policy's")
    parser.add_argument("--split-of", default="", help="a train-perception checkpoint: add its validation and "
                        "test episodes")
    parser.add_argument("--out", required=True, help="JSON file (the table: the same name, .md)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    perceptions, datasets = named(args.perception, "--perception"), named(args.dataset, "--dataset")
    data = {name: load_sequences(path) for name, path in datasets.items()}
    if args.split_of:
        run = load_checkpoint(args.split_of)
        run_cfg = stored_config(PerceptionTrainConfig, run["config"], args.split_of, "config")
        _, val, test = split_data(run_cfg, load_data(run_cfg, run["dataset"]["path"], run_cfg.max_samples))
        if val is None:
            raise ConfigError(f"--split-of {args.split_of}: its run has no validation split (val_fraction=0)")
        data.update(validation=val, test=test)
    rows: dict[str, dict[str, dict[str, float]]] = {}
    for pname, path in perceptions.items():
        model, cfg = perception_model(path)
        rows[pname] = {}
        for dname, frames in data.items():
            row = metrics(predict(model, frames), cfg, frames)
            rows[pname][dname] = {k: row[k] for k in ("position_rmse_cm", "touched_rmse_cm", "untouched_rmse_cm",
                                                      "untouched_fraction")}
        own = rows[pname][next(iter(data))]["position_rmse_cm"]
        for dname, row in rows[pname].items():
            row["ratio_to_own"] = row["position_rmse_cm"] / own
            print(f"{pname:>12} on {dname:>10}: {row['position_rmse_cm']:.3f} cm (touched {row['touched_rmse_cm']:.3f},"
                  f" untouched {row['untouched_rmse_cm']:.3f}), {row['ratio_to_own']:.2f}x its own policy's")
    controllers = {name: read_manifest(path)["metadata"]["controller"] for name, path in datasets.items()}
    if args.split_of:
        controllers.update(validation="the run's mix", test="the run's mix")
    result = {"perceptions": perceptions, "datasets": datasets, "controllers": controllers, "rows": rows,
              "target_ratio": TARGET_RATIO, "frames": {name: len(d) for name, d in data.items()},
              "provenance": provenance({**perceptions, **({"split_of": args.split_of} if args.split_of else {})}, None,
                                     {"datasets": datasets})}
    atomic_write_text(args.out, json.dumps(result, indent=1))
    head = "| perception | " + " | ".join(f"{d} (cm; x own)" for d in data) + " |"
    lines = [head, "|" + " --- |" * (len(data) + 1)]
    for pname, by in rows.items():
        cells = [f"{r['position_rmse_cm']:.3f} (untouched {r['untouched_rmse_cm']:.3f}); {r['ratio_to_own']:.2f}x"
                 for r in by.values()]
        lines.append(f"| {pname} | " + " | ".join(cells) + " |")
    atomic_write_text(Path(args.out).with_suffix(".md"), "\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    raise SystemExit(run_script(main))
