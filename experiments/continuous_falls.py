"""What ends continuous-task episodes early: each fall by rule and place, and the perception error before it.

    .venv/bin/python experiments/continuous_falls.py OUT.json LABEL=CHECKPOINT [...]
        [--episodes 128] [--seed 0] [--set KEY=VALUE ...] [--window 10] [--truth-too]

Each policy runs `--episodes` deterministic 10 s episodes side by side (as in
`continuous_angle.py`). For every fall it records which ball broke which rule of the env
(below the palm plane, lifted above the height band, beyond the palm radius), where in the
palm that ball was (thumb or little-finger side, finger or wrist end), when, and how far the
pair had turned. For a blind policy (obs_mode 'perceived') it also compares the perception
error in the `--window` steps before each fall (the ball that fell and the other) with the
error in episodes that kept both balls, and the mean error k steps before the falls.
`--truth-too` also runs each blind policy on the true ball positions (obs_mode groundtruth,
the same weights): the falls that remain are not the perception's doing.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from continuous_angle import run_episodes

from tacgnn.config import parse_overrides
from tacgnn.files import atomic_write_text
from tacgnn.provenance import provenance
from tacgnn.user_errors import labelled_paths, run_script

RULES = ("below the palm plane", "above the height band", "beyond the palm radius")
BEFORE_STEPS = (1, 5, 10, 15, 20, 25, 30, 40, 50, 75, 100)


def classify(end_palm: np.ndarray, fall_height: tuple[float, float], fall_radius: float) -> np.ndarray:
    """(N, 2, 3) bool: per ball, broke the rule below the plane / above the band / beyond the radius."""
    normal, across = end_palm[..., 0], np.hypot(end_palm[..., 1], end_palm[..., 2])
    return np.stack([normal < fall_height[0], normal > fall_height[1], across > fall_radius], axis=-1)


def summarise(r: dict, window: int) -> dict:
    """The falls of one run of `run_episodes`, by rule, ball, place and time; perception error before them."""
    cfg = r["config"]
    n, dt = len(r["fell"]), cfg.control_dt
    fell = np.flatnonzero(r["fell"])
    rules = np.asarray(classify(r["end_palm"], cfg.fall_height, cfg.fall_radius))[fell]  # (F, 2, 3)
    broke = np.asarray(rules.any(-1))  # (F, 2) which ball left
    turns = np.array([a[~np.isnan(a)][-1] / 360 for a in r["angles"].T])
    out: dict = {
        "episodes": n, "falls": len(fell), "fall_rate": len(fell) / n,
        "turns_mean": float(turns.mean()),
        "turns_kept_both": float(turns[~r["fell"]].mean()) if len(fell) < n else None,
        "by_rule": {name: int(rules[..., k].any(1).sum()) for k, name in enumerate(RULES)},
        "balls_out": {"one": int((broke.sum(1) == 1).sum()), "both": int((broke.sum(1) == 2).sum())},
        "by_ball_index": {"ball 0": int(broke[:, 0].sum()), "ball 1": int(broke[:, 1].sum())},
        "fall_time_s": [float(dt * (s + 1)) for s in r["ended"][fell]],
        "turns_at_fall": [float(x) for x in turns[fell]],
    }
    if len(fell):
        places = {"thumb side": 0, "little-finger side": 0, "finger end": 0, "wrist end": 0}
        heights = []
        for f, e in enumerate(fell):
            for b in np.flatnonzero(broke[f]):
                normal, across, along = r["end_palm"][e, b]
                heights.append(float(normal))
                if abs(across) >= abs(along):  # the palm's +y is the thumb's side, +z the fingers'
                    places["thumb side" if across > 0 else "little-finger side"] += 1
                else:
                    places["finger end" if along > 0 else "wrist end"] += 1
        out["place_of_ball_out"] = places
        out["height_of_ball_out_cm"] = [round(100 * h, 2) for h in heights]
        out["fall_time_quartiles_s"] = [float(q) for q in np.percentile(out["fall_time_s"], (25, 50, 75))]
    if r["ball_errors"] is not None:
        out["perception"] = perception_before_falls(r, fell, broke, window)
    return out


def perception_before_falls(r: dict, fell: np.ndarray, broke: np.ndarray, window: int) -> dict:
    """Perception error (cm) in the `window` steps before each fall against episodes that kept both balls."""
    errs, ended = r["ball_errors"], r["ended"]  # (T, N, 2)
    kept = np.flatnonzero(~r["fell"])
    lost, other = [], []
    for f, e in enumerate(fell):
        lo = max(0, ended[e] - window)
        seg = errs[lo:ended[e], e]  # the steps before the fall (the fall step has no prediction)
        ball = int(np.flatnonzero(broke[f])[0])
        lost.append(float(np.nanmean(seg[:, ball])))
        other.append(float(np.nanmean(seg[:, 1 - ball])))
    kept_err = errs[:, kept].mean(-1)  # (T, K) both balls' mean
    # the same-length windows in the kept episodes, everywhere along them
    starts = range(0, kept_err.shape[0] - window, window)
    kept_windows = np.array([np.nanmean(kept_err[s:s + window], 0) for s in starts])
    before = {}
    for k in BEFORE_STEPS:
        vals = [np.nanmean(errs[ended[e] - k, e]) for e in fell if ended[e] - k >= 0]
        before[f"{k} steps"] = float(np.mean(vals)) if vals else None
    lost_arr = np.array(lost)
    return {
        "window_steps": window,
        "fallen_ball_before_fall_cm_mean": float(lost_arr.mean()) if len(lost) else None,
        "fallen_ball_before_fall_cm_median": float(np.median(lost_arr)) if len(lost) else None,
        "other_ball_before_fall_cm_mean": float(np.mean(other)) if other else None,
        "falls_with_fallen_ball_error_over_1cm": int((lost_arr > 1.0).sum()),
        "kept_episodes_cm_mean": float(np.nanmean(kept_err)) if len(kept) else None,
        "kept_episodes_windows_over_1cm_fraction": float((kept_windows > 1.0).mean()) if len(kept) else None,
        "kept_episodes_window_p95_cm": float(np.nanpercentile(kept_windows, 95)) if len(kept) else None,
        "both_balls_cm_steps_before_fall": before,
        "fallen_ball_before_fall_cm": [round(x, 3) for x in lost],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    parser.add_argument("policies", nargs="+", metavar="LABEL=CHECKPOINT")
    parser.add_argument("--episodes", type=int, default=128)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE")
    parser.add_argument("--window", type=int, default=10, help="steps before a fall whose perception error counts")
    parser.add_argument("--truth-too", action="store_true", help="also run blind policies on the true positions")
    args = parser.parse_args(argv)
    changes = parse_overrides(args.set)
    items = labelled_paths(args.policies)
    results = {}
    for label, ckpt in items:
        r = run_episodes(ckpt, args.episodes, args.seed, changes, None)
        results[label] = summarise(r, args.window)
        if args.truth_too and r["config"].obs_mode == "perceived":
            on_truth = {**changes, "obs_mode": "groundtruth", "tactile": False}
            truth = run_episodes(ckpt, args.episodes, args.seed, on_truth, None)
            results[f"{label}, true positions"] = summarise(truth, args.window)
    for label, s in results.items():
        line = f"{label}: {s['falls']}/{s['episodes']} falls, turns {s['turns_mean']:.2f}; by rule {s['by_rule']}"
        if "place_of_ball_out" in s:
            line += f"; place {s['place_of_ball_out']}; time quartiles {s['fall_time_quartiles_s']}"
        print(line)
        if "perception" in s:
            p = s["perception"]
            print(f"  perception: fallen ball {p['fallen_ball_before_fall_cm_mean']} cm before the fall, other "
                  f"{p['other_ball_before_fall_cm_mean']}, kept episodes {p['kept_episodes_cm_mean']}; "
                  f"before: {p['both_balls_cm_steps_before_fall']}")
    record = {"policies": results,
              "provenance": provenance(dict(items), args.seed,
                                       {"episodes": args.episodes, "set": args.set, "window": args.window,
                                        "truth_too": args.truth_too})}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, json.dumps(record, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
