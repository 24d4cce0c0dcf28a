"""Where a blind policy's perception error in the loop comes from: the same policy and perception
on hands that lack one source of error at a time.

Each variant runs the deterministic policy with its own perception in the env's loop (as
`tacgnn evaluate`, counting from step `PERCEPTION_FROM_STEP`) and splits the ball-position error
(cm, per coordinate, ball order matched per frame) by whether the skin touches each ball now
(an activated taxel within `TOUCH_WITHIN_CM` of its centre). Beside it, the latency floor: the
error of a perfect reading of the frame the policy sees, which a late skin shows some steps
behind (the true positions that many steps ago against now).

    .venv/bin/python experiments/real_hand/inloop_error_parts.py src/tacgnn/assets/baoding_policy.pt \\
        --episodes 256 --seed 1 --out results/real_hand/inloop_error_parts.json
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tacgnn.config import override
from tacgnn.envs.baoding import BaodingEnv
from tacgnn.files import atomic_write_text, check_writable
from tacgnn.learning import checkpoint as ckpt
from tacgnn.learning.evaluate import PERCEPTION_FROM_STEP, matched_ball_errors
from tacgnn.learning.policy import perception_from_checkpoint, policy_from_checkpoint
from tacgnn.perception.evaluation import TOUCH_WITHIN_CM
from tacgnn.perception.sequences import touched_balls
from tacgnn.provenance import provenance
from tacgnn.user_errors import run_script

VARIANTS: dict[str, dict[str, Any]] = {
    "the hand of training": {},
    "no skin latency": {"randomization.skin_latency": (0.0, 0.0)},
    "nominal hand, real skin": {"randomization.enabled": False},
    "nominal hand, ideal skin": {"randomization.enabled": False, "skin_signal.preset": "ideal"},
}


def touched(readings: np.ndarray, taxel_pos: np.ndarray, balls: np.ndarray) -> np.ndarray:
    """(N, 2) whether the skin touches each ball, as the perception's evaluation counts it (positions in m)."""
    return touched_balls(torch.from_numpy(readings), torch.from_numpy(taxel_pos * 100),
                         torch.from_numpy(balls * 100), TOUCH_WITHIN_CM).numpy()


def run(checkpoint: str, overrides: dict[str, Any], episodes: int, num_envs: int, seed: int) -> dict[str, Any]:
    data = ckpt.load_policy_file(checkpoint)
    env_cfg = override(replace(ckpt.stored_env_config(data, checkpoint), task="simple", num_envs=num_envs, seed=seed),
                       overrides)
    perception = perception_from_checkpoint(data, checkpoint)
    if perception is None:
        raise SystemExit(f"{checkpoint}: not a blind policy (it has no perception)")
    policy = policy_from_checkpoint(data, checkpoint)
    env = BaodingEnv(env_cfg, perception=perception)
    obs, _ = env.reset(seed=seed)
    history = [env.ball_positions().reshape(num_envs, 6).copy()] * (env.hand_io.skin_frames + 1)
    sums = {"all": [0.0, 0], "touched": [0.0, 0], "untouched": [0.0, 0], "latency floor": [0.0, 0]}
    ended = successes = 0
    while ended < episodes:
        obs, _, terminated, truncated, info = env.step(policy(obs))
        now = info["ball_pos"].reshape(num_envs, 6)
        history = [now.copy()] + history[:-1]
        going = ~(terminated | truncated) & (info["episode_steps"] >= PERCEPTION_FROM_STEP)
        errors = matched_ball_errors(env.perceived_balls[going], now[going])
        touch = touched(info["tactile"][going], info["taxel_pos"][going], now[going])
        delay = env.skin_frames_late()[going]
        seen = np.stack(history)[delay, np.flatnonzero(going)]  # the true positions at the frame's instant
        for name, values in (("all", errors), ("touched", errors[touch]), ("untouched", errors[~touch]),
                             ("latency floor", matched_ball_errors(seen, now[going]))):
            sums[name][0] += float(values.sum())
            sums[name][1] += values.size
        done = np.flatnonzero(terminated | truncated)
        ended += len(done)
        successes += int(info["success"][done].sum())
    out = {f"{name} cm": 100 * float(np.sqrt(total / (3 * count))) if count else None
           for name, (total, count) in sums.items()}
    return {**out, "touched share": sums["touched"][1] / max(sums["all"][1], 1),
            "success": successes / ended, "episodes": ended, "overrides": {k: str(v) for k, v in overrides.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--episodes", type=int, default=256)
    parser.add_argument("--envs", type=int, default=128)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    check_writable(Path(args.out).parent)
    rows = {}
    for name, overrides in VARIANTS.items():
        rows[name] = run(args.checkpoint, overrides, args.episodes, args.envs, args.seed)
        print(name, {k: round(v, 3) if isinstance(v, float) else v for k, v in rows[name].items()}, flush=True)
    atomic_write_text(args.out, json.dumps({"variants": rows, "provenance": provenance(
        {"policy": args.checkpoint}, args.seed, vars(args))}, indent=1))


if __name__ == "__main__":
    raise SystemExit(run_script(main))
