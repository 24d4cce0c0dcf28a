"""Regenerate the paper's Tables I and II on our simulator, and the robustness table.

    .venv/bin/python experiments/perception_tables.py [--quick]

Makes the datasets it needs under data/ (resumable), trains every model x seed under
runs/perception/ (each run resumable), and writes docs/perception_results.md and
docs/perception_curves.png, with the paper's figures beside ours. `--quick` is a
smoke-sized version (minutes, not hours) for checking the pipeline.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from tacgnn.datasets import baoding_data, grasp_data
from tacgnn.datasets.store import read_manifest
from tacgnn.envs.grasp import GraspConfig
from tacgnn.perception.train import PerceptionTrainConfig, evaluate, load_checkpoint, train

PAPER_TABLE1 = {  # object: model: (position cm, orientation deg)
    "cube": {"mlp": (0.187, 12.31), "cnn": (0.891, 15.87), "gcn": (0.195, 10.33), "tacgnn": (0.176, 9.17)},
    "cylinder": {"mlp": (0.142, 14.25), "cnn": (1.424, 27.76), "gcn": (0.114, 12.32), "tacgnn": (0.067, 8.76)},
    "meat_can": {"mlp": (0.134, 19.57), "cnn": (3.172, 20.42), "gcn": (0.154, 10.11), "tacgnn": (0.142, 9.76)},
}
PAPER_TABLE2 = {  # model: (train cm, test cm)
    "mlp": (0.230, 0.250), "cnn": (0.114, 27.76), "gcn": (0.130, 0.152), "tacgnn-32": (0.077, 0.096),
    "tacgnn-16": (0.340, 0.251), "tacgnn-64": (0.098, 0.085), "tacgnn-128": (0.069, 0.077),
}
ROOT = Path(__file__).resolve().parents[1]


def ensure_datasets(args) -> dict[str, Path]:
    paths = {"baoding": ROOT / "data" / f"baoding_{args.baoding_samples}"}
    baoding_data.generate(baoding_data.BaodingDataConfig(samples=args.baoding_samples, shard_size=args.shard),
                          paths["baoding"])
    # the same motions seen by a skin of another pitch: models are evaluated on it untrained
    layout = baoding_data.BaodingDataConfig().env
    other = replace(layout, skin=layout.skin.with_pitch_scale(args.other_pitch))
    paths["baoding_other_pitch"] = ROOT / "data" / f"baoding_pitch{args.other_pitch}_{args.test_samples}"
    baoding_data.generate(baoding_data.BaodingDataConfig(samples=args.test_samples, shard_size=args.test_samples,
                                                         seed=99, env=other), paths["baoding_other_pitch"])
    for obj in ("cube", "cylinder", "meat_can"):
        paths[obj] = ROOT / "data" / f"{obj}_{args.grasp_samples}"
        grasp_data.generate(grasp_data.GraspDataConfig(samples=args.grasp_samples, shard_size=args.shard,
                                                       grasp=GraspConfig(object=obj)), paths[obj])
    return paths


def run(task: str, model: str, channels: int, seed: int, dataset: Path, args, max_samples: int = 0) -> dict:
    name = f"{model}-{channels}" if model == "tacgnn" else model
    run_dir = ROOT / "runs" / "perception" / task / (f"n{max_samples}" if max_samples else "all") / name / f"seed{seed}"
    cfg = PerceptionTrainConfig.for_task(task, model, epochs=args.epochs, seed=seed, max_samples=max_samples,
                                         model_kw={"channels": channels, "use_force": args.use_force})
    ckpt = run_dir / "checkpoint.pt"
    if ckpt.exists() and load_checkpoint(ckpt)["epoch"] == args.epochs - 1:
        history = load_checkpoint(ckpt)["history"]
    else:
        start = time.perf_counter()
        train(cfg, dataset, run_dir, resume=True, log=lambda line: print(f"[{task} {name} s{seed}] {line}", flush=True))
        print(f"[{task} {name} s{seed}] {time.perf_counter() - start:.0f} s", flush=True)
        history = load_checkpoint(ckpt)["history"]
    return {"ckpt": ckpt, "history": history, "final": history[-1]}


def mean_std(values: list[float]) -> str:
    return f"{np.mean(values):.3f} ± {np.std(values):.3f}" if len(values) > 1 else f"{values[0]:.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--epochs", type=int, default=10)
    parser.add_argument("--use-force", action="store_true", help="TacGNN node feature: position and force")
    args = parser.parse_args()
    args.baoding_samples, args.grasp_samples, args.test_samples, args.shard = 25_000, 20_000, 5_000, 5_000
    args.other_pitch = 1.25
    if args.quick:
        args.baoding_samples, args.grasp_samples, args.test_samples, args.shard = 2_000, 1_000, 1_000, 1_000
        args.seeds, args.epochs = 1, 2
    data = ensure_datasets(args)
    seeds = range(args.seeds)
    lines = ["# Perception results (issue 3)", "",
             "Made by `.venv/bin/python experiments/perception_tables.py"
             + (" --quick" if args.quick else "") + (" --use-force" if args.use_force else "") + "`; "
             f"{args.seeds} seed(s), {args.epochs} epochs, Adam 1e-3, batch 32, 80/20 split. "
             f"Datasets: Baoding {args.baoding_samples} frames, grasps {args.grasp_samples} per object "
             "(the paper: 1,000,000 steps and 200,000 grasps). Ours: mean ± std over seeds.", ""]

    # Table II: ball positions
    models = [("mlp", 32), ("cnn", 32), ("gcn", 32), ("tacgnn", 32), ("tacgnn", 16), ("tacgnn", 64), ("tacgnn", 128)]
    table2 = {}
    for model, ch in models:
        table2[(model, ch)] = [run("baoding", model, ch, s, data["baoding"], args) for s in seeds]
    lines += ["## Table II: ball positions (RMSE, cm)", "",
              "| model | train (ours) | test (ours) | train (paper) | test (paper) | s/epoch |", "|---|---|---|---|---|---|"]
    for (model, ch), runs in table2.items():
        key = f"tacgnn-{ch}" if model == "tacgnn" else model
        tr = [r["final"]["train/position_rmse_cm"] for r in runs]
        te = [r["final"]["test/position_rmse_cm"] for r in runs]
        sec = np.mean([h["seconds"] for r in runs for h in r["history"]])
        p = PAPER_TABLE2[key]
        lines.append(f"| {key} | {mean_std(tr)} | {mean_std(te)} | {p[0]} | {p[1]} | {sec:.1f} |")

    # Table I: objects
    lines += ["", "## Table I: object pose after a power grasp (test RMSE: position cm / orientation deg)", "",
              "| object | metric | MLP | CNN | GCN | TacGNN | paper MLP | paper CNN | paper GCN | paper TacGNN |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for obj in ("cube", "cylinder", "meat_can"):
        res = {m: [run(obj, m, 32, s, data[obj], args) for s in seeds] for m in ("mlp", "cnn", "gcn", "tacgnn")}
        for metric, idx, label in (("test/position_rmse_cm", 0, "position (cm)"),
                                   ("test/orientation_rmse_deg", 1, "orientation (deg)")):
            ours = [mean_std([r["final"][metric] for r in res[m]]) for m in ("mlp", "cnn", "gcn", "tacgnn")]
            paper = [str(PAPER_TABLE1[obj][m][idx]) for m in ("mlp", "cnn", "gcn", "tacgnn")]
            lines.append(f"| {obj} | {label} | " + " | ".join(ours + paper) + " |")

    # Robustness: dead taxels and another skin pitch, no retraining
    lines += ["", f"## Beyond the paper: dead taxels and a skin of {args.other_pitch}x pitch, no retraining "
              "(ball positions, test RMSE cm)", "",
              "| model | intact | 10 % dead | 20 % dead | other pitch |", "|---|---|---|---|---|"]
    for (model, ch), runs in table2.items():
        key = f"tacgnn-{ch}" if model == "tacgnn" else model
        cols = []
        for dead in (0.0, 0.1, 0.2):
            cols.append(mean_std([evaluate(r["ckpt"], data["baoding"], dead_fraction=dead, seed=i)["position_rmse_cm"]
                                  for i, r in enumerate(runs)]))
        cols.append(mean_std([evaluate(r["ckpt"], data["baoding_other_pitch"], whole=True)["position_rmse_cm"]
                              for r in runs]))
        lines.append(f"| {key} | " + " | ".join(cols) + " |")

    # Learning curve over dataset size (seed 0)
    sizes = [n for n in (2_500, 5_000, 10_000) if n < args.baoding_samples] + [0]
    curve = {}
    for model, ch in (("mlp", 32), ("tacgnn", 32)):
        curve[model] = [run("baoding", model, ch, 0, data["baoding"], args, max_samples=n)["final"]["test/position_rmse_cm"]
                        for n in sizes]
    lines += ["", "## Does more data change the ranking? (ball positions, seed 0, test RMSE cm)", "",
              "| samples | " + " | ".join(curve) + " |", "|---|" + "---|" * len(curve)]
    for i, n in enumerate(sizes):
        lines.append(f"| {n or args.baoding_samples} | " + " | ".join(f"{curve[m][i]:.3f}" for m in curve) + " |")

    plot_curves(table2, ROOT / "docs" / "perception_curves.png")
    lines += ["", "Learning curves (test RMSE per epoch, seed 0): `docs/perception_curves.png`.", ""]
    out = ROOT / "docs" / "perception_results.md"
    out.write_text("\n".join(lines))
    (ROOT / "docs" / "perception_results.json").write_text(json.dumps(
        {f"{m}-{c}": [r["final"] for r in runs] for (m, c), runs in table2.items()}, indent=1))
    print("\n".join(lines))
    print(f"data sets: {[str(p) for p in data.values()]}; metadata seeds "
          f"{[read_manifest(p)['metadata']['seed'] for p in data.values()]}")


def plot_curves(table2, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for (model, ch), runs in table2.items():
        h = runs[0]["history"]
        label = f"tacgnn-{ch}" if model == "tacgnn" else model
        ax.plot([r["epoch"] + 1 for r in h], [r["test/position_rmse_cm"] for r in h], label=label, marker="o", ms=3)
    ax.set_xlabel("epoch")
    ax.set_ylabel("test RMSE (cm)")
    ax.set_yscale("log")
    ax.set_title("Ball positions from the skin")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
