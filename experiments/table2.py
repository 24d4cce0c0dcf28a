"""Table II: ball positions from the skin, every perception model on a teacher's frames.

    .venv/bin/python experiments/table2.py [--dataset data/table2] [--seeds 1] [--epochs 10]
        [--models mlp cnn gcn tacgnn-32 tacgnn-64] [--max-samples N] [--samples N]

The dataset (recorded first, or completed if cut off: `record`) is 50,000 frames of the committed
ground-truth teacher on the 1 s hold task, the nominal hand and the default (real) skin, split
by frame 80/20 into training and test; a tenth of the training side is the validation split.
Each model x seed trains under runs/table2/ (resumed when cut off); the epoch with the lowest
validation error is the model (`best.pt`, copied to results/table2/checkpoints/), scored once on
the test split. results/table2/MODEL_sSEED.json: the chosen epoch, train (that epoch),
validation and test RMSE (cm), the test error of balls the skin touches and of balls it does not
(no activated taxel within 3 cm of the centre), and the error with the palm's whole patch lost,
with the run's provenance. Prints the table in markdown, the paper's figures beside ours.
`--max-samples N` trains and scores on the first N frames only (the same split rule; names end
in `_nN`): how the error falls with the data. `--samples N` records N frames instead of 50,000 (give it its own
`--dataset`, and `--max-samples` to name the runs).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from tacgnn.config import ConfigError
from tacgnn.files import atomic_write_text
from tacgnn.perception.checkpoint import load_checkpoint
from tacgnn.perception.evaluation import patch_loss
from tacgnn.perception.train_config import PerceptionTrainConfig
from tacgnn.perception.training import train
from tacgnn.provenance import provenance
from tacgnn.user_errors import run_script

PAPER = {"mlp": (0.230, 0.250), "cnn": (0.114, 27.76), "gcn": (0.130, 0.152), "tacgnn-32": (0.077, 0.096),
         "tacgnn-64": (0.098, 0.085)}  # model: (train cm, test cm)
ROOT = Path(__file__).resolve().parents[1]
TEACHER = "results/perception_mix/checkpoints/teacher_hold.pt"
SAMPLES = 50_000


def record(samples: int) -> list[str]:
    """The make-dataset arguments of the Table II frames."""
    return ["make-dataset", "baoding", "--policy", TEACHER, "--samples", str(samples), "--settle-steps", "0",
            "--seed", "0", "--set", "task=hold"]


VAL_FRACTION = 0.1


def run(name: str, seed: int, dataset: Path, epochs: int, max_samples: int = 0, samples: int = SAMPLES) -> dict:
    model, _, channels = name.partition("-")
    cfg = PerceptionTrainConfig.for_task("baoding", model, epochs=epochs, seed=seed, val_fraction=VAL_FRACTION,
                                         max_samples=max_samples, model_kw={"channels": int(channels or 32)})
    tag = f"{name}_s{seed}" + (f"_n{max_samples}" if max_samples else "")
    run_dir = ROOT / "runs" / "table2" / tag
    ckpt = run_dir / "checkpoint.pt"
    if not (ckpt.exists() and load_checkpoint(ckpt)["epoch"] == epochs - 1):
        def log(line: str) -> None:
            print(f"[{name} s{seed}] {line}", flush=True)

        train(cfg, dataset, run_dir, resume=ckpt.exists(), log=log)
    best = run_dir / "best.pt"
    chosen = load_checkpoint(best)["history"][-1]
    test = patch_loss(best, dataset, "palm")  # the intact test errors, and with the palm lost
    kept = ROOT / "results" / "table2" / "checkpoints" / f"{tag}.pt"
    kept.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(best, kept)
    result = {"model": name, "seed": seed, "epoch": chosen["epoch"], "train_rmse_cm": chosen["train/position_rmse_cm"],
              "val_rmse_cm": chosen["val/position_rmse_cm"],
              "test_rmse_cm": test["position_rmse_cm"], "touched_rmse_cm": test["touched_rmse_cm"],
              "untouched_rmse_cm": test["untouched_rmse_cm"], "untouched_fraction": test["untouched_fraction"],
              "palm_lost_rmse_ratio": test["rmse_ratio"], "paper_train_test_cm": PAPER.get(name),
              "provenance": provenance({"perception": kept.relative_to(ROOT)}, seed,
                                       {"epochs": epochs, "dataset": str(dataset), "val_fraction": VAL_FRACTION,
                                        "max_samples": max_samples, "record": record(samples)})}
    out = ROOT / "results" / "table2" / f"{tag}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, json.dumps(result, indent=1))
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", type=Path, default=ROOT / "data" / "table2")
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--epochs", type=int, default=10)
    ap.add_argument("--models", nargs="+", default=list(PAPER), choices=list(PAPER))
    ap.add_argument("--max-samples", type=int, default=0, help="train and score on the first N frames (0: all)")
    ap.add_argument("--samples", type=int, default=SAMPLES, help="frames to record in --dataset")
    args = ap.parse_args()
    if args.samples != SAMPLES and not args.max_samples:
        raise ConfigError(f"--samples {args.samples}: give --max-samples too (the runs' names)")
    # makes only the shards that are missing: a few seconds when the dataset is complete
    subprocess.run([sys.executable, "-m", "tacgnn.cli", *record(args.samples), "--out", str(args.dataset)],
                   check=True, cwd=ROOT)
    rows = ["| model | epoch | train (ours) | validation | test (ours) | touched | untouched | palm lost (x) "
            "| train (paper) | test (paper) |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for name in args.models:
        res = [run(name, s, args.dataset, args.epochs, args.max_samples, args.samples) for s in range(args.seeds)]

        def cell(key: str, res: list = res) -> str:
            v = [r[key] for r in res]
            return f"{np.mean(v):.3f}" + (f" ± {np.std(v):.3f}" if len(v) > 1 else "")

        paper = PAPER[name]
        rows.append(f"| {name} | {cell('epoch')} | {cell('train_rmse_cm')} | {cell('val_rmse_cm')} | "
                    f"{cell('test_rmse_cm')} | {cell('touched_rmse_cm')} | "
                    f"{cell('untouched_rmse_cm')} | {cell('palm_lost_rmse_ratio')} | {paper[0]} | {paper[1]} |")
    print("\n".join(rows))


if __name__ == "__main__":
    raise SystemExit(run_script(main))
