"""The ball pair's angle over a continuous-task episode, for a few episodes of each policy.

    .venv/bin/python experiments/continuous_angle.py OUT.png LABEL=CHECKPOINT [...]
        [--episodes 8] [--seed 0] [--set KEY=VALUE ...] [--perception FILE] [--video OUT.mp4]

Each policy runs deterministically in its own training env (task continuous, `--set`
changes applied), `--episodes` envs side by side, each until its first episode ends. The
figure has one panel per policy: turns of the ball-to-ball vector (in the policy's
direction) against time, a cross where a ball fell. A blind policy (obs_mode 'perceived')
gets a second panel: the perception's ball-position error along the episode (cm, the two
balls matched to the truth the cheaper way round), which is what a blind turn can stop on.
`--perception FILE` (a perception checkpoint, as for `tacgnn evaluate --perception`) runs
every policy on that perception's ball positions. `--video` also films the first policy's
first episode (10 s, the skin beside the hand; MUJOCO_GL=egl without a display).
Beside OUT.png a JSON holds the curves' summary (turns per episode, falls, step of each
fall, the mean perception error) with provenance.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from tacgnn.config import override, parse_overrides, to_dict  # noqa: E402
from tacgnn.envs.baoding import BaodingEnv  # noqa: E402
from tacgnn.files import atomic_write, atomic_write_text  # noqa: E402
from tacgnn.learning.evaluate import perception_from_file  # noqa: E402
from tacgnn.learning.policy import load_perception, load_policy  # noqa: E402
from tacgnn.provenance import provenance  # noqa: E402
from tacgnn.user_errors import labelled_paths, run_script  # noqa: E402


def ball_errors_cm(perceived: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N, 2) distance (cm) of each true ball from its perceived one, the pair matched the cheaper way."""
    p, t = perceived.reshape(-1, 2, 3), truth.reshape(-1, 2, 3)
    straight = np.linalg.norm(p - t, axis=2)
    crossed = np.linalg.norm(p[:, ::-1] - t, axis=2)
    keep = straight.mean(1, keepdims=True) <= crossed.mean(1, keepdims=True)
    return 100 * np.where(keep, straight, crossed)


def perception_error_cm(perceived: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N,) mean distance (cm) of the two perceived balls from the true ones, matched the cheaper way."""
    return ball_errors_cm(perceived, truth).mean(1)


def run_episodes(checkpoint: str, episodes: int, seed: int, changes: dict, perception_file: Path | None) -> dict:
    """Angles (deg, per step) of `episodes` first episodes, the step each ended, falls, perception errors.

    Also each ball's perception error per step (``ball_errors``, (steps, N, 2) cm) and the balls' palm
    coordinates (normal, across, along; m) at each episode's last step (``end_palm``), which say which
    fall rule ended it.
    """
    policy, stored = load_policy(checkpoint)
    cfg = override(replace(stored, task="continuous", num_envs=episodes, seed=seed), changes)
    perception = load_perception(checkpoint) if cfg.obs_mode == "perceived" else None
    if perception_file is not None:
        perception = perception_from_file(perception_file, to_dict(cfg.skin))
        cfg = replace(cfg, obs_mode="perceived", tactile=True)
    env = BaodingEnv(cfg, perception=perception)
    obs, _ = env.reset(seed=seed)
    n, limit = episodes, env.episode_limit
    angles, errors = np.full((limit, n), np.nan), np.full((limit, n), np.nan)
    ball_errors = np.full((limit, n, 2), np.nan)
    end_palm = np.full((n, 2, 3), np.nan)
    ended, fell = np.full(n, -1), np.zeros(n, bool)
    for t in range(limit):
        obs, _, terminated, truncated, info = env.step(policy(obs))
        live = ended < 0
        angles[t, live] = info["angle_deg"][live]
        done = live & (terminated | truncated)
        if perception is not None:  # perceived_balls: this step's prediction, except where an episode ended
            err = ball_errors_cm(env.perceived_balls, info["ball_pos"].reshape(n, 6))
            errors[t, live & ~done] = err[live & ~done].mean(1)
            ball_errors[t, live & ~done] = err[live & ~done]
        end_palm[done] = ((info["ball_pos"] - env.palm_centre) @ env.palm_axes)[done]
        fell[done] = info["fall"][done]
        ended[done] = t
    return {"config": cfg, "angles": angles, "ended": ended, "fell": fell, "end_palm": end_palm,
            "errors": errors if perception is not None else None,
            "ball_errors": ball_errors if perception is not None else None}


def film(checkpoint: str, out: Path, seed: int, changes: dict, perception_file: Path | None) -> None:
    """A video of one continuous-task episode of `checkpoint`, the skin beside the hand."""
    from tacgnn.tools.render import render_episode  # picks an offscreen GL backend before mujoco loads

    policy, stored = load_policy(checkpoint)
    cfg = override(replace(stored, task="continuous", num_envs=1, seed=seed, tactile=True), changes)
    perception = load_perception(checkpoint) if cfg.obs_mode == "perceived" else None
    if perception_file is not None:
        perception = perception_from_file(perception_file, to_dict(cfg.skin))
        cfg = replace(cfg, obs_mode="perceived")
    env = BaodingEnv(cfg, perception=perception)
    obs, _ = env.reset(seed=seed)
    summary = render_episode(env, policy, out, steps=env.episode_limit, obs=obs)
    print(f"video: {out} ({summary['frames']} frames, final angle {summary['final_angle_deg']:.0f} deg)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    parser.add_argument("policies", nargs="+", metavar="LABEL=CHECKPOINT")
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE")
    parser.add_argument("--perception", type=Path, metavar="FILE")
    parser.add_argument("--video", type=Path, metavar="OUT.mp4")
    args = parser.parse_args(argv)
    changes = parse_overrides(args.set)
    items = labelled_paths(args.policies)
    runs = [(label, ckpt, run_episodes(ckpt, args.episodes, args.seed, changes, args.perception))
            for label, ckpt in items]
    rows = sum(1 + (r["errors"] is not None) for _, _, r in runs)
    fig, axes = plt.subplots(rows, 1, figsize=(6.4, 2.3 * rows), sharex=True, squeeze=False)
    summary, row = [], 0
    for label, _ckpt, r in runs:
        dt = r["config"].control_dt
        t = dt * np.arange(1, r["angles"].shape[0] + 1)
        ax = axes[row, 0]
        for i in range(args.episodes):
            line, = ax.plot(t, r["angles"][:, i] / 360, lw=1)
            if r["fell"][i]:
                ax.plot(t[r["ended"][i]], r["angles"][r["ended"][i], i] / 360, "x", color=line.get_color(), ms=7)
        turns = [float(a[~np.isnan(a)][-1] / 360) for a in r["angles"].T]  # at each episode's end
        direction = "counter-clockwise" if r["config"].direction == 1 else "clockwise"
        ax.set_title(f"{label} ({direction}): {np.mean(turns):.1f} turns, {int(r['fell'].sum())}/{args.episodes} "
                     "dropped (x)", fontsize=9)
        ax.set_ylabel("turns")
        ax.grid(alpha=0.3)
        row += 1
        entry = {"label": label, "direction": r["config"].direction, "turns": turns,
                 "falls": int(r["fell"].sum()), "fall_steps": [int(s) for s in r["ended"][r["fell"]]]}
        if r["errors"] is not None:
            ax = axes[row, 0]
            ax.plot(t, r["errors"], lw=0.8)
            ax.set_ylabel("perception\nerror (cm)")
            ax.grid(alpha=0.3)
            entry["perception_error_cm_mean"] = float(np.nanmean(r["errors"]))
            row += 1
        summary.append(entry)
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(args.out, lambda fh: fig.savefig(fh, dpi=90, format=args.out.suffix[1:] or "png"))
    record = {"episodes": summary,
              "provenance": provenance({**{label: ckpt for label, ckpt, _ in runs}, "perception": args.perception},
                                       args.seed, {"episodes": args.episodes, "set": args.set})}
    atomic_write_text(args.out.with_suffix(".json"), json.dumps(record, indent=2))
    if args.video:
        film(items[0][1], args.video, args.seed, changes, args.perception)
    for e in summary:
        print(f"{e['label']}: turns {np.mean(e['turns']):.2f} (per episode {np.round(e['turns'], 2).tolist()}), "
              f"falls {e['falls']}/{args.episodes}")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
