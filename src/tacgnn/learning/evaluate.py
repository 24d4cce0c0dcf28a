"""Success rate of a trained policy on a Baoding task, with a 95 % confidence interval.

    tacgnn evaluate runs/gt/model_005000.pt --task middle --episodes 500

`--perception FILE` runs the policy on another perception's ball positions (a perception
checkpoint, or the perception inside another blind policy): a ground-truth policy made
blind, or two blind policies with their perceptions exchanged, judge perception and
control apart.

Episodes are counted per env, each env contributing a fixed quota (episodes / num_envs).
Counting whatever ends first would over-represent short episodes (quick successes and
quick falls), biasing the rate; with a per-env quota every counted episode is an
independent draw of the same distribution, whatever its length.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from tacgnn.config import ConfigError, override, parse_overrides, to_dict
from tacgnn.envs.baoding import BaodingEnv
from tacgnn.files import FileProblem, atomic_write_text, check_writable, read_weights
from tacgnn.learning import checkpoint as ckpt
from tacgnn.learning.online_perception import OnlinePerception, OnlinePerceptionConfig
from tacgnn.learning.policy import load_perception, perception_from_checkpoint, policy_from_checkpoint
from tacgnn.perception.checkpoint import load_checkpoint as load_perception_checkpoint
from tacgnn.perception.checkpoint import stored_config
from tacgnn.perception.models import PerceptionModelConfig
from tacgnn.perception.train_config import PerceptionTrainConfig
from tacgnn.provenance import provenance

TASKS_180: tuple[Literal["simple", "middle", "hard", "hold"], ...] = (  # the paper's three, and Simple with a 1 s hold
    "simple", "middle", "hard", "hold")
TASKS = (*TASKS_180, "continuous")  # and as many turns as possible in 10 s
PERCEPTION_FROM_STEP = 6  # the perception's in-loop error counts from here (the balls drop from the spawn before)


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (sound near 0 and 1, unlike p +- z se).

    centre = (p + z^2 / 2n) / (1 + z^2 / n),
    half   = z / (1 + z^2 / n) * sqrt(p (1 - p) / n + z^2 / 4n^2).
    """
    if n == 0:
        return (0.0, 1.0)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    lo = 0.0 if successes == 0 else max(0.0, centre - half)  # exact at the ends, not 1e-17 off
    hi = 1.0 if successes == n else min(1.0, centre + half)
    return (lo, hi)


def seed_bootstrap_difference(
    a: list[tuple[int, int]], b: list[tuple[int, int]], draws: int = 20_000, seed: int = 0
) -> tuple[float, float, float]:
    """Pooled success rate of `a` minus that of `b`, with a 95 % bootstrap interval.

    `a` and `b` hold one (successes, episodes) pair per training seed. Each draw
    resamples the seeds of each side with replacement, then the episodes of each drawn
    seed (binomial at that seed's rate), so the interval carries the spread between
    seeds as well as the episode noise; a pooled Wilson interval carries only the latter.
    With two or three seeds per side the seed level is coarse: read the interval as a
    lower bound on the uncertainty.
    """
    if not a or not b or any(n <= 0 or not 0 <= k <= n for k, n in (*a, *b)):
        raise ValueError(f"need at least one seed per side with 0 <= successes <= episodes > 0, got {a} and {b}")
    rng = np.random.default_rng(seed)

    def pooled_draws(runs: list[tuple[int, int]]) -> np.ndarray:
        k, n = np.array(runs, dtype=float).T
        pick = rng.integers(0, len(runs), size=(draws, len(runs)))
        wins = rng.binomial(n[pick].astype(np.int64), k[pick] / n[pick])
        return wins.sum(1) / n[pick].sum(1)

    def pooled(runs: list[tuple[int, int]]) -> float:
        return sum(k for k, _ in runs) / sum(n for _, n in runs)

    diff = pooled_draws(a) - pooled_draws(b)
    lo, hi = np.quantile(diff, [0.025, 0.975])
    return pooled(a) - pooled(b), float(lo), float(hi)


def perception_from_file(path: str | Path, skin: dict) -> OnlinePerception:
    """The frozen perception in `path`: a `train-perception` checkpoint for the Baoding balls
    (single-frame or temporal), or the perception a 'perceived' policy checkpoint was trained with."""
    if not Path(path).is_file():
        raise FileNotFoundError(f"perception file not found: {path}")
    raw = read_weights(Path(path), "perception or policy file")
    if not (isinstance(raw, dict) and "actor_state_dict" in raw):  # a perception checkpoint, or it says why not
        stored = stored_config(PerceptionTrainConfig, load_perception_checkpoint(path)["config"], path, "config")
        # the checkpoint's task, skin and architecture are checked and taken where it is read (`with_pretrained`)
        cfg = OnlinePerceptionConfig(model=PerceptionModelConfig(name=stored.model.name), pretrained=str(path),
                                     temporal=stored.temporal, window=1, buffer_size=32, batch_size=32, epochs=0)
        return OnlinePerception(cfg, skin)
    try:
        perception = load_perception(path)
    except (ValueError, FileProblem) as err:
        raise ckpt.CheckpointError(f"{path}: neither a perception checkpoint nor a policy checkpoint ({err})") from None
    if perception is None:
        raise ckpt.CheckpointError(f"{path}: a policy trained without a perception (not obs_mode 'perceived')")
    return perception


def evaluate(checkpoint: str | Path, task: Literal["simple", "middle", "hard", "hold", "continuous"] = "simple",
             episodes: int = 100, num_envs: int = 64, seed: int = 0,
             perception: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
             env_overrides: dict[str, Any] | None = None, perception_from: str | Path | None = None,
             allow_task_change: bool = False) -> dict:
    """Run the deterministic policy of `checkpoint` on `task` until `episodes` episodes ended.

    The env is the one the policy was trained in (obs mode, physics, randomisation) with
    the task, number of envs and seed replaced, and `env_overrides` (dotted config keys,
    e.g. ``{"hand.stiffness": 2.0, "randomization.enabled": False}``: another hand than the
    one trained on) applied. With `perception_from` (see `perception_from_file`) a policy
    that reads ball positions ('groundtruth' or 'perceived') reads that perception's.
    Returns success_rate, mean_steps_to_success (NaN without successes), ci95 (Wilson) of
    the success rate, episodes, plus fall_rate and mean_final_angle_deg; and the turns
    (rotations_mean with a 95 % interval, rotations_max: full turns of the ball pair per
    episode), the figure of the continuous task. A policy trained on a 180-degree task is
    evaluated on the continuous one only with `allow_task_change`.
    """
    if task not in TASKS:
        raise ConfigError(f"task must be one of {list(TASKS)}, got {task!r}")
    if episodes < 1:
        raise ConfigError(f"episodes must be >= 1, got {episodes}")
    if num_envs < 1:
        raise ConfigError(f"num_envs must be >= 1, got {num_envs}")
    # configs first: a policy that cannot act in the requested env is named before any tensor exists
    data = ckpt.load_policy_file(checkpoint)
    n = min(num_envs, episodes)
    stored = ckpt.stored_env_config(data, checkpoint)
    if (task == "continuous") != (stored.task == "continuous") and not allow_task_change:
        raise ConfigError(f"{checkpoint} was trained on the '{stored.task}' task, not '{task}': pass "
                          f"--allow-task-change to evaluate it there anyway")
    env_cfg = replace(stored, task=task, num_envs=n, seed=seed)
    env_cfg = override(env_cfg, env_overrides or {})
    ckpt.check_policy_fits(data, env_cfg, checkpoint)
    if perception_from is not None:
        if env_cfg.obs_mode not in ("groundtruth", "perceived"):
            raise ckpt.CheckpointError(f"{checkpoint}: a policy of obs_mode '{env_cfg.obs_mode}' does not read ball "
                             "positions; --perception needs a 'groundtruth' or 'perceived' policy")
        perception = perception_from_file(perception_from, to_dict(env_cfg.skin))
        env_cfg = replace(env_cfg, obs_mode="perceived", tactile=True)
    if perception is None and env_cfg.obs_mode == "perceived":
        perception = perception_from_checkpoint(data, checkpoint)
    if isinstance(perception, OnlinePerception) and perception.readings.shape[1] != env_cfg.skin.num_taxels:
        raise ckpt.CheckpointError(f"the perception reads {perception.readings.shape[1]} taxels, "
                         f"the env's skin has {env_cfg.skin.num_taxels}")
    policy = policy_from_checkpoint(data, checkpoint)
    env = BaodingEnv(env_cfg, perception=perception)
    obs, _ = env.reset(seed=seed)

    quota = np.full(n, episodes // n)
    quota[: episodes % n] += 1
    counted = np.zeros(n, np.int64)
    successes, falls, steps_to_success, final_angles = 0, 0, [], []
    squared, frames = 0.0, 0  # the perception's error in the loop (perceived policies)
    while (counted < quota).any():  # every episode ends within max_episode_steps
        obs, _, terminated, truncated, info = env.step(policy(obs))
        if env_cfg.obs_mode == "perceived":
            going = ~(terminated | truncated) & (info["episode_steps"] >= PERCEPTION_FROM_STEP) & (counted < quota)
            squared += matched_squared_error(env.perceived_balls[going], info["ball_pos"][going].reshape(-1, 6))
            frames += int(going.sum())
        # Same-step autoreset: `info` describes the episodes that just ended, `obs` the new ones.
        ids = np.flatnonzero((terminated | truncated) & (counted < quota))
        counted[ids] += 1
        won = ids[info["success"][ids]]
        successes += len(won)
        falls += int(info["fall"][ids].sum())
        steps_to_success += info["episode_steps"][won].tolist()
        final_angles += info["angle_deg"][ids].tolist()

    return {
        "task": task,
        "episodes": episodes,
        "success_rate": successes / episodes,
        "ci95": wilson_interval(successes, episodes),
        "mean_steps_to_success": float(np.mean(steps_to_success)) if steps_to_success else float("nan"),
        "fall_rate": falls / episodes,
        "mean_final_angle_deg": float(np.mean(final_angles)),
        **_turns(np.asarray(final_angles) / 360.0),
        "perception_rmse_cm": 100 * math.sqrt(squared / (6 * frames)) if frames else None,
    }


def matched_ball_errors(perceived: np.ndarray, true: np.ndarray) -> np.ndarray:
    """(F, 2) squared errors (m^2) of each ball of (F, 6) ball positions, each frame in the better ball
    order (the balls look alike)."""
    p, t = perceived.reshape(-1, 2, 3), true.reshape(-1, 2, 3)
    same, swapped = ((p - t) ** 2).sum(-1), ((p - t[:, ::-1]) ** 2).sum(-1)
    return np.where((same.sum(1) <= swapped.sum(1))[:, None], same, swapped)


def matched_squared_error(perceived: np.ndarray, true: np.ndarray) -> float:
    """Sum of squared coordinate errors (m^2) of (F, 6) ball positions, each frame in the better ball order."""
    return float(matched_ball_errors(perceived, true).sum())


def _turns(turns: np.ndarray) -> dict[str, Any]:
    """Mean full turns per episode with a normal-approximation 95 % interval, and the best."""
    half = 1.959964 * turns.std(ddof=1) / np.sqrt(len(turns)) if len(turns) > 1 else float("nan")
    return {"rotations_mean": float(turns.mean()),
            "rotations_ci95": (float(turns.mean() - half), float(turns.mean() + half)),
            "rotations_max": float(turns.max())}


def main(argv: list[str] | None = None, parser_class: type[argparse.ArgumentParser] = argparse.ArgumentParser) -> int:
    """`tacgnn evaluate`; user errors raise (ConfigError, CheckpointError, OSError), for the CLI to report."""
    parser = parser_class(prog="tacgnn evaluate",
                          description="Evaluate a PPO checkpoint on the Baoding tasks (Table III).")
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--task", default="all", choices=(*TASKS, "all"),
                        help="'all': the four 180-degree tasks; 'continuous': turns in 10 s")
    parser.add_argument("--allow-task-change", action="store_true",
                        help="evaluate a policy trained for the 180-degree tasks on the continuous one, or the reverse")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, help="also write the results as JSON here")
    parser.add_argument("--perception", type=Path, metavar="FILE",
                        help="run the policy on this perception's ball positions: a perception checkpoint "
                             "(tacgnn train-perception) or a blind policy checkpoint")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="env config changes for the evaluation, e.g. hand.stiffness=2.0 ball_mass=0.25")
    return _evaluate_command(parser.parse_args(argv))


def _evaluate_command(args: argparse.Namespace) -> int:
    for flag, value in (("--episodes", args.episodes), ("--envs", args.envs)):
        if value < 1:
            raise ConfigError(f"{flag} must be >= 1, got {value}")
    if args.out:  # a result that cannot be written is found out before the episodes, not after
        if args.out.is_dir():
            raise FileProblem(f"--out {args.out} is a folder; give the JSON file to write")
        check_writable(args.out.parent, "folder of --out")
    tasks = TASKS_180 if args.task == "all" else (args.task,)
    changes = parse_overrides(args.set)
    results = [evaluate(args.checkpoint, task, args.episodes, args.envs, args.seed, env_overrides=changes,
                        perception_from=args.perception, allow_task_change=args.allow_task_change)
               for task in tasks]
    for r in results:
        r["env_overrides"] = changes
        r["perception"] = None if args.perception is None else str(args.perception)
        r["provenance"] = provenance({"policy": args.checkpoint, "perception": args.perception}, args.seed,
                                     {"task": r["task"], "episodes": args.episodes, "envs": args.envs, "set": args.set})
    print(f"{args.checkpoint}: {args.episodes} episodes per task, deterministic policy"
          + (f", env changed: {' '.join(args.set)}" if args.set else "")
          + (f", ball positions from {args.perception}" if args.perception else ""))
    print(f"{'task':8s} {'success':>8s} {'95% CI':>13s} {'steps':>6s} {'falls':>6s}")
    for r in results:
        lo, hi = r["ci95"]
        seen = "" if r["perception_rmse_cm"] is None else f"  perception {r['perception_rmse_cm']:.3f} cm"
        if r["task"] == "continuous":
            tlo, thi = r["rotations_ci95"]
            print(f"{r['task']:8s} {r['rotations_mean']:.2f} turns per episode (95% CI {tlo:.2f}-{thi:.2f}, "
                  f"best {r['rotations_max']:.2f}), falls {100 * r['fall_rate']:.1f}%{seen}")
            continue
        print(f"{r['task']:8s} {100 * r['success_rate']:7.1f}% {100 * lo:5.1f}-{100 * hi:5.1f}% "
              f"{r['mean_steps_to_success']:6.1f} {100 * r['fall_rate']:5.1f}%{seen}")
    if args.out:
        atomic_write_text(args.out, json.dumps(results if len(results) > 1 else results[0], indent=2))
    return 0
