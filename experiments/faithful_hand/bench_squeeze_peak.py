"""Env speed with the squeeze penalty on the peak force over substeps, against the default.

    .venv/bin/python experiments/faithful_hand/bench_squeeze_peak.py [--envs 256] [--steps 200] [--rounds 3]

Runs bench/bench_sim.py's measurement (skin on, 2 threads) with `reward.squeeze_peak` off and
on, alternating, and prints the best env steps/s of each (target: >= 10,000 at 256 envs).
"""

from __future__ import annotations

import argparse
import importlib.util
from dataclasses import replace
from pathlib import Path

from tacgnn.envs.baoding import BaodingConfig, RewardConfig
from tacgnn.user_errors import run_script


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--envs", type=int, default=256)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    path = Path(__file__).resolve().parents[2] / "bench" / "bench_sim.py"
    spec = importlib.util.spec_from_file_location("bench_sim", path)
    assert spec is not None and spec.loader is not None, path
    bench_sim = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench_sim)
    best: dict[bool, float] = {False: 0.0, True: 0.0}
    for _ in range(args.rounds):
        for peak in (False, True):
            config = replace(BaodingConfig(), reward=RewardConfig(squeeze_peak=peak))
            row = bench_sim.bench(args.envs, args.steps, 2, nominal=config)
            best[peak] = max(best[peak], row["env steps/s"])
            print(f"squeeze_peak={peak}: {row['env steps/s']:.0f} env steps/s", flush=True)
    print(f"best of {args.rounds}: end of step {best[False]:.0f}, peak over substeps {best[True]:.0f} "
          f"env steps/s at {args.envs} envs ({best[True] / best[False]:.2f}x)")


if __name__ == "__main__":
    raise SystemExit(run_script(main))
