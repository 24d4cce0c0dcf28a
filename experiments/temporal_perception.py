"""Table II rows of the temporal perception models, touched / untouched, and the blind-area plot.

Reads trained sequence checkpoints (``tacgnn train-perception --temporal`` / ``--by-episode``),
evaluates each on its test episodes (split by episode; every model reads each episode from
its first frame; errors count frames from step 6 on, as the Table II datasets skip the first
5), and writes:

* ``results/temporal_perception/temporal_perception.json``: per run, overall / touched /
  untouched position RMSE (cm), the untouched share, the RMSE by steps since the ball last
  touched a taxel, and the RMSE with a whole skin patch reading 0 (``--lose-patch``, the palm
  by default);
* ``results/temporal_perception/fig_blind_area.png``: RMSE against steps since the ball last
  touched a taxel.

A ball is touched when an activated taxel lies within 3 cm of its centre (radius 2.625 cm).

The data and runs behind results/temporal_perception/fig_blind_area.png (ground-truth hold
policy, 16 envs, every frame kept, seed 1; 160,000 frames, 1,899 episodes, split 80/20 by
episode), each command niced on the shared 2-core machine; every model gets the same epochs
over the same training frames (an epoch puts every training frame into the loss once)::

    tacgnn make-dataset baoding --out data/baoding_seq2 --samples 160000 --shard-size 10000 --seed 1 \\
        --keep-every 1 --envs 16 --settle-steps 0 --policy runs/gt_hold_s0/model_000300.pt --set task=hold
    tacgnn train-perception --dataset data/baoding_seq2 --run runs/temporal2/tacgnn32_temporal \\
        --temporal --model tacgnn --channels 32 --epochs 20 --window 32 --burn-in 200 \\
        --set batch_size=16 lr_decay=0.85
    tacgnn train-perception --dataset data/baoding_seq2 --run runs/temporal2/tacgnn32_single \\
        --by-episode --model tacgnn --channels 32 --epochs 20 --set batch_size=256 lr_decay=0.85
    tacgnn train-perception --dataset data/baoding_seq2 --run runs/temporal2/mlp_temporal \\
        --temporal --model mlp --epochs 20 --window 32 --burn-in 200 --set batch_size=16 lr_decay=0.85
    tacgnn train-perception --dataset data/baoding_seq2 --run runs/temporal2/mlp_single \\
        --by-episode --model mlp --epochs 20 --set batch_size=256 lr_decay=0.85
    .venv/bin/python experiments/temporal_perception.py --dataset data/baoding_seq2 --train-error \\
        --runs runs/temporal2/tacgnn32_temporal runs/temporal2/tacgnn32_single \\
               runs/temporal2/mlp_temporal runs/temporal2/mlp_single runs/temporal/final/tacgnn32_temporal

The three comparison runs were trained 8 epochs, then resumed to 20 (``--resume --epochs 20``,
same arguments otherwise; a resumed run equals an uninterrupted one). The last run was trained
on data/baoding_seq (30,000 frames, seed 0, 30 epochs, burn-in 200) and is read on the same
test episodes (the split depends only on the episodes and the seed).

(results/temporal_perception/temporal_perception.json records each run's config, training time
and provenance.)
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from tacgnn.config import ConfigError, from_dict, to_dict
from tacgnn.datasets.store import read_manifest
from tacgnn.envs.observation import track_ball_identities
from tacgnn.files import atomic_write, atomic_write_text
from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.perception.checkpoint import load_checkpoint, load_model
from tacgnn.perception.evaluation import (
    ball_errors_since_touch,
    patch_taxels,
    predict,
    since_touch_curve,
    without_taxels,
)
from tacgnn.perception.evaluation import metrics as frame_metrics
from tacgnn.perception.sequences import SequenceData, load_sequences, split_by_episode
from tacgnn.provenance import provenance
from tacgnn.user_errors import run_script

BINS = [0, 1, 2, 3, 4, 6, 8, 12]
PAPER_TACGNN32_TEST_CM = 0.096


def label(cfg) -> str:
    name = {"tacgnn": f"TacGNN-{cfg.model.channels}", "mlp": "MLP", "cnn": "CNN"}[cfg.model.name]
    return f"{name} temporal" if cfg.temporal else f"{name} single-frame"


def touched_breakdown(pred: torch.Tensor, cfg, data: SequenceData, skin: dict, top: int = 8) -> dict:
    """Where the touched balls' error comes from: its spread, the RMSE by the skin patches that
    touch the ball (activated taxels within 3 cm of its centre; the most common sets first), and
    how much of the error the worst test episodes hold."""
    se, touch, _ = ball_errors_since_touch(pred, data, cfg.match_balls)
    layout = from_dict(SkinLayout, skin)
    names = [p.name for p in layout.patches]
    patch = torch.from_numpy(layout.patch_index())
    t = data.frames.targets
    swapped = t[:, [3, 4, 5, 0, 1, 2]]
    if cfg.match_balls:  # the ball order ball_errors_since_touch uses
        t = torch.where((((pred - swapped) ** 2).sum(1) < ((pred - t) ** 2).sum(1))[:, None], swapped, t)
    active = data.frames.readings > 0
    codes = []
    for b in range(2):  # bit p set: patch p has an activated taxel within 3 cm of ball b
        near = ((data.frames.positions - t[:, None, 3 * b:3 * b + 3]).norm(dim=-1) < 3.0) & active
        hit = torch.stack([near[:, patch == p].any(1) for p in range(len(names))], 1)
        codes.append((hit.long() << torch.arange(len(names))).sum(1))
    code = torch.stack(codes, 1)
    evaluated = data.step >= cfg.eval_from_step
    # how concentrated the error is in a few test episodes (all balls, touched or not)
    ep_se = torch.zeros(int(data.episode.max()) + 1).index_add_(0, data.episode[evaluated], se[evaluated].sum(1))
    worst = ep_se.argsort(descending=True)
    without = evaluated & (data.episode != worst[0])
    episodes = {"worst_two_share_of_squared_error": float(ep_se[worst[:2]].sum() / ep_se.sum()),
                "worst_episode_frames": int((evaluated & (data.episode == worst[0])).sum()),
                "rmse_without_worst_episode_cm": float(se[without].mean().sqrt()),
                "touched_rmse_without_worst_episode_cm": float(se[without][touch[without]].mean().sqrt())}
    keep = evaluated[:, None] & touch
    se, code = se[keep], code[keep]
    ordered = se.sort(descending=True).values
    tail = max(1, len(ordered) // 20)
    groups = []
    values, counts = code.unique(return_counts=True)
    for v in values[counts.argsort(descending=True)][:top].tolist():
        sel = code == v
        groups.append({"patches": [n for i, n in enumerate(names) if v >> i & 1], "share": float(sel.float().mean()),
                       "rmse_cm": float(se[sel].mean().sqrt()),
                       "share_of_squared_error": float(se[sel].sum() / se.sum())})
    return {"median_cm": float(ordered.median().sqrt()), "p95_cm": float(ordered[tail - 1].sqrt()),
            "top5pct_share_of_squared_error": float(ordered[:tail].sum() / ordered.sum()), "by_patches": groups,
            "episodes": episodes}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--runs", nargs="+", required=True, help="run folders holding checkpoint.pt")
    parser.add_argument("--train-error", action="store_true", help="also the error on the training episodes")
    parser.add_argument("--lose-patch", default="palm", help="also the error with this skin patch reading 0 ('' none)")
    parser.add_argument("--out", default="results/temporal_perception/temporal_perception.json")
    parser.add_argument("--figure", default="results/temporal_perception/fig_blind_area.png",
                        help="the plot ('' for none)")
    parser.add_argument("--ensemble", action="store_true",
                        help="also the mean of the runs' outputs (each ball matched to the first run's), one row")
    args = parser.parse_args()
    torch.set_num_threads(1)

    loaded: dict[int, SequenceData] = {}  # by max_samples: the dataset is read once
    results = {}
    outputs: list[tuple[torch.Tensor, object, SequenceData]] = []  # for --ensemble
    for run in args.runs:
        ckpt = Path(run) / "checkpoint.pt"
        model, cfg, _ = load_model(ckpt)
        payload = load_checkpoint(ckpt)
        history, trained_on = payload["history"], payload.get("dataset", {}).get("path", args.dataset)
        if cfg.max_samples not in loaded:
            loaded[cfg.max_samples] = load_sequences(args.dataset, cfg.max_samples)
        train_set, test_set = split_by_episode(loaded[cfg.max_samples], cfg.train_fraction, cfg.seed)
        pred = predict(model, test_set)
        outputs.append((pred, cfg, test_set))
        metrics = frame_metrics(pred, cfg, test_set)
        name = label(cfg)
        own = Path(trained_on).resolve() == Path(args.dataset).resolve()
        if not own:  # a model trained on another dataset, read on these test episodes
            name = f"{name}, trained on {trained_on}"
        if name in results:
            name = f"{name} ({Path(run).name})"
        results[name] = {
            "run": str(run), "trained_on": trained_on, "epochs": cfg.epochs,
            "train_seconds": sum(h["seconds"] for h in history),
            "train_frames": len(train_set) if own else None,
            "train_episodes": len(train_set.episodes()) if own else None,
            "extra_train": list(cfg.extra_train),  # datasets whose episodes were all trained on
            "extra_train_frames": payload.get("dataset", {}).get("extra_train_frames", 0),
            "test_frames": len(test_set), "test_episodes": len(test_set.episodes()), **metrics,
            "by_steps_since_touch": since_touch_curve(pred, cfg, test_set, BINS),
            "history_test_rmse_cm": [h["test/position_rmse_cm"] for h in history],
        }
        results[name]["touched_breakdown"] = touched_breakdown(pred, cfg, test_set,
                                                               read_manifest(args.dataset)["metadata"]["skin"])
        if args.lose_patch:
            taxels = patch_taxels(read_manifest(args.dataset)["metadata"]["skin"], args.lose_patch)
            lost = without_taxels(test_set, taxels)
            lost_rmse = frame_metrics(predict(model, lost), cfg, lost)["position_rmse_cm"]
            results[name][f"{args.lose_patch}_lost_rmse_cm"] = lost_rmse
            results[name][f"{args.lose_patch}_lost_rmse_ratio"] = lost_rmse / metrics["position_rmse_cm"]
        if args.train_error and own:
            results[name]["train_position_rmse_cm"] = frame_metrics(
                predict(model, train_set), cfg, train_set)["position_rmse_cm"]
        results[name]["config"] = to_dict(cfg)
        results[name]["provenance"] = provenance({"perception": ckpt}, cfg.seed, {"dataset": args.dataset})
        print(f"{name:>24}: overall {metrics['position_rmse_cm']:.3f} cm, touched "
              f"{metrics['touched_rmse_cm']:.3f}, untouched {metrics['untouched_rmse_cm']:.3f} "
              f"({metrics['untouched_fraction']:.1%} of balls untouched)"
              + (f", {args.lose_patch} lost x{results[name][args.lose_patch + '_lost_rmse_ratio']:.2f}"
                 if args.lose_patch else ""), flush=True)
    if args.ensemble:
        results["ensemble"] = ensemble(outputs, args.runs)
        e = results["ensemble"]
        print(f"{'ensemble':>24}: overall {e['position_rmse_cm']:.3f} cm, touched {e['touched_rmse_cm']:.3f}, "
              f"untouched {e['untouched_rmse_cm']:.3f}", flush=True)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, json.dumps({"dataset": args.dataset, "touched_within_cm": 3.0,
                                          "paper_tacgnn32_test_cm": PAPER_TACGNN32_TEST_CM, "runs": results},
                                         indent=1))
    print(f"wrote {args.out}")
    if args.figure:
        plot(results, args.figure)
        print(f"wrote {args.figure}")


def ensemble(outputs: list, runs: list[str]) -> dict:
    """Errors of the mean output of several runs on their shared test episodes. The balls look
    alike, so each run's pair is first put in the order nearer the first run's (as the env tracks
    identities from one step to the next)."""
    first, cfg, data = outputs[0]
    for *_, other in outputs[1:]:
        if not torch.equal(other.episode, data.episode) or not torch.equal(other.step, data.step):
            raise ConfigError("--ensemble: the runs were tested on different episodes (another split or max_samples)")
    aligned = [torch.from_numpy(track_ball_identities(pred.numpy(), first.numpy())) for pred, _, _ in outputs]
    mean = torch.stack(aligned).mean(0)
    return {"runs": list(runs), **frame_metrics(mean, cfg, data),
            "by_steps_since_touch": since_touch_curve(mean, cfg, data, BINS)}


def plot(results: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8.4, 4.0))
    for name, r in results.items():
        curve = r["by_steps_since_touch"]
        ticks = [str(b) if hi is None or hi - b == 1 else f"{b}-{hi - 1}"
                 for b, hi in zip(curve["bins"], curve["bins"][1:] + [None])]
        ticks[-1] = f"{curve['bins'][-1]}+"
        style = "-" if "temporal" in name else "--"
        ax.plot(range(len(ticks)), curve["rmse_cm"], style, marker="o", ms=3, label=name)
    counts = next(iter(results.values()))["by_steps_since_touch"]["count"]
    ax.set_xticks(range(len(ticks)))
    ax.set_xticklabels([f"{t}\n({c})" for t, c in zip(ticks, counts)], fontsize=7)
    ax.axhline(PAPER_TACGNN32_TEST_CM, color="grey", lw=0.8, ls=":", label="paper TacGNN-32 (0.096 cm)")
    ax.set_xlabel("steps since the ball last touched a taxel (balls in bin)")
    ax.set_ylabel("ball position RMSE (cm)")
    ax.set_title("Blind area: error against time without contact (test episodes)", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.grid(alpha=0.3)
    fig.tight_layout()
    atomic_write(path, lambda fh: fig.savefig(fh, dpi=130, format=Path(path).suffix[1:] or "png"))


if __name__ == "__main__":
    raise SystemExit(run_script(main))
