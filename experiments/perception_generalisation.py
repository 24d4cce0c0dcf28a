"""Does the perception shipped inside the blind policy generalise? It against an offline TacGNN-32 on fresh frames.

The blind policy's TacGNN learns in the loop from the policy's own recent frames; an
offline TacGNN-32 (``tacgnn train-perception``, Table II) learns from 50,000 frames of the
ground-truth policy. Both read frames neither has seen: rollouts of the ground-truth policy
with another seed. Writes ``results/perception_generalisation/perception_generalisation.json``
(overall, touched and untouched RMSE in cm, the ratio shipped / offline, provenance).

The fresh frames (3,000, the teacher dataset's settings, seed 7; every step kept, so that a
perception with memory reads each episode from its first frame as in the env)::

    tacgnn make-dataset baoding --out data/baoding_fresh_seq_s7 --samples 3000 --shard-size 3000 \\
        --keep-every 1 --envs 16 --settle-steps 0 --policy runs/gt_hold_s0/model_000300.pt --seed 7
    .venv/bin/python experiments/perception_generalisation.py --dataset data/baoding_fresh_seq_s7 \\
        --offline runs/table2/tacgnn-32_s0/checkpoint.pt
"""

from __future__ import annotations

import argparse
import json

import torch

from tacgnn.config import ConfigError
from tacgnn.datasets.store import read_manifest
from tacgnn.files import atomic_write_text
from tacgnn.learning.policy import SHIPPED_POLICY, load_perception
from tacgnn.perception.checkpoint import load_model
from tacgnn.perception.data import load_tactile
from tacgnn.perception.evaluation import ball_errors, predict, predict_frames
from tacgnn.perception.objectives import Objective
from tacgnn.perception.sequences import load_sequences
from tacgnn.provenance import provenance
from tacgnn.user_errors import run_script


def errors(pred: torch.Tensor, data) -> dict[str, float]:
    """Position RMSE (cm) of predictions `pred` (N, 6) of `data`'s frames: all, touched and untouched balls."""
    out = {"position_rmse_cm": Objective("baoding", True).metrics(pred, data.targets)["position_rmse_cm"]}
    se, touch, _ = ball_errors(pred, data, True)
    return {**out, "touched_rmse_cm": float(se[touch].mean().sqrt()),
            "untouched_rmse_cm": float(se[~touch].mean().sqrt()),
            "untouched_fraction": float((~touch).float().mean())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True, help="fresh frames of the ground-truth policy")
    parser.add_argument("--offline", required=True, help="an offline TacGNN-32 checkpoint (train-perception)")
    parser.add_argument("--policy", default=str(SHIPPED_POLICY), help="the blind policy (default: the shipped one)")
    parser.add_argument("--out", default="results/perception_generalisation/perception_generalisation.json")
    args = parser.parse_args()
    torch.set_num_threads(1)
    shipped = load_perception(args.policy)
    if shipped is None:
        raise ConfigError(f"{args.policy}: holds no perception (not a blind policy)")
    offline, _, _ = load_model(args.offline)
    data = load_tactile(args.dataset, "baoding")
    if shipped.temporal:  # memory: each episode read from its first frame
        sequences = load_sequences(args.dataset)  # the same frames, in episode order
        shipped_row = errors(predict(shipped.model, sequences), sequences.frames)
    else:
        shipped_row = errors(predict_frames(shipped.model, data), data)
    rows = {"shipped": shipped_row, "offline": errors(predict_frames(offline, data), data)}
    ratio = rows["shipped"]["position_rmse_cm"] / rows["offline"]["position_rmse_cm"]
    for name, r in rows.items():
        print(f"{name:>8}: {r['position_rmse_cm']:.3f} cm (touched {r['touched_rmse_cm']:.3f}, untouched "
              f"{r['untouched_rmse_cm']:.3f}, {r['untouched_fraction']:.1%} untouched)")
    print(f"shipped / offline: {ratio:.2f}x (target <= 1.2x)")
    meta = read_manifest(args.dataset)["metadata"]
    result = {"dataset": args.dataset, "frames": len(data), "dataset_seed": meta.get("seed"),
              "controller": meta.get("controller"), **rows, "ratio_shipped_over_offline": ratio,
              "target_ratio": 1.2,
              "provenance": provenance({"policy": args.policy, "offline": args.offline}, meta.get("seed"),
                                       {"dataset": args.dataset})}
    atomic_write_text(args.out, json.dumps(result, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    raise SystemExit(run_script(main))
