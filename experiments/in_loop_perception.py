"""How well a blind policy's perception follows the balls once the policy acts on it.

    .venv/bin/python experiments/in_loop_perception.py runs/blind_tacgnn_hard_s0/model_000001.pt [--episodes 64]

Prints (1) the Simple-task success of the checkpoint with TacGNN's graphs built by the
numba kernels and by the torch graph ops (for other perception models the two lines are
the same run twice), and (2) the error (cm) of the perceived balls, identity-tracked and
best-permutation, at chosen steps of 64 envs that the policy drives from reset.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from tacgnn.envs.baoding import BaodingEnv
from tacgnn.learning.evaluate import evaluate
from tacgnn.learning.policy import load_perception, load_policy
from tacgnn.perception.models import TacGNN


def perceived_ball_errors(checkpoint: str, num_envs: int = 64, steps: int = 40) -> dict[int, tuple]:
    """Step -> (tracked error cm, best-permutation error cm, envs alive) over envs still running."""
    policy, cfg = load_policy(checkpoint)
    env = BaodingEnv(dataclasses.replace(cfg, num_envs=num_envs, task="simple"), perception=load_perception(checkpoint))
    obs, _ = env.reset(seed=0)
    out = {}
    for t in range(steps):
        obs, _, term, trunc, info = env.step(policy(obs))
        alive = ~(term | trunc)
        true, seen = info["ball_pos"], env.perceived_balls.reshape(-1, 2, 3)
        tracked = np.linalg.norm(seen - true, axis=-1).mean(1)
        swapped = np.linalg.norm(seen[:, ::-1] - true, axis=-1).mean(1)
        out[t] = (100 * tracked[alive].mean(), 100 * np.minimum(tracked, swapped)[alive].mean(), int(alive.sum()))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint")
    ap.add_argument("--episodes", type=int, default=64)
    args = ap.parse_args()
    for compiled in (True, False):
        TacGNN.use_compiled_graphs = compiled
        r = evaluate(args.checkpoint, task="simple", episodes=args.episodes, num_envs=64)
        print(f"{'numba' if compiled else 'torch'} graphs: success {100 * r['success_rate']:.1f} %, "
              f"falls {100 * r['fall_rate']:.1f} % ({args.episodes} Simple episodes)")
    TacGNN.use_compiled_graphs = True
    errors = perceived_ball_errors(args.checkpoint)
    for t in (0, 1, 2, 4, 6, 10, 20, 30, 39):
        print("step %2d: tracked error %.2f cm, best-permutation error %.2f cm, envs running %d" % (t, *errors[t]))


if __name__ == "__main__":
    main()
