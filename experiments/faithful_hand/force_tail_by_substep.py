"""Is the squeezing tail between control steps? Ball contact forces per physics substep of a policy.

    .venv/bin/python experiments/faithful_hand/force_tail_by_substep.py POLICY [POLICY ...] \\
        [--episodes 64] [--out results/faithful_hand/force_tail_by_substep.json]

Reads the balls' contact sensors (the 4 strongest contacts per ball, the squeeze term's input)
after every substep of 64 episodes of each ground-truth policy on its own task (seed 123, as the
audit): the 99th percentile over all substeps against the one over the last substep of each control
step (what the end-of-step squeeze term reads), and the contacts above 10 N in each substep. If the
tail were impacts between control steps, the last substep would hold fewer of them.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace

import numpy as np

from tacgnn.config import ConfigError
from tacgnn.envs.baoding import BaodingEnv
from tacgnn.files import atomic_write_text
from tacgnn.learning.policy import load_policy
from tacgnn.provenance import provenance
from tacgnn.user_errors import run_script


def tail(path: str, episodes: int) -> dict:
    policy, cfg = load_policy(path)
    if cfg.obs_mode != "groundtruth":
        raise ConfigError(f"{path}: a ground-truth policy is needed (obs_mode {cfg.obs_mode})")
    env = BaodingEnv(replace(cfg, num_envs=episodes))
    step_one = env.sim.step
    forces: list[np.ndarray] = []  # per substep: (N, 8) forces, 0 for envs whose episode ended
    done = np.zeros(episodes, bool)

    def stepped(nstep: int) -> np.ndarray:
        bad = np.zeros(episodes, bool)
        for _ in range(nstep):
            bad |= step_one(1)
            forces.append(np.where(done[:, None], 0.0, env.ball_contact_forces()))
        return bad

    env.sim.step = stepped
    obs, _ = env.reset(seed=123)
    for _ in range(cfg.max_episode_steps):
        obs, _, term, trunc, _ = env.step(policy(obs))
        done |= term | trunc
        if done.all():
            break
    f = np.stack(forces).reshape(-1, env.substeps, episodes, forces[0].shape[1])  # (steps, substep, N, 8)
    every, last = f[f > 0], f[:, -1][f[:, -1] > 0]
    return {"policy": path, "substeps": env.substeps, "contact_samples": int(every.size),
            "p99_all_substeps": float(np.percentile(every, 99)), "p99_last_substep": float(np.percentile(last, 99)),
            "above_10N_by_substep": [int((f[:, k] > 10).sum()) for k in range(env.substeps)]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("policies", nargs="+")
    ap.add_argument("--episodes", type=int, default=64)
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    rows = [tail(p, args.episodes) for p in args.policies]
    for r in rows:
        print(f"{r['policy']}: p99 {r['p99_all_substeps']:.2f} N over all substeps, {r['p99_last_substep']:.2f} N "
              f"at the end of the step; > 10 N by substep {r['above_10N_by_substep']}")
    if args.out:
        out = {"rows": rows, "provenance": provenance({f"policy_{i}": p for i, p in enumerate(args.policies)}, 123,
                                                       {"episodes": args.episodes})}
        atomic_write_text(args.out, json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
