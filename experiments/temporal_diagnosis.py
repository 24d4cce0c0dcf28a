"""Where a temporal perception model's test error comes from: episodes, steps, ball states.

Reads one sequence checkpoint and its dataset, places the balls of every test episode (as
``experiments/temporal_perception.py`` does) and writes a JSON of:

* how the test episodes and the training episodes are spread over lengths and steps, and the
  test RMSE by step of the episode and by episode length (coverage of long episodes);
* the worst test episodes: their share of the squared error, length, how the worst ball
  sits (touched share, speed, height, which patches touch it), and whether its estimate sits
  on the other ball (an identity swap the per-frame matching could not undo);
* the error of the frames where the ball is at rest (stuck) against moving;
* the test RMSE (overall, touched, untouched) without the worst 1, 2, 4 episodes, and how many
  training frames lie near the worst episode's last ball pair (within 1.5 cm, either order);
* with ``--compare RUN`` (a single-frame run on the same split), that run's error on the
  worst episodes: whether the frame encoder or the recurrence loses the ball.

Example::

    .venv/bin/python experiments/temporal_diagnosis.py --dataset data/baoding_seq2 \\
        --run runs/temporal2/tacgnn32_temporal --compare runs/temporal2/tacgnn32_single \\
        --out results/temporal_perception/temporal_diagnosis.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from tacgnn.config import ConfigError, from_dict
from tacgnn.datasets.store import read_manifest
from tacgnn.files import atomic_write_text
from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.perception.checkpoint import load_model
from tacgnn.perception.evaluation import ball_errors_since_touch, predict
from tacgnn.perception.evaluation import metrics as frame_metrics
from tacgnn.perception.sequences import SequenceData, load_sequences, split_by_episode
from tacgnn.provenance import provenance
from tacgnn.user_errors import run_script

STEP_BINS = [6, 25, 50, 75, 100, 125, 150, 175, 200]
LENGTH_BINS = [0, 50, 75, 100, 125, 150, 199, 10_000]
REST_CM_PER_STEP = 0.02
"""A ball moving less than this per control step (1 cm/s) is at rest."""


def episode_lengths(data: SequenceData) -> tuple[torch.Tensor, torch.Tensor]:
    """Per frame: its episode's number of frames, and the episode's last step."""
    ids, inverse, counts = torch.unique_consecutive(data.episode, return_inverse=True, return_counts=True)
    last = torch.zeros(len(ids), dtype=torch.long).scatter_reduce(0, inverse, data.step, "amax")
    return counts[inverse], last[inverse]


def binned(values: torch.Tensor, bins: list[int], se: torch.Tensor | None = None) -> list[dict]:
    out = []
    for lo, hi in zip(bins, bins[1:]):
        sel = (values >= lo) & (values < hi)
        row: dict = {"from": lo, "to": hi, "count": int(sel.sum())}
        if se is not None:
            row["rmse_cm"] = float(se[sel].mean().sqrt()) if sel.any() else None
            row["share_of_squared_error"] = float(se[sel].sum() / se.sum())
        out.append(row)
    return out


def ball_speed(data: SequenceData) -> torch.Tensor:
    """(N, 2) cm per step each ball moved since the previous frame (0 at a run's first frame)."""
    t = data.frames.targets.view(-1, 2, 3)
    speed = torch.zeros(len(data), 2)
    speed[1:] = (t[1:] - t[:-1]).norm(dim=-1)
    speed[data.run_starts()] = 0
    return speed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--run", required=True, help="run folder holding checkpoint.pt")
    parser.add_argument("--worst", type=int, default=6, help="worst test episodes to describe")
    parser.add_argument("--compare", default="", help="another run on the same split (e.g. the single-frame one)")
    parser.add_argument("--cache", default="", help="predictions file (.pt): read if present, else written")
    parser.add_argument("--out", default="results/temporal_perception/temporal_diagnosis.json")
    args = parser.parse_args()
    torch.set_num_threads(1)

    ckpt = Path(args.run) / "checkpoint.pt"
    model, cfg, _ = load_model(ckpt)
    data = load_sequences(args.dataset, cfg.max_samples)
    train, test = split_by_episode(data, cfg.train_fraction, cfg.seed)
    if args.cache and Path(args.cache).exists():
        pred = torch.load(args.cache)
    else:
        pred = predict(model, test)
        if args.cache:
            Path(args.cache).parent.mkdir(parents=True, exist_ok=True)
            torch.save(pred, args.cache)
    metrics = frame_metrics(pred, cfg, test)
    se, touch, since = ball_errors_since_touch(pred, test, cfg.match_balls)
    keep = test.step >= cfg.eval_from_step
    frame_se = se.mean(1)

    report: dict = {"dataset": args.dataset, "run": args.run, "metrics": metrics}
    # coverage: frames by step and episodes by length, train against test
    for name, part in (("train", train), ("test", test)):
        length, _ = episode_lengths(part)
        first = part.run_starts()
        report[f"{name}_frames_by_step"] = binned(part.step, STEP_BINS)
        report[f"{name}_episodes_by_length"] = binned(length[first], LENGTH_BINS)
    length, _ = episode_lengths(test)
    report["test_rmse_by_step"] = binned(test.step[keep], STEP_BINS, frame_se[keep])
    report["test_rmse_by_episode_length"] = binned(length[keep], LENGTH_BINS, frame_se[keep])

    # at rest against moving (the worst episodes hold a ball still for long)
    speed = ball_speed(test)
    rest = speed < REST_CM_PER_STEP
    k2 = keep[:, None].expand_as(se)
    report["rest"] = {"rest_cm_per_step": REST_CM_PER_STEP,
                      "at_rest_share": float(rest[k2].float().mean()),
                      "at_rest_rmse_cm": float(se[k2 & rest].mean().sqrt()),
                      "moving_rmse_cm": float(se[k2 & ~rest].mean().sqrt())}

    # the worst episodes
    ep_ids, inverse = torch.unique_consecutive(test.episode, return_inverse=True)
    ep_se = torch.zeros(len(ep_ids)).index_add_(0, inverse[keep], se[keep].sum(1))
    order = ep_se.argsort(descending=True)
    report["without_worst_episodes"] = []
    for k in (1, 2, 4):
        rest_rows = keep & ~torch.isin(inverse, order[:k])
        report["without_worst_episodes"].append({
            "dropped": k, "rmse_cm": float(se[rest_rows].mean().sqrt()),
            "touched_rmse_cm": float(se[rest_rows][touch[rest_rows]].mean().sqrt()),
            "untouched_rmse_cm": float(se[rest_rows][~touch[rest_rows]].mean().sqrt())})
    end = test.frames.targets[((inverse == order[0]) & keep).nonzero().max()].view(2, 3)
    pair = train.frames.targets.view(-1, 2, 3)
    near = torch.minimum(torch.maximum((pair[:, 0] - end[0]).norm(dim=-1), (pair[:, 1] - end[1]).norm(dim=-1)),
                         torch.maximum((pair[:, 1] - end[0]).norm(dim=-1), (pair[:, 0] - end[1]).norm(dim=-1)))
    report["worst_episode_last_pair_cm"] = end.tolist()
    report["train_frames_near_it"] = {"within_cm": 1.5, "frames": int((near < 1.5).sum()),
                                      "episodes": len(torch.unique(train.episode[near < 1.5]))}
    other_se = None
    if args.compare:
        other, other_cfg, _ = load_model(Path(args.compare) / "checkpoint.pt")
        if (other_cfg.seed, other_cfg.train_fraction, other_cfg.max_samples) != (cfg.seed, cfg.train_fraction,
                                                                                 cfg.max_samples):
            raise ConfigError(f"--compare {args.compare}: another split than {args.run}")
        other_se = ball_errors_since_touch(predict(other, test), test, other_cfg.match_balls)[0]
        report["compare"] = args.compare
    total = float(ep_se.sum())
    layout = from_dict(SkinLayout, read_manifest(args.dataset)["metadata"]["skin"])
    names = [p.name for p in layout.patches]
    patch = torch.from_numpy(layout.patch_index())
    t = test.frames.targets
    worst = []
    for e in order[:args.worst].tolist():
        rows = ((inverse == e) & keep).nonzero().squeeze(1)
        b = int(se[rows].sum(0).argmax())  # the ball with most of the episode's error
        err = se[rows, b].mul(3).sqrt()  # distance (cm)
        bad = rows[err > 1.0]
        # matched targets of this ball: the target nearer its prediction, the other ball's target
        p, tt = pred[rows].view(-1, 2, 3), t[rows].view(-1, 2, 3)
        straight = ((p - tt) ** 2).sum((1, 2)) <= ((p - tt.flip(1)) ** 2).sum((1, 2))
        own = torch.where(straight[:, None], tt[:, b], tt[:, 1 - b])
        other_target = torch.where(straight[:, None], tt[:, 1 - b], tt[:, b])
        to_other = (p[:, b] - other_target).norm(dim=-1)
        active = test.frames.readings[rows] > 0
        near = ((test.frames.positions[rows] - own[:, None]).norm(dim=-1) < 3.0) & active
        patches = {n: float(near[:, patch == i].any(1).float().mean()) for i, n in enumerate(names)}
        worst.append({
            "episode": int(ep_ids[e]), "frames": len(rows), "last_step": int(test.step[rows].max()),
            "share_of_squared_error": float(ep_se[e]) / total,
            "ball_rmse_cm": float(se[rows, b].mean().sqrt()),
            "other_ball_rmse_cm": float(se[rows, 1 - b].mean().sqrt()),
            "frames_off_by_more_than_1cm": len(bad),
            "first_step_off_by_1cm": int(test.step[bad].min()) if len(bad) else None,
            "ball_touched_share": float(touch[rows, b].float().mean()),
            "ball_at_rest_share": float(rest[rows, b].float().mean()),
            "ball_mean_cm": own.mean(0).tolist(), "ball_travel_cm": float((own[-1] - own[0]).norm()),
            "ball_distance_error_median_cm": float(err.median()),
            "estimate_to_other_ball_median_cm": float(to_other.median()),
            "touching_patches_share": {n: round(v, 3) for n, v in patches.items() if v > 0.05},
            "active_taxels_mean": float(active.sum(1).float().mean()),
            **({} if other_se is None else {"compare_ball_rmse_cm": float(other_se[rows, b].mean().sqrt()),
                                            "compare_other_ball_rmse_cm": float(other_se[rows, 1 - b].mean().sqrt())}),
        })
    report["worst_episodes"] = worst
    report["provenance"] = provenance({"perception": ckpt}, cfg.seed, {"dataset": args.dataset})
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, json.dumps(report, indent=1))
    print(json.dumps({k: v for k, v in report.items() if k != "provenance"}, indent=1))


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    raise SystemExit(run_script(main))
