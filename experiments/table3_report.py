"""Table III: success of the ground-truth teacher and of the blind policies, beside the paper's.

    .venv/bin/python experiments/table3_report.py [--iterations 400] [--folder DIR] [--figure PNG]

Reads results/table3/*.json (written by `experiments/baoding_pipeline.sh` through `tacgnn
evaluate`; `--folder results/table3_real_hand` for `experiments/table3_real_hand.sh`'s) and prints
one markdown row per run: success on Simple / Middle / Hard and the 1 s hold (with Wilson 95 %
intervals; for several seeds, each seed's rate), mean steps to success and the perception's error in
the loop (blind runs), beside the paper's figures. Runs of several seeds of one model are pooled;
every two blind runs with two seeds or more get the seed-bootstrap interval of their difference.
`--figure` draws each run's success per task, a bar for the pooled rate and a dot per seed.
"""

from __future__ import annotations

import argparse
import json
import re
from collections import defaultdict
from pathlib import Path

import numpy as np

from tacgnn.learning.evaluate import seed_bootstrap_difference
from tacgnn.user_errors import run_script

ROOT = Path(__file__).resolve().parents[1]
PAPER = {  # model: success % Simple / Middle / Hard, mean steps
    "mlp": ((52.44, 45.57, 41.78), (76, 77, 79)), "cnn": ((42.71, 63.75, 50.88), (147, 133, 119)),
    "gcn": ((70.62, 64.51, 55.11), (100, 87, 103)), "tacgnn": ((94.71, 88.57, 79.78), (82, 86, 94)),
}
TASKS = ("simple", "middle", "hard", "hold")


def load(folder: Path, iterations: int | None) -> dict[str, list[dict]]:
    """{run label: [per-seed {task: result}]} of the result files of `folder`."""
    runs: dict[str, list[dict]] = defaultdict(list)
    for path in sorted(folder.glob("*.json")):
        m = re.fullmatch(r"(.+?)(?:_s(\d+))?_model_(\d+)", path.stem)
        if not m or (iterations and m.group(1).startswith("blind") and int(m.group(3)) != iterations):
            continue
        results = json.loads(path.read_text())
        label = f"{m.group(1)} ({int(m.group(3))} it.)"
        runs[label].append({r["task"]: r for r in (results if isinstance(results, list) else [results])})
    return runs


def figure(runs: dict[str, list[dict]], path: Path) -> None:
    """Success per task: a bar per run (pooled over its seeds), a dot per seed."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.2))
    width = 0.8 / len(runs)
    for i, (label, seeds) in enumerate(runs.items()):
        x = np.arange(len(TASKS)) + (i - (len(runs) - 1) / 2) * width
        per_seed = np.array([[100 * s[t]["success_rate"] if t in s else np.nan for t in TASKS] for s in seeds])
        ax.bar(x, np.nanmean(per_seed, 0), width, label=f"{label.split(' (')[0]} ({len(seeds)})", alpha=0.6)
        for row in per_seed:
            ax.plot(x, row, "k.", markersize=4)
    ax.set_xticks(np.arange(len(TASKS)), ["Simple", "Middle", "Hard", "1 s hold"])
    ax.set_ylabel("success (%)")
    ax.set_ylim(50, 100)
    ax.legend(fontsize=7, ncol=5, loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"figure: {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iterations", type=int, default=None, help="only blind runs evaluated at this many iterations")
    ap.add_argument("--folder", type=Path, default=ROOT / "results" / "table3")
    ap.add_argument("--figure", type=Path, default=None, help="also draw the table as a figure (PNG)")
    args = ap.parse_args()
    runs = load(args.folder, args.iterations)
    if args.figure is not None:
        figure(runs, args.figure)
    print("| policy | seeds | Simple | Middle | Hard | 1 s hold | steps (S/M/H) "
          "| perception in the loop, cm (S/M/H/hold) | paper (S/M/H) | paper steps |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for label, seeds in runs.items():
        cells = []
        for task in TASKS:
            done = [s[task] for s in seeds if task in s]
            if not done:
                cells.append("-")
                continue
            wins = sum(round(r["success_rate"] * r["episodes"]) for r in done)
            n = sum(r["episodes"] for r in done)
            if len(done) == 1:  # one seed: its Wilson interval; several: each seed's rate
                lo, hi = done[0]["ci95"]
                spread = f" ({100 * lo:.1f}-{100 * hi:.1f})"
            else:
                spread = " (" + ", ".join(f"{100 * r['success_rate']:.1f}" for r in done) + ")"
            cells.append(f"{100 * wins / n:.1f}{spread}")
        steps = "/".join(f"{np.nanmean([s[t]['mean_steps_to_success'] for s in seeds if t in s]):.0f}"
                         for t in TASKS[:3])
        errors = [[s[t]["perception_rmse_cm"] for s in seeds if s.get(t, {}).get("perception_rmse_cm") is not None]
                  for t in TASKS]
        in_loop = "/".join(f"{np.mean(e):.2f}" for e in errors) if all(errors) else "-"
        model = next((k for k in PAPER if f"_{k}" in label), None)
        paper = PAPER.get(model) if model else None
        print(f"| {label} | {len(seeds)} | " + " | ".join(cells) + f" | {steps} | {in_loop} | "
              + ("/".join(f"{v:.2f}" for v in paper[0]) + " | " + "/".join(map(str, paper[1])) if paper else "- | -")
              + " |")
    blind = [(label, seeds) for label, seeds in runs.items() if label.startswith("blind") and len(seeds) >= 2]
    blind.sort(key=lambda run: not run[0].startswith("blind_tacgnn ("))  # TacGNN minus each other first
    for i, (label_a, seeds_a) in enumerate(blind):  # every pair of blind runs with two seeds or more
        for label_b, seeds_b in blind[i + 1:]:
            for task in TASKS:
                diff = seed_bootstrap_difference(
                    [(round(s[task]["success_rate"] * s[task]["episodes"]), s[task]["episodes"]) for s in seeds_a],
                    [(round(s[task]["success_rate"] * s[task]["episodes"]), s[task]["episodes"]) for s in seeds_b])
                print(f"{label_a} minus {label_b}, {task}: {100 * diff[0]:+.1f} points "
                      f"(seed-bootstrap 95 % interval {100 * diff[1]:+.1f} to {100 * diff[2]:+.1f})")


if __name__ == "__main__":
    raise SystemExit(run_script(main))
