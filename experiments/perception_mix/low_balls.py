"""How much of a perception's error on a controller's frames comes from balls out of the hand?

    .venv/bin/python experiments/perception_mix/low_balls.py \\
        --perception results/perception_mix/checkpoints/tacgnn32_temporal_mix.pt \\
        --dataset own=data/fresh_teacher teacher=data/heldout_teacher \\
        --out results/perception_mix/low_balls.json

Each dataset is read from every episode's first frame, as in the loop (`generalisation.py`); the
scored frames are split by whether a ball's centre is under `--below-cm` (a ball dropping out of
the hand, which no skin places), and the position RMSE given with and without those frames.
"""

from __future__ import annotations

import argparse
import json

import torch
from generalisation import named, perception_model

from tacgnn.files import atomic_write_text
from tacgnn.perception.evaluation import ball_errors, predict, scored
from tacgnn.perception.sequences import load_sequences
from tacgnn.provenance import provenance
from tacgnn.user_errors import run_script


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--perception", required=True, help="a train-perception checkpoint or a blind policy")
    parser.add_argument("--dataset", nargs="+", required=True, help="name=folder")
    parser.add_argument("--below-cm", type=float, default=1.5)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)
    model, cfg = perception_model(args.perception)
    rows = {}
    for name, path in named(args.dataset, "--dataset").items():
        data = load_sequences(path)
        keep = scored(cfg, data)
        frames = data.subset(keep.nonzero().squeeze(1)).frames
        se, _, _ = ball_errors(predict(model, data)[keep], frames, cfg.match_balls)
        se = se.reshape(len(frames.targets), -1)
        low = (frames.targets.reshape(len(frames.targets), 2, 3)[:, :, 2] < args.below_cm).any(1)
        rows[name] = {"rmse_cm": float(se.mean().sqrt()), "low_share": float(low.float().mean()),
                      "rmse_cm_without_low": float(se[~low].mean().sqrt()),
                      "rmse_cm_low_only": float(se[low].mean().sqrt())}
        print(f"{name}: {rows[name]}")
    atomic_write_text(args.out, json.dumps({"rows": rows, "below_cm": args.below_cm, "provenance": provenance(
        {"perception": args.perception}, None, {"datasets": args.dataset})}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    raise SystemExit(run_script(main))
