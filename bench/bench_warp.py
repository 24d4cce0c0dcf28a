"""Env steps/s and the skin's cost on both physics backends: MuJoCo's C engine and MuJoCo Warp.

Run: .venv/bin/python bench/bench_warp.py [--envs 16 64] [--steps 20] [--device cpu|cuda:0]
Prints one table. Each row runs the Baoding env (skin on) for `--steps` control steps
of a scripted finger wave after a warm-up, and times:

* env steps/s: whole env steps (physics, skin, rules);
* physics share: the part spent in the engine's step;
* skin us/step: the readings (noise on) per env step, on the run's last state: the
  compiled numba kernel for 'c', the torch model for 'warp' fed numpy views (as the env
  does), and 'device' the torch model on the engine's device arrays (no host copies,
  what a GPU run would use).

On the CPU MuJoCo Warp is a development target (one launch per kernel, no threads); its
speed is on a GPU, where this script runs unchanged with --device cuda:0. The first Warp
run compiles its kernels (a minute or more), cached after that.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import torch

from tacgnn.envs.baoding import BaodingConfig, BaodingEnv
from tacgnn.envs.scripted import FingerWave


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def timed(fn, repeats: int, device: str = "cpu") -> float:
    _sync(device)
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    _sync(device)
    return time.perf_counter() - start


def bench(backend: str, num_envs: int, steps: int, device: str) -> dict:
    cfg = BaodingConfig(num_envs=num_envs)
    cfg = replace(cfg, sim=replace(cfg.sim, backend=backend, device=device if backend == "warp" else "cpu"))
    start = time.perf_counter()
    env = BaodingEnv(cfg)
    obs, _ = env.reset(seed=0)
    wave = FingerWave(env.last_action[0], num_envs, seed=0)
    for _ in range(5):  # warm up (compiles or loads Warp's kernels), get contacts going
        obs, *_ = env.step(wave(obs))
    setup = time.perf_counter() - start
    actions = [wave(None) for _ in range(steps)]

    physics = [0.0]
    sim_step = env.sim.step

    def timed_sim_step(nstep):
        t = time.perf_counter()
        out = sim_step(nstep)
        physics[0] += time.perf_counter() - t
        return out

    env.sim.step = timed_sim_step
    it = iter(actions)
    env_time = timed(lambda: env.step(next(it)), steps)
    env.sim.step = sim_step

    sim, rng = env.sim, np.random.default_rng(0)
    n = num_envs * steps
    readings = timed(lambda: env.tactile.readings(sim.sensordata, sim.xpos, sim.xmat, rng), steps)
    row = {
        "backend": backend, "device": cfg.sim.device, "envs": num_envs, "setup s": setup,
        "env steps/s": n / env_time, "physics share": physics[0] / env_time,
        "skin us/step": 1e6 * readings / n, "device skin us/step": float("nan"),
        "contacts/env": float((env.tactile.contacts(sim.sensordata)[0] > 0).sum((1, 2)).mean()),
    }
    if backend == "warp":
        views = sim.device_views()
        on_device = timed(lambda: env.tactile.readings(views["sensordata"], views["xpos"], views["xmat"], rng),
                          steps, cfg.sim.device)
        row["device skin us/step"] = 1e6 * on_device / n
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", type=int, nargs="+", default=[16, 64])
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--device", default="cuda:0" if torch.cuda.is_available() else "cpu",
                        help="Warp's device (default: the first GPU if torch sees one, else cpu)")
    parser.add_argument("--backends", nargs="+", default=["c", "warp"], choices=["c", "warp"])
    parser.add_argument("--torch-threads", type=int, default=1,
                        help="torch CPU threads (1: small ops on busy cores are slower threaded)")
    args = parser.parse_args()
    torch.set_num_threads(args.torch_threads)
    rows = [bench(b, n, args.steps, args.device) for b in args.backends for n in args.envs]
    keys = list(rows[0])
    print(" | ".join(keys))
    fmt = {"physics share": "{:.2f}", "env steps/s": "{:.0f}"}
    for row in rows:
        print(" | ".join(fmt.get(k, "{:.1f}").format(row[k]) if isinstance(row[k], float) else str(row[k])
                         for k in keys), flush=True)


if __name__ == "__main__":
    main()
