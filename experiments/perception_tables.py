"""Regenerate the paper's Tables I and II on our simulator, and the robustness table.

    .venv/bin/python experiments/perception_tables.py [--quick] [--baoding-data DIR]

Makes the datasets it needs under data/ (resumable; Baoding frames from the
ground-truth policy trained by PPO, results/real_hand/checkpoints/gt_ppo.pt, unless --baoding-data names an
existing dataset), trains every model x seed under
runs/perception/ (each run resumable), and writes results/table2/perception_results.md
(Tables II and I, the robustness table) and results/table2/perception_results.png (learning
curves), with the paper's figures beside ours; --only-table1 writes
results/table1/perception_table1.md. `--quick` is a
smoke-sized version (minutes, not hours) for checking the pipeline.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import tacgnn.datasets.baoding_data as baoding_data
import tacgnn.datasets.grasp_data as grasp_data
from tacgnn.datasets.store import read_manifest
from tacgnn.envs.grasp import GraspConfig, ObjectName
from tacgnn.files import atomic_write, atomic_write_text
from tacgnn.perception.checkpoint import load_checkpoint, save_checkpoint
from tacgnn.perception.evaluation import evaluate
from tacgnn.perception.objectives import TaskName
from tacgnn.perception.train_config import PerceptionTrainConfig
from tacgnn.perception.training import train
from tacgnn.provenance import provenance
from tacgnn.user_errors import run_script

PAPER_TABLE1 = {  # object: model: (position cm, orientation deg)
    "cube": {"mlp": (0.187, 12.31), "cnn": (0.891, 15.87), "gcn": (0.195, 10.33), "tacgnn": (0.176, 9.17)},
    "cylinder": {"mlp": (0.142, 14.25), "cnn": (1.424, 27.76), "gcn": (0.114, 12.32), "tacgnn": (0.067, 8.76)},
    "meat_can": {"mlp": (0.134, 19.57), "cnn": (3.172, 20.42), "gcn": (0.154, 10.11), "tacgnn": (0.142, 9.76)},
}
PAPER_TABLE2 = {  # model: (train cm, test cm)
    "mlp": (0.230, 0.250), "cnn": (0.114, 27.76), "gcn": (0.130, 0.152), "tacgnn-32": (0.077, 0.096),
    "tacgnn-16": (0.340, 0.251), "tacgnn-64": (0.098, 0.085), "tacgnn-128": (0.069, 0.077),
}
# Table I's columns: the paper's four models; TacGNN at 32 channels (Table II's reference width),
# at 64 (32 channels underfit the grasps: train error = test error) and at 128
TABLE1_MODELS = (("mlp", 32), ("cnn", 32), ("gcn", 32), ("tacgnn", 32), ("tacgnn", 64), ("tacgnn", 128))
OBJECTS: tuple[ObjectName, ...] = ("cube", "cylinder", "meat_can")
CURVE_MODELS = (("mlp", 32), ("gcn", 32), ("tacgnn", 32))  # the dataset-size curve's models
ROOT = Path(__file__).resolve().parents[1]


GT_POLICY = ROOT / "results" / "real_hand" / "checkpoints" / "gt_ppo.pt"  # trained by PPO on the true positions


def ensure_datasets(args) -> dict[str, Path]:
    """The datasets the invocation needs (--only-table1: the grasp datasets only)."""
    paths: dict[str, Path] = {}
    for obj in args.objects if args.only_table1 else OBJECTS:
        paths[obj] = ROOT / "data" / f"{obj}_{args.grasp_samples}"
        grasp_data.generate(grasp_data.GraspDataConfig(samples=args.grasp_samples, shard_size=args.shard,
                                                       grasp=GraspConfig(object=obj)), paths[obj])
    if args.only_table1:
        return paths
    if args.baoding_data:
        paths["baoding"] = Path(args.baoding_data)
        read_manifest(paths["baoding"])  # exists and is complete, or a clear error
    else:
        paths["baoding"] = ROOT / "data" / f"baoding_gt_{args.baoding_samples}"
        baoding_data.generate(baoding_data.BaodingDataConfig(samples=args.baoding_samples, shard_size=args.shard,
                                                             policy_checkpoint=str(GT_POLICY)), paths["baoding"])
    # the same motions seen by a skin of another pitch: models are evaluated on it untrained
    layout = baoding_data.BaodingDataConfig().env
    other = replace(layout, skin=layout.skin.with_pitch_scale(args.other_pitch))
    paths["baoding_other_pitch"] = ROOT / "data" / f"baoding_pitch{args.other_pitch}_{args.test_samples}"
    baoding_data.generate(baoding_data.BaodingDataConfig(samples=args.test_samples, shard_size=args.test_samples,
                                                         seed=99, env=other, policy_checkpoint=str(GT_POLICY)),
                          paths["baoding_other_pitch"])
    return paths


def row_label(model: str, channels: int, joints: int = 0) -> str:
    return (f"{model}-{channels}" if model == "tacgnn" else model) + (" + joint angles" if joints else "")


def run_config(task: TaskName, model: str, channels: int, seed: int, args, max_samples: int = 0,
               joints: int = 0) -> PerceptionTrainConfig:
    cfg = PerceptionTrainConfig.for_task(task, model, epochs=args.epochs, seed=seed, max_samples=max_samples,
                                         model_kw={"channels": channels, "joint_inputs": joints, **args.model_kw})
    return replace(cfg, lr=1e-3, lr_schedule="constant", init_output_bias=False) if args.paper_setup else cfg


def run(task: TaskName, model: str, channels: int, seed: int, dataset: Path, args, max_samples: int = -1,
        joints: int = 0) -> dict | None:
    max_samples = args.max_samples.get(task, 0) if max_samples < 0 else max_samples
    name = (f"{model}-{channels}" if model == "tacgnn" else model) + ("-joints" if joints else "")
    setup = "paper" if args.paper_setup else "ours"
    root = ROOT / "runs" / ("perception_quick" if args.quick else "perception")  # quick runs never mix in
    # Baoding runs are kept per dataset (--baoding-data may name any); each grasp task has one dataset
    data_dir = f"{task}/{dataset.name}" if task == "baoding" else task
    run_dir = root / setup / data_dir / (f"n{max_samples}" if max_samples else "all") / name / f"seed{seed}"
    cfg = run_config(task, model, channels, seed, args, max_samples, joints)
    ckpt = run_dir / "checkpoint.pt"
    complete = ckpt.exists() and load_checkpoint(ckpt)["epoch"] == args.epochs - 1
    if args.report and not complete:
        return None  # --report: the page shows "not run"
    if not args.report:
        _wait_for_other_process(run_dir)
    if complete:
        history = load_checkpoint(ckpt)["history"]
    else:
        start = time.perf_counter()
        train(cfg, dataset, run_dir, resume=True, log=lambda line: print(f"[{task} {name} s{seed}] {line}", flush=True))
        print(f"[{task} {name} s{seed}] {time.perf_counter() - start:.0f} s", flush=True)
        history = load_checkpoint(ckpt)["history"]
    if not args.report:
        (run_dir / ".owner").unlink(missing_ok=True)
    return {"ckpt": ckpt, "history": history, "final": history[-1]}


def _wait_for_other_process(run_dir: Path) -> None:
    """Two invocations (e.g. one with --only-table1) may reach the same run: the second waits.

    A run folder being trained holds `.owner` with the trainer's pid; a folder whose owner is
    gone (killed) is taken over and resumed.
    """
    owner = run_dir / ".owner"
    while owner.exists():
        try:
            pid = int(owner.read_text())
            os.kill(pid, 0)  # raises if no such process
        except (ValueError, ProcessLookupError, FileNotFoundError):
            break
        if pid == os.getpid():
            return
        time.sleep(10)
    run_dir.mkdir(parents=True, exist_ok=True)
    owner.write_text(str(os.getpid()))


def mean_std(values: list[float]) -> str:
    if not values:
        return "not run"
    return f"{np.mean(values):.3f} ± {np.std(values):.3f}" if len(values) > 1 else f"{values[0]:.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--epochs", type=int, default=10)
    parser.add_argument("--only-table1", action="store_true",
                        help="train Table I's runs and stop (to run beside a full invocation on another core; "
                             "a full run afterwards reuses them and writes the page)")
    parser.add_argument("--only-curve", action="store_true",
                        help="train the dataset-size curve's runs (ball positions, seed 0), write "
                             "results/table2/perception_data_curve.md and stop")
    parser.add_argument("--models", nargs="+", default=None, metavar="NAME",
                        help="with --only-table1 or --only-curve: train only these models "
                             "(mlp cnn gcn tacgnn-32 tacgnn-64 tacgnn-128)")
    parser.add_argument("--objects", nargs="+", default=list(OBJECTS), choices=OBJECTS, metavar="OBJECT",
                        help="with --only-table1: train only these objects (default: all three)")
    parser.add_argument("--report", action="store_true",
                        help="train nothing: write the page from the runs that are complete ('not run' for others)")
    parser.add_argument("--paper-setup", action="store_true",
                        help="the paper's loop and TacGNN (lr 1e-3 constant, positions only, last-layer pool) "
                             "instead of our training defaults")
    parser.add_argument("--baoding-data", default="", help="an existing Baoding dataset (else made from the "
                        "ground-truth policy trained by PPO, results/real_hand/checkpoints/gt_ppo.pt)")
    parser.add_argument("--baoding-samples", type=int, default=25_000,
                        help="frames used for Table II (the first ones of the dataset)")
    parser.add_argument("--grasp-samples", type=int, default=20_000,
                        help="grasps per object (a multiple of 5,000; the datasets are data/OBJECT_N)")
    args = parser.parse_args()
    known = [row_label(m, ch) for m, ch in TABLE1_MODELS]
    if args.models and not (args.only_table1 or args.only_curve):
        parser.error("--models goes with --only-table1 or --only-curve")
    if args.models and (unknown := set(args.models) - set(known)):
        parser.error(f"--models: unknown {sorted(unknown)}; choose from {known}")
    args.test_samples, args.shard = 5_000, 5_000
    args.model_kw = {"use_force": False, "force_feature": "raw", "pool": "last"} if args.paper_setup else {}
    args.other_pitch = 1.25
    if args.quick:
        args.baoding_samples, args.grasp_samples, args.test_samples, args.shard = 2_000, 1_000, 1_000, 1_000
        args.seeds, args.epochs = 1, 2
    data = ensure_datasets(args)
    args.max_samples = {"baoding": args.baoding_samples}
    seeds = range(args.seeds)
    example = run_config("baoding", "tacgnn", 32, 0, args)
    command = " ".join(["`.venv/bin/python experiments/perception_tables.py"] + [a for a in sys.argv[1:]]) + "`"
    lines = ["# Perception results", "",
             f"Made by {command}; {args.seeds} seed(s), {args.epochs} epochs, Adam lr {example.lr} "
             f"({example.lr_schedule} schedule), batch {example.batch_size}, 80/20 split"
             + (", the paper's loop and TacGNN" if args.paper_setup else
                f"; TacGNN node input position + {example.model.force_feature} force, readout "
                f"`pool={example.model.pool}`") + ". "
             + (f"Datasets: Baoding {args.baoding_samples} frames of "
                f"`{data['baoding'].relative_to(ROOT) if data['baoding'].is_absolute() else data['baoding']}`, "
                if "baoding" in data else "Datasets: ")
             + f"grasps {args.grasp_samples} per object under the {GraspConfig().hand.torque_limit} N m torque limit "
             "(the paper: 1,000,000 steps and 200,000 grasps). Ours: mean ± std over seeds.", ""]

    if args.only_table1:
        for s in seeds:  # seed-major: an interrupted invocation leaves whole seeds behind
            for m, ch in chosen(TABLE1_MODELS, args):
                for obj in args.objects:
                    run(obj, m, ch, s, data[obj], args)
        trained, args.report = not args.report, True  # the page shows the complete runs ("not run" for others)
        if trained and not args.quick:  # result files carry the command that trained them, not a later --report
            write_table1_results(data, args, seeds)
        text = "\n".join(lines[:4] + table1_lines(data, args, seeds)) + "\n"
        atomic_write_text(ROOT / "results" / "table1" / f"{page_stem('perception_table1', args)}.md", text)
        print(text)
        return

    if args.only_curve:
        models = chosen(TABLE1_MODELS, args) if args.models else CURVE_MODELS
        text = "\n".join(lines[:4] + data_curve_lines(data, args, models)) + "\n"
        atomic_write_text(ROOT / "results" / "table2" / f"{page_stem('perception_data_curve', args)}.md", text)
        print(text)
        return

    # Table II: ball positions
    # the paper's rows, then beyond the paper: the same models reading the hand's 16 joint angles too
    table2_models = [("mlp", 32, 0), ("cnn", 32, 0), ("gcn", 32, 0), ("tacgnn", 32, 0), ("tacgnn", 16, 0),
                     ("tacgnn", 64, 0), ("tacgnn", 128, 0), ("mlp", 32, 16), ("tacgnn", 32, 16)]
    table2 = {}
    for model, ch, joints in table2_models:
        table2[(model, ch, joints)] = [r for s in seeds
                                       if (r := run("baoding", model, ch, s, data["baoding"], args, joints=joints))]
    lines += ["## Table II: ball positions (RMSE, cm)", "",
              "Test error split by what the skin sees: *touched* = balls with an activated taxel "
              "within 3 cm of the centre, *untouched* = the others (resting on the other ball or on "
              "a part of the hand without skin); `tacgnn.perception.evaluation.ball_errors`.", "",
              "| model | train (ours) | test (ours) | test, touched balls | test, untouched balls | train (paper) "
              "| test (paper) | s/epoch |", "|---|---|---|---|---|---|---|---|"]
    blind_share = []
    for (model, ch, joints), runs in table2.items():
        key = row_label(model, ch, joints)
        tr = [r["final"]["train/position_rmse_cm"] for r in runs]
        te = [r["final"]["test/position_rmse_cm"] for r in runs]
        vis = [evaluate(r["ckpt"], data["baoding"]) for r in runs]
        blind_share += [v["untouched_fraction"] for v in vis[:1]]
        sec = np.mean([h["seconds"] for r in runs for h in r["history"]]) if runs else float("nan")
        p = PAPER_TABLE2.get(key, ("-", "-"))
        lines.append(f"| {key} | {mean_std(tr)} | {mean_std(te)} | {mean_std([v['touched_rmse_cm'] for v in vis])} | "
                     f"{mean_std([v['untouched_rmse_cm'] for v in vis])} | {p[0]} | {p[1]} | {sec:.1f} |")
    if blind_share:
        lines += ["", f"Untouched balls: {100 * blind_share[0]:.1f} % of the test balls.", ""]

    lines += table1_lines(data, args, seeds)

    # Robustness: dead taxels and another skin pitch, no retraining
    lines += ["", f"## Beyond the paper: dead taxels and a skin of {args.other_pitch}x pitch, no retraining "
              "(ball positions, test RMSE cm)", "",
              "| model | intact | 10 % dead | 20 % dead | other pitch |", "|---|---|---|---|---|"]
    for (model, ch, joints), runs in table2.items():
        key = row_label(model, ch, joints)
        cols = []
        for dead in (0.0, 0.1, 0.2):
            cols.append(mean_std([evaluate(r["ckpt"], data["baoding"], dead_fraction=dead, seed=i)["position_rmse_cm"]
                                  for i, r in enumerate(runs)]))
        cols.append(mean_std([evaluate(r["ckpt"], data["baoding_other_pitch"], whole=True)["position_rmse_cm"]
                              for r in runs]))
        lines.append(f"| {key} | " + " | ".join(cols) + " |")

    lines += data_curve_lines(data, args, CURVE_MODELS)

    stem = page_stem("perception_results", args)
    pages = ROOT / "results" / "table2"
    pages.mkdir(parents=True, exist_ok=True)
    plot_curves(table2, pages / f"{stem}.png")
    lines += ["", f"Learning curves (test RMSE per epoch, seed 0): `results/table2/{stem}.png`.", ""]
    out = pages / f"{stem}.md"
    atomic_write_text(out, "\n".join(lines))
    atomic_write_text(pages / f"{stem}.json", json.dumps(
        {row_label(*k): [r["final"] for r in runs] for k, runs in table2.items()}, indent=1))
    print("\n".join(lines))
    print(f"data sets: {[str(p) for p in data.values()]}; metadata seeds "
          f"{[read_manifest(p)['metadata']['seed'] for p in data.values()]}")


def page_stem(name: str, args) -> str:
    """A page's file stem: --paper-setup and --quick runs write pages of their own."""
    return name + ("_paper_setup" if args.paper_setup else "") + ("_quick" if args.quick else "")


def chosen(models, args) -> list[tuple[str, int]]:
    """The (model, channels) of `models` that --models names (all of them without --models)."""
    return [(m, ch) for m, ch in models if not args.models or row_label(m, ch) in args.models]


def _rmse_cell(result: dict | None) -> str:
    return f"{result['final']['test/position_rmse_cm']:.3f}" if result else "not run"


def data_curve_lines(data: dict[str, Path], args, models) -> list[str]:
    """Ball-position test RMSE against the number of Baoding frames (seed 0): does more data
    change the ranking? Sizes 2,500, 5,000, 10,000, --baoding-samples and the whole dataset."""
    total = sum(s["samples"] for s in read_manifest(data["baoding"])["shards"].values())
    sizes = sorted({n for n in (2_500, 5_000, 10_000, args.baoding_samples) if n < total} | {total})
    curve = {}
    for model, ch in models:
        curve[row_label(model, ch)] = [run("baoding", model, ch, 0, data["baoding"], args,
                                           max_samples=0 if n == total else n) for n in sizes]
    lines = ["", "## Does more data change the ranking? (ball positions, seed 0, test RMSE cm)", "",
             "| frames | " + " | ".join(curve) + " |", "|---|" + "---|" * len(curve)]
    for i, n in enumerate(sizes):
        lines.append(f"| {n} | " + " | ".join(_rmse_cell(curve[m][i]) for m in curve) + " |")
    return lines


def keep_weights(ckpt: Path, dest: Path) -> dict:
    """Write to `dest` the finished run's checkpoint without its optimizer state (a third of the size),
    the file the repository keeps and `tacgnn eval-perception --checkpoint` scores again; return it."""
    payload = {k: v for k, v in load_checkpoint(ckpt).items() if k not in ("format_version", "kind")}
    dest.parent.mkdir(parents=True, exist_ok=True)
    save_checkpoint(dest, {**payload, "optimizer": {}})
    return payload


def write_table1_results(data: dict[str, Path], args, seeds) -> None:
    """results/table1/OBJECT_MODEL_sSEED.json of every complete Table I run this invocation
    trained (--models, --objects): its final train and test errors, seconds per epoch and provenance,
    which names the run's weights kept as results/table1/checkpoints/OBJECT_MODEL_sSEED.pt."""
    out = ROOT / "results" / "table1"
    for obj in (o for o in OBJECTS if o in data):
        for m, ch in chosen(TABLE1_MODELS, args):
            for s in seeds:
                r = run(obj, m, ch, s, data[obj], args)
                if not r:
                    continue
                name = f"{obj}_{row_label(m, ch)}_s{s}"
                kept = out / "checkpoints" / f"{name}.pt"
                cfg = keep_weights(r["ckpt"], kept)["config"]
                result = {"object": obj, "model": row_label(m, ch), "epochs": len(r["history"]), **r["final"],
                          "seconds_per_epoch": float(np.mean([h["seconds"] for h in r["history"]])),
                          "provenance": provenance({"perception": kept}, s,
                                                   {**cfg, "dataset": str(data[obj].relative_to(ROOT))})}
                atomic_write_text(out / f"{name}.json", json.dumps(result, indent=1) + "\n")


def table1_lines(data: dict[str, Path], args, seeds) -> list[str]:
    """Table I (object pose after a power grasp), ours beside the paper's, as markdown lines."""
    ours_head = " | ".join(m.upper() if m != "tacgnn" else f"TacGNN-{ch}" for m, ch in TABLE1_MODELS)
    lines = ["", "## Table I: object pose after a power grasp (test RMSE: position cm / orientation deg)", "",
             f"| object | metric | {ours_head} | paper MLP | paper CNN | paper GCN | paper TacGNN |",
             "|---|---|" + "---|" * (len(TABLE1_MODELS) + 4)]
    seconds: dict[tuple[str, int], list[float]] = {key: [] for key in TABLE1_MODELS}
    for obj in (o for o in OBJECTS if o in data):
        res = {(m, ch): [r for s in seeds if (r := run(obj, m, ch, s, data[obj], args))] for m, ch in TABLE1_MODELS}
        for key, runs in res.items():
            seconds[key] += [h["seconds"] for r in runs for h in r["history"]]
        for metric, idx, label in (("test/position_rmse_cm", 0, "position (cm)"),
                                   ("test/orientation_rmse_deg", 1, "orientation (deg)")):
            ours = [mean_std([r["final"][metric] for r in res[key]]) for key in TABLE1_MODELS]
            paper = [str(PAPER_TABLE1[obj][m][idx]) for m in ("mlp", "cnn", "gcn", "tacgnn")]
            lines.append(f"| {obj} | {label} | " + " | ".join(ours + paper) + " |")
    # what the table costs: the training time of its runs on this machine
    lines.append("| all | s/epoch | " + " | ".join(f"{np.mean(v):.0f}" if v else "-" for v in seconds.values())
                 + " | - | - | - | - |")
    return lines


def plot_curves(table2, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for key, runs in table2.items():
        if not runs:
            continue
        h = runs[0]["history"]
        ax.plot([r["epoch"] + 1 for r in h], [r["test/position_rmse_cm"] for r in h], label=row_label(*key), marker="o",
                ms=3)
    ax.set_xlabel("epoch")
    ax.set_ylabel("test RMSE (cm)")
    ax.set_yscale("log")
    ax.set_title("Ball positions from the skin")
    ax.legend(fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda fh: fig.savefig(fh, dpi=120, format=Path(path).suffix[1:] or "png"))


if __name__ == "__main__":
    raise SystemExit(run_script(main))
