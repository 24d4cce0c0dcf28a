"""Env steps/s and the skin's cost on both physics backends: MuJoCo's C engine and MuJoCo Warp.

Run: .venv/bin/python bench/bench_warp.py [--envs 16 64] [--steps 20] [--device cpu|cuda:0] [--check]
Prints one table. Each row runs the Baoding env (skin on) for `--steps` control steps
of a scripted finger wave after a warm-up, and times:

* env steps/s: whole env steps (physics, skin, rules);
* physics share: the part spent in the engine's step;
* skin us/step: the readings (noise on) per env step, on the run's last state: the
  compiled numba kernel for 'c', the torch model for 'warp' fed host numpy arrays, and
  'device' the torch model on the engine's device arrays (as the env runs it on Warp).
* host KB/env-step ('warp'): what a GPU run copies between host and device per env step
  as the env drives the engine: the engine's host mirrors (the rows the host changed up
  before each engine call, the arrays the host reads down after it; on the CPU the mirrors
  are switched on for this count) and the skin's traffic (`DeviceTactile.host_bytes`: inputs staged up,
  readings and taxel positions copied down for a consumer that needs numpy: none in this loop, where
  they stay on the device). A line per Warp row splits it, beside the same count with the skin fed
  the host mirrors instead of the device arrays (its readings then come back as numpy).

On the CPU MuJoCo Warp is a development target (one launch per kernel, no threads); its
speed is on a GPU, where this script runs unchanged with --device cuda:0. The first Warp
run compiles its kernels (a minute or more), cached after that.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from typing import Literal

import numpy as np
import torch

from tacgnn.envs.baoding import BaodingConfig, BaodingEnv
from tacgnn.envs.scripted import FingerWave
from tacgnn.user_errors import run_script


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


def bench(backend: Literal["c", "warp"], num_envs: int, steps: int, device: str) -> dict:
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
        "host KB/env-step": float("nan"),
    }
    if backend == "warp":
        traffic = host_traffic(env, [wave(None) for _ in range(steps)])
        host_fed = host_traffic(env, [wave(None) for _ in range(steps)], host_fed=True)
        row["host KB/env-step"] = sum(traffic.values()) / 1024
        row["bytes"] = (traffic, host_fed)
        views = sim.device_views()
        on_device = timed(lambda: env.tactile.readings(views["sensordata"], views["xpos"], views["xmat"], rng),
                          steps, cfg.sim.device)
        row["device skin us/step"] = 1e6 * on_device / n
    return row


def host_traffic(env: BaodingEnv, actions: list[np.ndarray], host_fed: bool = False) -> dict[str, float]:
    """Bytes per env step copied between host and device by a Warp env with host mirrors:
    {'engine': the mirrors, 'skin': the skin's inputs and results}. `host_fed`: the skin
    reads the host mirrors instead of the engine's device arrays (for comparison)."""
    sim, tactile = env.sim, env.tactile
    mirror, engine, skin = sim.mirror, sim.host_bytes, tactile.host_bytes
    sim.mirror = True  # on the CPU the "mirrors" are the views themselves: copying them changes nothing
    host_sensors = sim.host_sensors
    if host_fed:
        sim.host_sensors = None  # the skin reads its contact slots on the host: the mirror copies them too
        tactile.engine_readings = lambda sim, ids, rng: tactile.readings(sim.sensordata[ids], sim.xpos[ids],
                                                                         sim.xmat[ids], rng)
        tactile.engine_positions = lambda sim, ids: tactile.positions(sim.xpos[ids], sim.xmat[ids])
    try:
        for action in actions:
            env.step(action)
    finally:
        sim.mirror, sim.host_sensors = mirror, host_sensors
        if host_fed:
            del tactile.engine_readings, tactile.engine_positions  # back to the class's methods
    steps = len(actions) * env.num_envs
    return {"engine": (sim.host_bytes - engine) / steps, "skin": (tactile.host_bytes - skin) / steps}


def equivalence(num_envs: int, device: str, states: int = 5) -> dict:
    """Max gaps of one control step on Warp from the C engine's states (randomised physics
    but ball mass, middle task's kicks), and of the torch skin from the compiled one."""
    from tacgnn.envs.baoding import RandomizationConfig
    from tacgnn.sim.tactile_device import DeviceTactile

    cfg = BaodingConfig(num_envs=num_envs, task="middle", disturbance_interval=1,
                        randomization=RandomizationConfig(enabled=True, ball_mass=(0.15, 0.15)))
    c = BaodingEnv(cfg)
    w = BaodingEnv(replace(cfg, sim=replace(cfg.sim, backend="warp", device=device)))
    skin = DeviceTactile(cfg.skin, c.model)
    c.reset(seed=0)
    rng = np.random.default_rng(0)
    gaps = {"ball gap m": 0.0, "joint gap rad": 0.0, "skin gap N": 0.0}
    for _ in range(states):
        for _ in range(10):
            c.step(np.clip(c.last_action + 0.05 * rng.standard_normal(c.last_action.shape), -1, 1))
        w.load_state_dict(c.state_dict())
        c.sim.forward()
        gaps["skin gap N"] = max(gaps["skin gap N"], float(np.abs(
            skin.readings(c.sim.sensordata, c.sim.xpos, c.sim.xmat, np.random.default_rng(1))
            - c.tactile.readings(c.sim.sensordata, c.sim.xpos, c.sim.xmat, np.random.default_rng(1))).max()))
        action = np.clip(c.last_action + 0.3 * rng.standard_normal(c.last_action.shape), -1, 1)
        _, _, term, trunc, info_c = c.step(action)
        _, _, _, _, info_w = w.step(action)
        ok = ~(term | trunc)  # rows not reset by the step
        gaps["ball gap m"] = max(gaps["ball gap m"], float(np.abs(info_w["ball_pos"] - info_c["ball_pos"])[ok].max()))
        gaps["joint gap rad"] = max(gaps["joint gap rad"], float(np.abs(w.joint_pos - c.joint_pos)[ok].max()))
    return gaps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", type=int, nargs="+", default=[16, 64])
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--device", default="cuda:0" if torch.cuda.is_available() else "cpu",
                        help="Warp's device (default: the first GPU if torch sees one, else cpu)")
    parser.add_argument("--backends", nargs="+", default=["c", "warp"], choices=["c", "warp"])
    parser.add_argument("--torch-threads", type=int, default=1,
                        help="torch CPU threads (1: small ops on busy cores are slower threaded)")
    parser.add_argument("--check", action="store_true",
                        help="first print the one-step gaps between the backends (same states)")
    args = parser.parse_args()
    torch.set_num_threads(args.torch_threads)
    if args.check:
        gaps = equivalence(max(args.envs), args.device)
        print("one control step, Warp vs C, from the same states: " +
              ", ".join(f"{k} {v:.2e}" for k, v in gaps.items()), flush=True)
    rows = [bench(b, n, args.steps, args.device) for b in args.backends for n in args.envs]
    traffic = [(row["envs"], row.pop("bytes")) for row in rows if "bytes" in row]
    keys = list(rows[0])
    print(" | ".join(keys))
    fmt = {"physics share": "{:.2f}", "env steps/s": "{:.0f}", "host KB/env-step": "{:.2f}"}
    for row in rows:
        print(" | ".join(fmt.get(k, "{:.1f}").format(row[k]) if isinstance(row[k], float) else str(row[k])
                         for k in keys), flush=True)
    for envs, (device_fed, host_fed) in traffic:
        print(f"warp, {envs} envs, host<->device bytes per env step: engine mirrors {device_fed['engine']:,.0f}, "
              f"skin {device_fed['skin']:,.0f} (fed the device arrays, its readings left there), "
              f"total {sum(device_fed.values()):,.0f}; with the skin fed the host mirrors: "
              f"skin {host_fed['skin']:,.0f}, total {sum(host_fed.values()):,.0f}", flush=True)


if __name__ == "__main__":
    raise SystemExit(run_script(main))
