"""Where the env's own time goes: CPU ms per step of the env's parts, beside the physics.

    .venv/bin/python bench/bench_env_parts.py [--envs 256] [--steps 200]

The hand of training (randomised, latencies, skin observed), driven by the shipped ground-truth
policy (its episodes as in training, so resets every few steps). Each part is timed in CPU time
(`time.process_time`, inclusive of what it calls), so time lost to other processes does not count;
the physics' CPU time covers its 2 threads. The parts run in the serial order
(`second_thread.ENABLED = False`: a part on the second thread would count the main thread's CPU too).
Run with nothing else on the machine for wall-clock shares (`bench/bench_sim.py`).
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import torch

from tacgnn.envs import baoding, baoding_terms, randomization
from tacgnn.envs.baoding import BaodingEnv, training_env_config
from tacgnn.learning.config import PPOConfig
from tacgnn.learning.policy import SHIPPED_GROUND_TRUTH, load_policy
from tacgnn.sim import second_thread, skin_signal, tactile
from tacgnn.user_errors import run_script

PARTS = ((skin_signal.SkinSignal, "reset", "reset: skin draw and calibration"),
         (baoding.BaodingEnv, "_spawn_overlaps", "reset: spawn checks"),
         (baoding, "randomize_physics", "reset: randomize_physics (set_const inside)"),
         (baoding.BaodingEnv, "_reset_envs", "reset: all of it"),
         (skin_signal.SkinSignal, "__call__", "skin chain"),
         (tactile.TactileModel, "readings", "contact model"),
         (tactile.TactileModel, "positions", "taxel positions"),
         (baoding.BaodingEnv, "_late_skin", "late-skin ring"),
         (baoding_terms, "copy_obs", "copy_obs"),
         (randomization.HandIO, "observe", "hand_io.observe"),
         (baoding.BaodingEnv, "_reward_terms", "reward terms"))


def timed(spent: dict[str, float], label: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            spent[label] += time.process_time() - start
    return wrapper


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=200)
    args = parser.parse_args()
    second_thread.ENABLED = False
    spent: dict[str, float] = defaultdict(float)
    for owner, name, label in PARTS:
        setattr(owner, name, timed(spent, label, getattr(owner, name)))
    torch.set_num_threads(PPOConfig().torch_threads)  # as in training: idle OpenMP threads spin, on CPU time
    act, trained = load_policy(SHIPPED_GROUND_TRUTH)
    cfg = replace(training_env_config(), obs_mode="tactile", num_envs=args.envs,
                  target_band_rad=trained.target_band_rad)
    env = BaodingEnv(cfg)
    env.sim.step = timed(spent, "physics", env.sim.step)
    env.sim.step_controls = timed(spent, "physics", env.sim.step_controls)  # action latency's engine call
    env.reset(seed=0)
    for _ in range(20):  # warm up: contacts, compiled kernels
        env.step(act(env.groundtruth_obs()))
    spent.clear()
    step_cpu, resets = 0.0, 0
    for _ in range(args.steps):
        actions = act(env.groundtruth_obs())
        start = time.process_time()
        _, _, terminated, truncated, _ = env.step(actions)
        step_cpu += time.process_time() - start
        resets += int((terminated | truncated).sum())
    ms, physics = 1e3 / args.steps, spent["physics"]
    print(f"{args.envs} envs, {resets / args.steps:.2f} resets per step; CPU ms per step: "
          f"env step {step_cpu * ms:.2f}, physics {physics * ms:.2f}, the env's own {(step_cpu - physics) * ms:.2f}")
    for label, seconds in sorted(spent.items(), key=lambda kv: -kv[1]):
        if label != "physics":
            print(f"  {label:45s} {seconds * ms:6.2f}")


if __name__ == "__main__":
    raise SystemExit(run_script(main))
