"""Speed of the simulation: the Baoding env with the skin on against the raw physics of the same states.

Run: .venv/bin/python bench/bench_sim.py [--envs 64 128 256] [--steps 200] [--hand nominal|real]
Prints one table; docs/results.md quotes it. Targets: env >= 80 % of the raw physics rate
("env/raw"), >= 10,000 env steps/s at 50 Hz with the skin on, skin < 5 us per env step.
"raw steps/s" replays, right after each env step, the state that step started from, a control step in
one engine call (no latency, skin, observations, rules or resets): what stepping the model costs on
this workload at that moment. "env/raw" is the env's physics steps/s over it, the issue's measure;
"env/physics" is the share of an env step spent in MuJoCo (the physics timed inside the env, which
also runs slower there than back to back). The env's own work runs partly on a second thread
(`tacgnn.sim.second_thread`). The skin (readings with noise, positions) is timed on the env run's
last state, the one whose contacts and active taxels the table reports. ``--hand real`` runs the
hand of training (`training_env_config`: randomised physics, latencies, encoder effects, the real
skin and its calibration) with the skin observed, as a blind policy's env. ``--actions policy``
drives the fingers with the shipped ground-truth policy on training's torch threads (acting on the
true state; its episodes end as training's do, every 49-62 steps: an env in 50 resets each step),
``wave`` with the scripted finger wave (few contacts; its episodes run to the time limit). The
table gives the mean episode length.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import torch

from tacgnn.envs.baoding import BaodingConfig, BaodingEnv, training_env_config
from tacgnn.envs.scripted import FingerWave
from tacgnn.learning.config import PPOConfig
from tacgnn.learning.policy import SHIPPED_GROUND_TRUTH, load_policy
from tacgnn.user_errors import run_script


def timed_repeats(fn, repeats: int) -> float:
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    return time.perf_counter() - start


def raw_replay(sim, step: Callable[[int], np.ndarray], state: np.ndarray, substeps: int) -> float:
    """Seconds the engine alone takes for one control step from `state` (one call, the controls the
    state holds), timed beside the env step that started there; the env's state and its derived
    fields are put back after."""
    after = sim.batch.state.copy()
    sim.batch.state[...] = state
    start = time.perf_counter()
    step(substeps)
    seconds = time.perf_counter() - start
    sim.batch.state[...] = after
    sim.forward()  # the derived fields (poses the policy reads) of the env's own state again
    return seconds


def driver(env: BaodingEnv, act: Callable[[np.ndarray], np.ndarray] | None) -> Callable[[], np.ndarray]:
    """The next actions: the scripted wave's (`act` None), or a ground-truth policy's on the true state."""
    if act is None:
        wave = FingerWave(env.last_action[0], env.num_envs, seed=0)
        return lambda: wave(None)
    return lambda: act(env.groundtruth_obs())


def bench(num_envs: int, steps: int, nthread: int, hand: str = "nominal", drive: str = "wave",
          nominal: BaodingConfig | None = None, torch_threads: int | None = None) -> dict:
    """One row of the table; `nominal` replaces the nominal hand's config (e.g. another reward);
    the policy runs on `torch_threads` (None: training's)."""
    cfg = (nominal or BaodingConfig()) if hand == "nominal" else replace(training_env_config(), obs_mode="tactile")
    cfg = replace(cfg, num_envs=num_envs, sim=replace(cfg.sim, nthread=nthread))
    act = None
    if drive == "policy":  # the shipped ground truth; its actions mean what they meant in training
        torch.set_num_threads(torch_threads or PPOConfig().torch_threads)  # more: idle OpenMP threads spin
        act, trained = load_policy(SHIPPED_GROUND_TRUTH)
        cfg = replace(cfg, target_band_rad=trained.target_band_rad)
    env = BaodingEnv(cfg)
    env.reset(seed=0)
    next_actions = driver(env, act)
    for _ in range(20):  # warm up, get contacts going
        env.step(next_actions())

    # time the physics inside the env run (same states, same contacts, same resets); after each env
    # step, the raw physics from the state that step's physics started from, then the env's state back
    sim = env.sim
    physics, instrument = [0.0], [0.0]
    start_state: list[np.ndarray] = []

    def timed(engine_call):
        def call(*args):
            start = time.perf_counter()
            if not start_state:  # the step's first engine call (squeeze_peak makes one per substep)
                start_state.append(sim.batch.state.copy())
            copied = time.perf_counter()
            out = engine_call(*args)
            physics[0] += time.perf_counter() - copied
            instrument[0] += copied - start
            return out
        return call

    step, step_controls = sim.step, sim.step_controls
    sim.step, sim.step_controls = timed(step), timed(step_controls)
    env_time, raw_time, ended = 0.0, 0.0, 0
    for _ in range(steps):
        actions = next_actions()
        start = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(actions)
        env_time += time.perf_counter() - start
        ended += int((terminated | truncated).sum())
        raw_time += raw_replay(sim, step, start_state.pop(), env.substeps)
    env_time -= instrument[0]
    sim.step, sim.step_controls = step, step_controls
    contacts = (env.tactile.contacts(env.sim.sensordata)[0] > 0).sum((1, 2)).mean()
    active = (env.tactile_readings() > 0).sum(1).mean()
    readings_time = timed_repeats(env.tactile_readings, steps)
    positions_time = timed_repeats(env.taxel_positions, steps)
    n = num_envs * steps
    return {
        "hand": hand, "actions": drive, "envs": num_envs, "threads": nthread,
        "env steps/s": n / env_time,
        "physics steps/s in env": n * env.substeps / physics[0],
        "env physics steps/s": n * env.substeps / env_time,
        "env/physics": physics[0] / env_time,
        "raw steps/s": n * env.substeps / raw_time,
        "env/raw": raw_time / env_time,
        "readings us/step": 1e6 * readings_time / n,
        "positions us/step": 1e6 * positions_time / n,
        "contacts/env": contacts, "active taxels/env": active, "steps/episode": n / max(ended, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--envs", type=int, nargs="+", default=[64, 128, 256])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--threads", type=int, nargs="+", default=[2])
    parser.add_argument("--hand", choices=["nominal", "real"], nargs="+", default=["nominal", "real"],
                        help="the nominal hand, or the hand of training (randomised, the real skin observed)")
    parser.add_argument("--actions", choices=["wave", "policy"], nargs="+", default=["wave", "policy"],
                        help="the scripted finger wave (balls fall within ~30 steps), or the shipped "
                             "ground-truth policy (episodes as in training)")
    parser.add_argument("--torch-threads", type=int, default=None,
                        help="the policy's torch threads (default: training's, 1); 2 shows idle OpenMP "
                             "threads spinning beside the physics")
    args = parser.parse_args()
    rows = [bench(n, args.steps, t, h, a, torch_threads=args.torch_threads)
            for a in args.actions for h in args.hand for t in args.threads for n in args.envs]
    keys = list(rows[0])
    print(" | ".join(keys))
    fmt = {"env/physics": "{:.3f}", "env/raw": "{:.3f}"}
    for row in rows:
        cells = (fmt.get(k, "{:.1f}").format(row[k]) if isinstance(row[k], float) else str(row[k]) for k in keys)
        print(" | ".join(cells))


if __name__ == "__main__":
    raise SystemExit(run_script(main))
