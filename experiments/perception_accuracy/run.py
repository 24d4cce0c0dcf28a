"""One screening run: train (tacgnn.perception.train.train), then split the test error by ball visibility.

    .venv/bin/python experiments/perception_accuracy/run.py NAME [--dataset D] [--epochs E]
        [--max-samples N] [--model tacgnn] [--set key=value ...]

Writes runs/acc/NAME (checkpoint, history) and appends one JSON line to
experiments/perception_accuracy/results.jsonl: config overrides, test/train RMSE (cm), s/epoch,
and the test RMSE of balls that touch the skin ("seen": an activated taxel within 3 cm of the
centre) and of balls that touch no taxel ("blind", nothing within 3 cm).
"""
import argparse
import json
import time
from pathlib import Path

import torch

torch.set_num_threads(1)
from tacgnn.config import override, parse_overrides, to_dict  # noqa: E402
from tacgnn.perception.train import (PerceptionTrainConfig, ball_visibility_errors, load_model,  # noqa: E402
                                     load_tactile, predict, split, train)

ROOT = Path(__file__).resolve().parents[2]
OUT = Path(__file__).with_name("results.jsonl")


def breakdown(model, test, match_balls: bool) -> dict:
    """The library's touched/untouched split, under this screen's result keys."""
    v = ball_visibility_errors(predict(model, test), test, match_balls)
    seen_se = (1 - v["blind_fraction"]) * v["seen_rmse_cm"] ** 2
    blind_se = v["blind_fraction"] * v["blind_rmse_cm"] ** 2
    return {"seen_rmse": v["seen_rmse_cm"], "blind_rmse": v["blind_rmse_cm"],
            "blind_share_of_mse": blind_se / (seen_se + blind_se), "blind_frac": v["blind_fraction"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("name")
    ap.add_argument("--dataset", default="data/baoding_gt50k")
    ap.add_argument("--model", default="tacgnn")
    ap.add_argument("--epochs", type=int, default=10)
    ap.add_argument("--max-samples", type=int, default=0)
    ap.add_argument("--set", nargs="*", default=[])
    ap.add_argument("--note", default="")
    args = ap.parse_args()
    cfg = PerceptionTrainConfig.for_task("baoding", args.model, epochs=args.epochs, max_samples=args.max_samples)
    cfg = override(cfg, parse_overrides(args.set))
    run = ROOT / "runs" / "acc" / args.name
    t0 = time.time()
    logf = open(run.parent / f"{args.name}.log", "w") if run.parent.mkdir(parents=True, exist_ok=True) is None else None
    last = train(cfg, ROOT / args.dataset, run, log=lambda s: (print(s, flush=True), print(s, file=logf, flush=True)))
    model, cfg2, _ = load_model(run / "checkpoint.pt")
    data = load_tactile(ROOT / args.dataset, "baoding", cfg.max_samples, joints=cfg.model.joint_inputs > 0)
    test = split(data, cfg.train_fraction, cfg.seed)[1]
    hist = json.loads((run / "history.json").read_text())
    row = {"name": args.name, "model": args.model, "dataset": args.dataset, "epochs": args.epochs,
           "max_samples": args.max_samples, "set": args.set, "note": args.note,
           "test_rmse": last["test/position_rmse_cm"], "train_rmse": last["train/position_rmse_cm"],
           "best_test": min(h["test/position_rmse_cm"] for h in hist),
           "sec_per_epoch": sum(h["seconds"] for h in hist) / len(hist), "wall": time.time() - t0,
           "params": sum(p.numel() for p in model.parameters()),
           **breakdown(model, test, cfg.match_balls)}
    print(json.dumps(row))
    with OUT.open("a") as f:
        f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
