"""A long session on one skin and one calibration: success per block of episodes, with and without
the tracking baseline (docs/results.md, section 11).

    .venv/bin/python experiments/real_hand/drift_session.py [--policy FILE] [--episodes 256] [--block 32] \
        [--out results/real_hand/drift_session.json]

The simulated hand of `bench/bench_ros.py --reference` (the controller in this process, no ROS):
one skin for the whole session, calibrated once from its rest frames, drifting as the real
skin's config says. Run once with the policy's tracking baseline and once with the baseline
fixed at the calibration's (`skin_signal.baseline_tracking=0`); per block: success and the
skin's mean absolute drift (N).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from tacgnn.envs.baoding import BaodingConfig
from tacgnn.files import atomic_write_text
from tacgnn.learning.policy import SHIPPED_POLICY
from tacgnn.provenance import provenance
from tacgnn.real.sim_hand import SimHand
from tacgnn.user_errors import run_script

_spec = importlib.util.spec_from_file_location("bench_ros", Path(__file__).parents[2] / "bench" / "bench_ros.py")
bench_ros = importlib.util.module_from_spec(_spec)  # type: ignore[arg-type]
_spec.loader.exec_module(bench_ros)  # type: ignore[union-attr]


def session(policy: str, episodes: int, block: int, tracking: bool) -> list[dict]:
    """Success and drift per block of `block` episodes of one session."""
    wins: list[bool] = []
    rows: list[dict] = []

    def fixed_baseline(env: BaodingConfig) -> BaodingConfig:
        return replace(env, skin_signal=replace(env.skin_signal, baseline_tracking=0.0))

    def count(hand: SimHand, success: bool) -> None:
        wins.append(success)
        if len(wins) % block == 0:
            rows.append({"episodes": len(wins), "success": float(np.mean(wins[-block:])),
                         "drift_mean_abs_n": float(np.abs(hand.env.skin_signal.drift[0]).mean())})

    calibration = bench_ros.make_calibration(Path(tempfile.mkdtemp()), policy)
    total = bench_ros.reference(policy, calibration, "simple", episodes, 0,
                                env_change=None if tracking else fixed_baseline, on_episode=count)
    print(f"tracking {'on' if tracking else 'off'}: {total['success_rate']:.3f} of {episodes}; per block of "
          f"{block}: " + ", ".join(f"{r['success']:.2f}" for r in rows))
    return rows + [{"episodes": episodes, "success_total": total["success_rate"]}]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default=str(SHIPPED_POLICY))
    parser.add_argument("--episodes", type=int, default=256)
    parser.add_argument("--block", type=int, default=32)
    parser.add_argument("--out", default="results/real_hand/drift_session.json")
    args = parser.parse_args()
    result: dict[str, Any] = {name: session(args.policy, args.episodes, args.block, tracking)
              for name, tracking in (("tracking", True), ("fixed_baseline", False))}
    result["provenance"] = provenance({"policy": args.policy}, 0, vars(args))
    atomic_write_text(args.out, json.dumps(result, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    raise SystemExit(run_script(main))
