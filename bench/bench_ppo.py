"""Training throughput of PPO on the Baoding env: env steps per second, learning included.

Run: .venv/bin/python bench/bench_ppo.py [--envs 256] [--iters 10] [--threads 1]
Times rsl_rl's loop (rollout of num_envs x num_steps_per_env steps, then the PPO update)
with the default PPOConfig on GROUNDTRUTH, with the skin computed every step (the env's
default) and without it (GROUNDTRUTH does not read the skin), and splits each iteration
into env stepping, policy inference + bookkeeping, and the update.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import time

import torch

from tacgnn.envs.baoding import BaodingConfig
from tacgnn.learning.config import PPOConfig
from tacgnn.learning.rsl_env import RslBaodingEnv
from tacgnn.learning.runner import make_runner
from tacgnn.learning.train import seed_everything
from tacgnn.user_errors import run_script


def bench(num_envs: int, iters: int, tactile: bool) -> dict:
    ppo = PPOConfig(num_envs=num_envs)
    env = RslBaodingEnv(BaodingConfig(num_envs=num_envs, obs_mode="groundtruth", tactile=tactile),
                        ppo.reward_scale)
    with contextlib.redirect_stdout(io.StringIO()):  # rsl_rl prints the models
        runner = make_runner(env, ppo)
    spent = {"env": 0.0, "update": 0.0}

    def timed(name, fn):
        def wrapper(*args, **kw):
            start = time.perf_counter()
            out = fn(*args, **kw)
            spent[name] += time.perf_counter() - start
            return out
        return wrapper

    env.step = timed("env", env.step)  # type: ignore[method-assign]
    runner.alg.update = timed("update", runner.alg.update)
    runner.learn(2)  # warm up: first contacts, allocator, normaliser
    spent.update(env=0.0, update=0.0)
    start = time.perf_counter()
    runner.learn(iters)
    total = time.perf_counter() - start
    steps = iters * num_envs * ppo.num_steps_per_env
    return {"steps/s": steps / total, "s/iter": total / iters, "env": spent["env"] / total,
            "update": spent["update"] / total, "other": 1 - (spent["env"] + spent["update"]) / total}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--iters", type=int, default=10)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (physics uses sim.nthread)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    seed_everything(0)
    print(f"PPO on Baoding GROUNDTRUTH, {args.envs} envs x 8 steps per iteration, {args.iters} iterations, "
          f"torch threads {args.threads}")
    print(f"{'skin':>6} {'env steps/s':>12} {'s/iter':>8} {'env':>6} {'update':>7} {'policy+other':>13}")
    for tactile in (True, False):
        r = bench(args.envs, args.iters, tactile)
        print(f"{'on' if tactile else 'off':>6} {r['steps/s']:>12,.0f} {r['s/iter']:>8.3f} {r['env']:>6.0%} "
              f"{r['update']:>7.0%} {r['other']:>13.0%}")


if __name__ == "__main__":
    raise SystemExit(run_script(main))
