"""Where a Baoding env step spends its time: cProfile of 300 steps of the bench's workload.

    .venv/bin/python bench/profile_env.py [--envs 64] [--threads 2]

Same set-up as bench/bench_sim.py (scripted finger wave, skin on, 20 warm-up steps).
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
from dataclasses import replace

from tacgnn.envs.baoding import BaodingConfig, BaodingEnv
from tacgnn.envs.scripted import FingerWave
from tacgnn.user_errors import run_script


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--envs", type=int, default=64)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    cfg = BaodingConfig(num_envs=args.envs)
    env = BaodingEnv(replace(cfg, sim=replace(cfg.sim, nthread=args.threads)))
    obs, _ = env.reset(seed=0)
    wave = FingerWave(env.last_action[0], args.envs, seed=0)
    for _ in range(20):
        obs, *_ = env.step(wave(obs))
    actions = [wave(None) for _ in range(300)]
    profiler = cProfile.Profile()
    profiler.enable()
    for a in actions:
        env.step(a)
    profiler.disable()
    pstats.Stats(profiler).sort_stats("tottime").print_stats(15)


if __name__ == "__main__":
    raise SystemExit(run_script(main))
