"""The perception-swap table from the evaluations experiments/perception_swap.sh wrote.

    .venv/bin/python experiments/perception_swap_report.py [--out docs/perception_swap.md] [--condition otherhand_x1]

One policy, many perceptions: success % on Simple / Middle / Hard (512 episodes each,
Wilson 95 % intervals), seeds of one perception model pooled in one row with the seeds'
own rates beside it. The first row is the same policy reading the true ball positions.
Then TacGNN-32 (offline) minus each other offline perception, with the seed-and-episode
bootstrap interval of experiments/table3_report.py.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

from table3_report import difference_cells, successes  # experiments/, beside this script

from tacgnn.learning.evaluate import wilson_interval

ROOT = Path(__file__).resolve().parents[1]
TASKS = ("simple", "middle", "hard")
MODELS = ("tacgnn", "tacgnnjoints", "tacgnnraw", "cnn", "gcn", "gcnrest", "mlp", "mlplog")
# experiments/perception_inputs.sh: TacGNN-32 reading the raw force instead of its log, the MLP log1p of it,
# the GCN on the taxels' rest positions instead of their current ones
LABEL = {"tacgnn": "TacGNN-32", "tacgnnraw": "TacGNN-32 with raw force", "cnn": "CNN", "gcn": "GCN",
         "gcnrest": "GCN on rest positions", "mlp": "MLP", "mlplog": "MLP with log force",
         "tacgnnjoints": "TacGNN-32 + joint angles"}
# experiments/table3.sh names the same perceptions with its PSET_TAG (gthard_s0_gcn_rest_t2_pi)
ALIASES = {"gcn_rest": "gcnrest", "tacgnn_joints": "tacgnnjoints"}
# results/swap_gt__gthard_s0_cnn_pi.json, results/swap_gt__blind_cnn_wu4_lr0.0001_hard_s1_model_000600.json
OFFLINE = re.compile(r"swap_gt__gthard_s(\d+)_(\w+?)_pi\.json")
IN_LOOP = re.compile(r"swap_gt__blind_([a-z]+)_(?:wu\d+_)?(?:lr[\d.]+_)?hard_s(\d+)_model_(\d+)\.json")


def offline_model(name: str, teacher_tag: str, file_name: str) -> str | None:
    """The perception model of an offline perception's name (gthard_s1_<name>_pi), or None when it
    belongs to another teacher than the one reported: "gcn_t2" is teacher t2's GCN, "gcn" the first
    teacher's. A name that is no known model raises, so that no perception drops out of the table unseen."""
    known = {**{m: m for m in MODELS}, **ALIASES}
    if teacher_tag:
        if not name.endswith(f"_{teacher_tag}"):
            return None
        name = name.removesuffix(f"_{teacher_tag}")
    elif name not in known and any(name.startswith(f"{k}_") for k in known):
        return None  # <model>_<tag>: a retrained teacher's
    if name not in known:
        raise ValueError(f"{file_name}: unknown perception model {name!r}; known: {', '.join(known)}")
    return known[name]


def cells(records_by_seed: dict[str, list[dict]]) -> list[str]:
    """Pooled rate [CI] (seed rates) for each task."""
    out = []
    for task in TASKS:
        recs = {seed: next(r for r in recs if r["task"] == task) for seed, recs in records_by_seed.items()}
        n = sum(r["episodes"] for r in recs.values())
        wins = sum(successes(r) for r in recs.values())
        lo, hi = wilson_interval(wins, n)
        seeds = " / ".join(f"{100 * r['success_rate']:.1f}" for r in recs.values())
        out.append(f"{100 * wins / n:.1f} [{100 * lo:.1f}-{100 * hi:.1f}]" + (f" ({seeds})" if len(recs) > 1 else ""))
    return out


def table(results: Path, condition: str = "", teacher_tag: str = "") -> str:
    """The tables; with `condition` (e.g. otherhand_x1), those of the evaluations under that env change;
    with `teacher_tag` (experiments/table3.sh's TEACHER_TAG), the offline perceptions trained on that
    teacher's rollouts and run through it, alone."""
    pre = f"{condition}_" if condition else ""
    tt = f"_{teacher_tag}" if teacher_tag else ""
    rows, offline = [], {}
    teacher = results / f"{pre}gt{tt}_hard_s0_model_002000.json"
    if teacher.is_file():
        rows.append(("true ball positions (the policy's own training input)", {"-": json.loads(teacher.read_text())}))
    for kind, pattern in (("offline", OFFLINE), ("in the loop", IN_LOOP)):
        groups: dict[str, dict[str, list[dict]]] = {}
        for path in sorted(results.glob(f"{pre}swap_gt__*.json")):
            if m := pattern.fullmatch(path.name.removeprefix(pre)):
                model, seed = (m.group(2), m.group(1)) if kind == "offline" else (m.group(1), m.group(2))
                if kind == "offline":
                    model = offline_model(model, teacher_tag, path.name)
                    if model is None:
                        continue
                elif tt:
                    continue  # the in-loop swaps ran from the first teacher only
                label = f"s{seed}" if kind == "offline" else f"s{seed} @{int(m.group(3))}"
                groups.setdefault(model, {})[label] = json.loads(path.read_text())
        if kind == "offline":
            offline = groups
        for model in MODELS:
            if model in groups:
                seeds = ", ".join(groups[model])
                rows.append((f"{LABEL[model]}, trained {kind} ({seeds})", groups[model]))
    lines = ["| ball positions from | Simple | Middle | Hard |", "| --- | --- | --- | --- |"]
    lines += [f"| {name} | " + " | ".join(cells(recs)) + " |" for name, recs in rows]
    cross = [] if tt else sorted(results.glob(f"{pre}swap_*_policy__*_perception.json"))  # first teacher's
    if cross:
        lines += ["", "| policy trained with | perception from | Simple | Middle | Hard |", "| --- | --- | --- | --- | --- |"]
        for path in cross:
            policy, perception = path.stem.removeprefix(f"{pre}swap_").split("__")
            lines.append(f"| {policy.removesuffix('_policy')} | {perception.removesuffix('_perception')} | "
                         + " | ".join(cells({"-": json.loads(path.read_text())})) + " |")
    if "tacgnn" in offline and len(offline) > 1:
        lines += ["", "| TacGNN-32 (offline) minus | seeds | Simple | Middle | Hard |", "| --- | --- | --- | --- | --- |"]
        for model in MODELS:
            if model != "tacgnn" and model in offline:
                lines.append(f"| {LABEL[model]} | {len(offline['tacgnn'])} / {len(offline[model])} | "
                             + " | ".join(difference_cells(offline["tacgnn"], offline[model])) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=ROOT / "results")
    parser.add_argument("--out", type=Path, help="also write the table here")
    parser.add_argument("--condition", default="", help="the evaluations under an env change, e.g. otherhand_x1 "
                        "(results/otherhand_x1_swap_..., written by experiments/other_hand.sh)")
    parser.add_argument("--teacher", default="", help="the perceptions of a retrained teacher, e.g. t2 "
                        "(results/..._swap_gt__gthard_sK_MODEL_t2_pi.json, written by experiments/other_hand.sh)")
    args = parser.parse_args()
    text = table(args.results, args.condition, args.teacher)
    print(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
