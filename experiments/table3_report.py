"""Table III from the evaluations that experiments/table3.sh wrote, beside the paper's.

    .venv/bin/python experiments/table3_report.py [--iterations 800] [--out docs/table3.md]

Reads results/blind_<model>_hard_s<seed>_model_<iterations>.json (and the ground-truth
teacher's results/gt_hard_s<seed>_model_002000.json; with `--condition C`, the files
results/C_blind_... and results/C_gt_hard_... of evaluations under a changed env; with `--teacher T`,
the runs of table3.sh's TEACHER_TAG=T, results/blind_<model>_wu4_lr0.0001_T_hard_... and
results/gt_T_hard_..., alone), pools the episodes of all seeds of a
row into one success rate with a Wilson 95 % interval, and lists the seeds' own rates
beside it, so the spread over seeds and the uncertainty from the episodes both show.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

from tacgnn.learning.evaluate import seed_bootstrap_difference, wilson_interval

ROOT = Path(__file__).resolve().parents[1]
TASKS = ("simple", "middle", "hard")
PAPER = {  # success %, mean steps to finish; Simple / Middle / Hard
    "mlp": ((52.44, 45.57, 41.78), (76, 77, 79)),
    "cnn": ((42.71, 63.75, 50.88), (147, 133, 119)),
    "gcn": ((70.62, 64.51, 55.11), (100, 87, 103)),
    "tacgnn": ((94.71, 88.57, 79.78), (82, 86, 94)),
}
# (run tag of experiments/table3.sh, label, the paper's row to show beside it)
ROWS = [("mlp", "MLP", "mlp"), ("cnn", "CNN", "cnn"), ("gcn", "GCN", "gcn"), ("tacgnn", "TacGNN-32", "tacgnn"),
        ("mlp_wu4", "MLP, 4 perception warm-up rounds (beyond the paper)", "mlp"),
        ("cnn_wu4", "CNN, 4 perception warm-up rounds (beyond the paper)", "cnn"),
        ("gcn_wu4", "GCN, 4 perception warm-up rounds (beyond the paper)", "gcn"),
        ("tacgnn_wu4", "TacGNN-32, 4 perception warm-up rounds (beyond the paper)", "tacgnn"),
        ("tacgnn_joints", "TacGNN-32 + joint angles (beyond the paper)", None)]
RECIPE_MODELS = (("mlp", "MLP"), ("cnn", "CNN"), ("gcn", "GCN"), ("tacgnn", "TacGNN-32"))
ROWS += [(f"{model}_wu4_lr0.0001", f"{label}, warm-up, PPO learning rate 1e-4 (session 7)", model)
         for model, label in RECIPE_MODELS]


def teacher_rows(teacher: str) -> list[tuple[str, str, str]]:
    """The rows of the runs made from a retrained teacher (table3.sh's TEACHER_TAG): the current
    recipe only, as no other ran from it."""
    rows = [(f"{model}_wu4_lr0.0001_{teacher}", f"{label}, warm-up, learning rate 1e-4, teacher {teacher}", model)
            for model, label in RECIPE_MODELS]
    return rows + [(f"tacgnn_joints_wu4_lr0.0001_{teacher}", f"TacGNN-32 + joint angles, teacher {teacher} "
                    "(beyond the paper)", None),
                   (f"mlp_joints_wu4_lr0.0001_{teacher}", f"MLP + joint angles, teacher {teacher} "
                    "(beyond the paper)", None),
                   (f"tacgnn_c64_wu4_lr0.0001_{teacher}", f"TacGNN-64, teacher {teacher} "
                    "(`PSET_TAG=c64 ... model.channels=64`)", "tacgnn"),
                   (f"gcn_rest_wu4_lr0.0001_{teacher}", f"GCN on the taxels' rest positions, teacher {teacher} "
                    "(`PSET_TAG=rest ... model.gcn_node_positions=rest`)", "gcn")]


def collect(results: Path, run_prefix: str, iterations: int) -> dict[int, list[dict]]:
    """Seed -> the three task records of every evaluated run `<prefix>_s<seed>_model_<iterations>`."""
    found = {}
    pattern = re.compile(rf"{re.escape(run_prefix)}_s(\d+)_model_{iterations:06d}\.json")
    for path in sorted(results.glob("*.json")):
        if m := pattern.fullmatch(path.name):
            found[int(m.group(1))] = json.loads(path.read_text())
    return found


def task_records(per_seed: dict, task: str) -> list[dict]:
    """Every seed's record of one task."""
    return [r for recs in per_seed.values() for r in recs if r["task"] == task]


def successes(record: dict) -> int:
    """Episodes won: the records store the rate."""
    return round(record["success_rate"] * record["episodes"])


def pooled_cells(per_seed: dict[int, list[dict]]) -> list[str]:
    """One markdown cell per task: pooled rate [Wilson CI] (seed rates), mean steps."""
    cells = []
    for task in TASKS:
        records = task_records(per_seed, task)
        if not records:
            cells.append("not run")
            continue
        n = sum(r["episodes"] for r in records)
        won = [successes(r) for r in records]
        wins = sum(won)
        lo, hi = wilson_interval(wins, n)
        # a run without a success has NaN mean steps: it adds nothing
        steps = sum(r["mean_steps_to_success"] * k for r, k in zip(records, won) if k) / max(wins, 1)
        seeds = " / ".join(f"{100 * r['success_rate']:.1f}" for r in records)
        steps_text = f"{steps:.0f} steps" if wins else "no success"
        cells.append(f"**{100 * wins / n:.1f}** [{100 * lo:.1f}-{100 * hi:.1f}] ({seeds}); {steps_text}")
    return cells


def difference_cells(ours: dict, other: dict) -> list[str]:
    """One cell per task: pooled success points of `ours` minus `other` [seed-and-episode
    bootstrap 95 % interval]. Each side maps a seed (or any label) to that run's records, as
    `collect` returns (experiments/perception_swap_report.py passes its own groups)."""
    def runs(per_seed, task):
        return [(successes(r), r["episodes"]) for r in task_records(per_seed, task)]

    cells = []
    for task in TASKS:
        a, b = runs(ours, task), runs(other, task)
        if not a or not b:
            cells.append("not run")
            continue
        diff, lo, hi = seed_bootstrap_difference(a, b)
        cells.append(f"**{100 * diff:+.1f}** [{100 * lo:+.1f}, {100 * hi:+.1f}]")
    return cells


def minus_row(label: str, ours: dict, other: dict) -> str:
    """A markdown row of a "minus" table: the baseline, both seed counts, one difference per task."""
    return f"| {label} | {len(ours)} / {len(other)} | " + " | ".join(difference_cells(ours, other)) + " |"


# the comparison section: TacGNN's row against each baseline of the same recipe
COMPARE = ("tacgnn_wu4_lr0.0001", [("mlp_wu4_lr0.0001", "MLP"), ("cnn_wu4_lr0.0001", "CNN"),
                                   ("gcn_wu4_lr0.0001", "GCN")])
# compared only where it ran (from teacher t2): the GCN without the hand's pose in its node features
COMPARE_IF_RUN = [("gcn_rest_wu4_lr0.0001", "GCN on rest positions")]


def report_command(args: argparse.Namespace) -> str:
    """The command that remakes this page: every option that chose what it reports."""
    command = f".venv/bin/python experiments/table3_report.py --iterations {args.iterations}"
    for option in ("condition", "teacher"):
        if value := getattr(args, option):
            command += f" --{option} {value}"
    return command


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=800, help="PPO iterations of the blind runs to report")
    ap.add_argument("--results", default=str(ROOT / "results"))
    ap.add_argument("--out", default=str(ROOT / "docs" / "table3.md"))
    ap.add_argument("--condition", default="", help="report the evaluations under a changed env instead, "
                    "e.g. otherhand_x1 (results/otherhand_x1_blind_..., written by experiments/other_hand.sh)")
    ap.add_argument("--teacher", default="", help="report the runs of a retrained teacher instead: "
                    "experiments/table3.sh's TEACHER_TAG, e.g. t2 (results/blind_..._t2_hard_..., results/gt_t2_hard_...)")
    args = ap.parse_args()
    results = Path(args.results)
    pre = f"{args.condition}_" if args.condition else ""
    tt = f"_{args.teacher}" if args.teacher else ""
    rows = teacher_rows(args.teacher) if args.teacher else ROWS
    title = "# Table III: blind Baoding, success rate by perception model"
    if args.condition:
        title += (f", evaluated under the change `{args.condition}` (for `otherhand_xK`: "
                  f"`experiments/other_hand.sh {args.iterations} K`, 256 episodes per task)")
    if args.teacher:
        title += (f", runs from the retrained teacher `{args.teacher}` (`TEACHER_TAG={args.teacher} WARMUP=4 "
                  "GT_SEED=0 experiments/table3.sh MODEL SEED N`)")
    lines = [title, "",
             f"Made by `experiments/table3.sh MODEL SEED {args.iterations}` per row and seed (for a "
             f"checkpoint inside a longer run: `tacgnn evaluate RUN/model_{args.iterations:06d}.pt --task all "
             "--episodes 512 --envs 128 --out results/RUN_model_NNNNNN.json`), then "
             f"`{report_command(args)}`. "
             "Rows not marked \"learning rate 1e-4\" ran at the blind stage's old learning rate "
             "(sessions 2-6): prefix `LR=0.0003` to remake them, and `WARMUP=4 GT_SEED=0` for the "
             "warm-up rows. "
             "Each cell: success % pooled over all episodes of all seeds, [Wilson 95 % interval], "
             "(each seed's rate), mean steps to success. The paper's figures follow in the same row.", "",
             "| perception | Simple | Middle | Hard | paper Simple / Middle / Hard | paper steps |",
             "|---|---|---|---|---|---|"]
    teacher = collect(results, f"{pre}gt{tt}_hard", 2000)
    lines.append("| ground truth (teacher, Hard fine-tune) | " + " | ".join(pooled_cells(teacher)) + " | - | - |")
    for key, label, paper_key in rows:
        per_seed = collect(results, f"{pre}blind_{key}_hard", args.iterations)
        paper = PAPER.get(paper_key)
        paper_cells = (" / ".join(map(str, paper[0])), " / ".join(map(str, paper[1]))) if paper else ("-", "-")
        lines.append(f"| {label} | " + " | ".join(pooled_cells(per_seed)) + f" | {paper_cells[0]} | {paper_cells[1]} |")
    ours_key, baselines = COMPARE
    ours = collect(results, f"{pre}blind_{ours_key}{tt}_hard", args.iterations)
    lines += ["", "## TacGNN-32 minus each baseline (learning rate 1e-4, warm-up rows)", "",
              "Success points, TacGNN-32's pooled rate minus the baseline's, with a 95 % interval from "
              "a bootstrap that resamples the seeds of each model and then each seed's episodes "
              "(`tacgnn.learning.evaluate.seed_bootstrap_difference`, 20,000 draws). An interval above "
              "0 means TacGNN-32 is ahead beyond what the seeds and episodes measured can explain; with "
              "two or three seeds per model it understates the spread between seeds.", "",
              "| TacGNN-32 minus | seeds (TacGNN / baseline) | Simple | Middle | Hard |", "|---|---|---|---|---|"]
    others = {label: collect(results, f"{pre}blind_{key}{tt}_hard", args.iterations) for key, label in baselines}
    for key, label in COMPARE_IF_RUN:
        if found := collect(results, f"{pre}blind_{key}{tt}_hard", args.iterations):
            others[label] = found
    for label, other in others.items():
        lines.append(minus_row(label, ours, other))
    # the GCN reads every taxel's current position, that is the hand's pose (docs/results.md, section 12):
    # TacGNN given the pose as joint angles, against it
    with_joints = collect(results, f"{pre}blind_tacgnn_joints_wu4_lr0.0001{tt}_hard", args.iterations)
    if with_joints:
        gcn = others["GCN"]
        lines += ["", "| TacGNN-32 + joint angles minus | seeds | Simple | Middle | Hard |", "|---|---|---|---|---|",
                  minus_row("GCN", with_joints, gcn), minus_row("TacGNN-32", with_joints, ours)]
        # the same pose input given to the MLP: does TacGNN still lead when both read the joint angles?
        if mlp_joints := collect(results, f"{pre}blind_mlp_joints_wu4_lr0.0001{tt}_hard", args.iterations):
            lines.append(minus_row("MLP + joint angles", with_joints, mlp_joints))
    # the wider TacGNN (64 channels, Table I's best) against the same baselines and the 32-channel one
    if wide := collect(results, f"{pre}blind_tacgnn_c64_wu4_lr0.0001{tt}_hard", args.iterations):
        lines += ["", "| TacGNN-64 minus | seeds | Simple | Middle | Hard |", "|---|---|---|---|---|"]
        for label, other in {**others, "TacGNN-32": ours}.items():
            lines.append(minus_row(label, wide, other))
    text = "\n".join(lines) + "\n"
    Path(args.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
