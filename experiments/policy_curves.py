"""Learning curves of PPO runs (the paper's Fig. 4B/4C): training success rate against env steps.

    .venv/bin/python experiments/policy_curves.py OUT.png LABEL=RUN_DIR[,RUN_DIR...] [...]
        [--title T] [--smooth 25] [--iterations N]

Reads each run's TensorBoard scalars (`Episode/success_rate`, logged by rsl_rl every
iteration from the episodes that ended in it) and the run's config for the env steps per
iteration (num_envs x num_steps_per_env). Several event files in one run (a resumed run)
are merged, later files winning. Also prints, per run, the env steps and wall-clock time
at which the smoothed success rate first reached 50 % and 90 %, its final value, and the in-loop
perception's ball-position error at its last update (cm, on frames it had not trained on yet;
for seeds run to different lengths, the last update within the iterations the curve shows).
Several runs in one item (seeds, comma-separated) draw their mean over the iterations all of
them logged, with a band from the lowest to the highest seed (each smoothed); the columns
then read the mean curve, and the wall clock is the slowest seed's.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import yaml

from tacgnn.config import ConfigError
from tacgnn.files import atomic_write
from tacgnn.user_errors import run_script

Scalars = dict[str, dict[int, tuple[float, float]]]


def run_scalars(run_dir: Path) -> Scalars:
    """Tag -> iteration -> (value, wall time) of every TensorBoard scalar of a run, its event files
    merged, later files winning (a resumed run). Each file is parsed once, for all tags."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    scalars: Scalars = {}
    files = sorted(run_dir.glob("events.out.tfevents.*"), key=lambda p: p.stat().st_mtime)
    if not files:
        raise FileNotFoundError(f"{run_dir}: no TensorBoard event files")
    for f in files:
        acc = EventAccumulator(str(f), size_guidance={"scalars": 0})
        acc.Reload()
        for tag in acc.Tags()["scalars"]:
            points = scalars.setdefault(tag, {})
            for e in acc.Scalars(tag):
                points[e.step] = (e.value, e.wall_time)
    return scalars


def success_curve(scalars: Scalars) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(iterations, success rates, wall-clock seconds since the first event) of a run's scalars."""
    points = scalars.get("Episode/success_rate", {})
    steps = np.array(sorted(points))
    values = np.array([points[s][0] for s in steps])
    wall = np.array([points[s][1] for s in steps])
    # resumed runs: count only time spent training, not the gaps between runs
    gaps = np.diff(wall, prepend=wall[0])
    gaps[gaps > 60] = np.median(gaps[gaps <= 60]) if (gaps <= 60).any() else 0.0
    return steps, values, np.cumsum(gaps)


def final_perception_error(scalars: Scalars, last_iteration: int | None = None) -> float | None:
    """The in-loop perception's ball-position error (cm) at its last update, measured on the
    newest frames before it trained on them (`perception/rmse_cm_before`): None for a run
    without perception in the loop. With `last_iteration`, the last update once that iteration
    was done (an update is logged at the count of iterations done: 600 after iteration 599), so
    that seeds run for different lengths are read where their curves are compared."""
    points = scalars.get("perception/rmse_cm_before", {})
    steps = [s for s in points if last_iteration is None or s <= last_iteration + 1]
    return points[max(steps)][0] if steps else None


def error_cell(errors: list[float]) -> str:
    """The seeds' mean perception error, and each seed's when there are several; "-" for none."""
    if not errors:
        return "-"
    cell = f"{np.mean(errors):.3f}"
    if len(errors) > 1:
        cell += " (" + " / ".join(f"{e:.2f}" for e in errors) + ")"
    return cell


def steps_per_iteration(run_dir: Path) -> int:
    cfg = yaml.safe_load((run_dir / "config.yaml").read_text())
    return int(cfg["ppo"]["num_envs"]) * int(cfg["ppo"]["num_steps_per_env"])


def common_iterations(curves: list[tuple[np.ndarray, np.ndarray, np.ndarray]], iterations: int | None = None):
    """(iterations, success rates [runs, iterations], slowest wall clock) on the iterations every run logged;
    with `iterations`, only the first that many (0 .. iterations - 1), so that runs trained longer than
    others are compared at the same length."""
    common = curves[0][0] if iterations is None else curves[0][0][curves[0][0] < iterations]
    for it, _, _ in curves[1:]:
        common = np.intersect1d(common, it)
    if len(common) == 0:
        raise ValueError("the runs share no logged iteration")
    values = np.stack([v[np.searchsorted(it, common)] for it, v, _ in curves])
    wall = np.stack([w[np.searchsorted(it, common)] for it, _, w in curves]).max(axis=0)
    return common, values, wall


def smooth(values: np.ndarray, window: int) -> np.ndarray:
    if window <= 1 or len(values) < window:
        return values
    kernel = np.ones(window) / window
    padded = np.concatenate([np.full(window - 1, values[0]), values])
    return np.convolve(padded, kernel, mode="valid")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    parser.add_argument("runs", nargs="+", help="LABEL=RUN_DIR")
    parser.add_argument("--title", default="Baoding training success")
    parser.add_argument("--smooth", type=int, default=25, help="moving-average window (iterations)")
    parser.add_argument("--iterations", type=int, help="draw and read every run up to this many iterations "
                        "(default: as far as all seeds of an item logged)")
    args = parser.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    print(f"{'run':22s} {'iters':>6s} {'50% at (M steps, min)':>22s} {'90% at (M steps, min)':>22s} "
          f"{'final':>6s} {'perception cm':>14s}")
    for item in args.runs:
        label, _, paths = item.partition("=")
        if not paths:
            raise ConfigError(f"expected LABEL=RUN_DIR[,RUN_DIR...], got {item!r}")
        runs = [Path(p) for p in paths.split(",")]
        per_iteration = {steps_per_iteration(run) for run in runs}
        if len(per_iteration) > 1:
            raise ConfigError(f"{label}: the runs differ in env steps per iteration {sorted(per_iteration)}")
        scalars = [run_scalars(run) for run in runs]
        it, values, wall = common_iterations([success_curve(sc) for sc in scalars], args.iterations)
        env_steps = it * per_iteration.pop() / 1e6
        each = np.stack([smooth(v, args.smooth) for v in values])
        s = each.mean(axis=0)
        line, = ax.plot(env_steps, 100 * s, label=label + (f" ({len(runs)} seeds)" if len(runs) > 1 else ""))
        if len(runs) > 1:
            ax.fill_between(env_steps, 100 * each.min(axis=0), 100 * each.max(axis=0),
                            color=line.get_color(), alpha=0.15, linewidth=0)
        cells = []
        for level in (0.5, 0.9):
            hit = np.flatnonzero(s >= level)
            cells.append(f"{env_steps[hit[0]]:8.2f} M, {wall[hit[0]] / 60:6.1f} min" if len(hit) else "never")
        errors = [final_perception_error(sc, last_iteration=int(it[-1])) for sc in scalars]
        error = error_cell([e for e in errors if e is not None])
        print(f"{label:22s} {it[-1]:6d} {cells[0]:>22s} {cells[1]:>22s} {100 * s[-1]:5.1f}% {error:>14s}")
    ax.set_xlabel("env steps (millions)")
    ax.set_ylabel(f"training success rate (%), {args.smooth}-iteration mean")
    ax.set_ylim(0, 100)
    ax.set_title(args.title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(args.out, lambda fh: fig.savefig(fh, dpi=120, format=Path(args.out).suffix[1:] or "png"))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    raise SystemExit(run_script(main))
