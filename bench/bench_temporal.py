"""Inference cost per env step of the temporal perception against the single-frame one, at batch 256.

One env step of a blind policy asks the perception for the balls of every env: the
single-frame TacGNN reads the 256 frames; the temporal TacGNN reads them too (the same
per-frame encoder, 64 features out instead of 6) and steps its filter (GRU, gate) with
the joint angles, the previous actions and its state. Target: temporal <= 2x single-frame.
The MLP and its temporal version are timed beside them.

Frames: 256 real skin frames spread over a sequence dataset (``--dataset``, e.g. data/baoding_seq
made by ``tacgnn make-dataset baoding --keep-every 1``), else synthetic ones (two blobs of
~30 taxels on a random taxel cloud). Untrained weights: the cost does not depend on them.
1 torch thread; several rounds, the best is the headline, the median beside it (the 2
cores are shared).

Usage: ``python bench/bench_temporal.py [--dataset data/baoding_seq] [--rounds 7] [--steps 50] [--channels 32]``
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time

import numpy as np
import torch

from tacgnn.perception.models.build import build_model
from tacgnn.perception.models.temporal import TemporalModelConfig, TemporalPerception
from tacgnn.user_errors import run_script

T, B = 653, 256


def synthetic_frames(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    rest = torch.rand(T, 3, generator=g) * torch.tensor([20.0, 10.0, 4.0])
    near = torch.cdist(rest, rest).argsort(1)
    readings = torch.zeros(B, T)
    for _ in range(2):
        centre = near[torch.randint(0, T, (B,), generator=g), :30]
        readings.scatter_(1, centre, torch.rand(B, 30, generator=g) + 0.1)
    return readings, rest.expand(B, T, 3) + torch.randn(B, 1, 3, generator=g)


def dataset_frames(root: str) -> tuple[torch.Tensor, torch.Tensor]:
    from tacgnn.datasets.store import load

    data = load(root, ["tactile", "taxel_pos"])
    # spread over the whole dataset: its first rows are the first steps of a few episodes (balls still dropping)
    rows = np.linspace(0, len(data["tactile"]) - 1, B).round().astype(np.int64)
    return torch.from_numpy(data["tactile"][rows]), torch.from_numpy(data["taxel_pos"][rows] * 100.0)


def time_it(fn, rounds: int, steps: int) -> tuple[float, float]:
    """(best, median) milliseconds per call over `rounds` rounds of `steps` calls."""
    fn()  # warm up (numba kernels, allocator)
    per_round = []
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(steps):
            fn()
        per_round.append((time.perf_counter() - start) / steps * 1000)
    return min(per_round), statistics.median(per_round)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="", help="a Baoding dataset to take 256 real frames from")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--channels", type=int, default=32, help="TacGNN width, single-frame and temporal alike")
    args = parser.parse_args()
    torch.set_num_threads(1)
    readings, positions = dataset_frames(args.dataset) if args.dataset else synthetic_frames()
    joints, actions = torch.zeros(B, 16), torch.zeros(B, 16)
    print(f"batch {B}, {float((readings > 0).sum(1).float().mean()):.1f} activated taxels per frame "
          f"({'dataset ' + args.dataset if args.dataset else 'synthetic frames'}), TacGNN {args.channels} channels, "
          f"1 thread, load average {os.getloadavg()[0]:.2f}")
    results = {}
    for name in ("tacgnn", "mlp"):
        cfg = TemporalModelConfig()
        cfg = dataclasses.replace(cfg, frame=dataclasses.replace(cfg.frame, name=name, channels=args.channels))
        torch.manual_seed(0)
        single = build_model(dataclasses.replace(cfg.frame, out_dim=6)).eval()
        temporal = TemporalPerception(cfg).eval()
        state = temporal.initial_state(B)
        with torch.inference_mode():
            results[name] = time_it(lambda m=single: m(readings, positions), args.rounds, args.steps)
            results[f"{name} temporal"] = time_it(
                lambda m=temporal, s=state: m.step(readings, positions, joints, actions, s), args.rounds, args.steps)
        base, temp = results[name], results[f"{name} temporal"]
        print(f"{name:>7}: single-frame {base[0]:.2f} ms (median {base[1]:.2f}), temporal {temp[0]:.2f} ms "
              f"(median {temp[1]:.2f}) per env step of {B} envs: ratio {temp[0] / base[0]:.2f}x "
              f"(median {temp[1] / base[1]:.2f}x)")
    ratio = results["tacgnn temporal"][0] / results["tacgnn"][0]
    print(f"target temporal TacGNN <= 2x single-frame: {'met' if ratio <= 2 else 'NOT met'} ({ratio:.2f}x)")


if __name__ == "__main__":
    raise SystemExit(run_script(main))
