"""How well could the skin place a ball it touches? A geometric estimate beside a trained model.

    .venv/bin/python experiments/perception_accuracy/palm_geometry.py RUN_DIR [RUN_DIR ...] [--dataset DATASET]

For balls that touch the palm and no other patch, the palm is a plane: the ball's centre
is the pressed taxels' reading-weighted centroid, lifted one ball radius (plus the skin's
offset, fitted on the training split) along the palm's normal. The taxels of a ball are
those within 3 cm of its true centre (an oracle grouping, as in `ball_visibility_errors`;
with two balls far apart, grouping is the easy part). The script prints the RMSE per
coordinate (cm, as the tables) of that estimate and of the model in RUN_DIR on the same
test balls, and the model's error on the other groups of balls. If the geometry alone is
well under the model's error, the skin holds more than the model reads from it. With several
runs, one block each (e.g. every Baoding perception: runs/perc/gthard_s?_*_pi).
"""
import argparse
import functools

import numpy as np
import torch

torch.set_num_threads(1)
from tacgnn.config import from_dict  # noqa: E402
from tacgnn.datasets.store import read_manifest  # noqa: E402
from tacgnn.envs.baoding import BaodingConfig  # noqa: E402
from tacgnn.hand.skin_layout import SkinLayout  # noqa: E402
from tacgnn.perception.train import load_model, load_tactile, predict, split  # noqa: E402

SEEN_CM = 3.0


def per_coordinate_rmse(err: np.ndarray) -> float:
    """err (n, 3) in cm -> sqrt(mean squared coordinate error)."""
    return float(np.sqrt((err**2).mean())) if len(err) else float("nan")


@functools.lru_cache(maxsize=1)  # several runs trained on one dataset read it once
def dataset_frames(dataset: str, task: str, max_samples: int, joints: bool):
    return load_tactile(dataset, task, max_samples, joints=joints)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="run folders of tacgnn train-perception (Baoding)")
    parser.add_argument("--dataset", help="default: the dataset each model was trained on")
    args = parser.parse_args()
    for run in args.runs:
        report(run, args.dataset)


def report(run: str, dataset: str | None = None) -> None:
    model, cfg, meta = load_model(f"{run}/checkpoint.pt")
    dataset = dataset or meta["path"]
    data = dataset_frames(dataset, cfg.task, cfg.max_samples, cfg.model.joint_inputs > 0)
    train_set, test = split(data, cfg.train_fraction, cfg.seed)
    skin = from_dict(SkinLayout, read_manifest(dataset)["metadata"]["skin"])
    palm = skin.patch_index() == 0
    radius_cm = 100 * BaodingConfig().ball_radius

    def palm_only_balls(d):
        """Per ball: its taxels (mask), and whether they are all on the palm (and some are)."""
        active = (d.readings > 0).numpy()
        pos, t = d.positions.numpy(), d.targets.numpy().reshape(-1, 2, 3)
        near = np.linalg.norm(pos[:, None] - t[:, :, None], axis=-1) < SEEN_CM  # (N, ball, taxel)
        mine = near & active[:, None]
        touched = mine.any(-1)
        only_palm = touched & ~(mine & ~palm).any(-1)
        return mine, touched, only_palm, pos, t

    def geometric(d, offset_cm: float):
        mine, touched, only_palm, pos, t = palm_only_balls(d)
        w = d.readings.numpy()[:, None] * mine  # (N, ball, taxel)
        centroid = (w[..., None] * pos[:, None]).sum(2) / np.maximum(w.sum(-1, keepdims=True), 1e-12)
        # the palm's outward normal from its taxels' plane (SVD per frame), pointing to the balls
        p = pos[:, palm]
        q = p - p.mean(1, keepdims=True)
        normal = np.linalg.svd(q, full_matrices=False)[2][:, -1]  # (N, 3)
        normal *= np.sign(((t.mean(1) - p.mean(1)) * normal).sum(-1, keepdims=True))
        estimate = centroid + (radius_cm + offset_cm) * normal[:, None]
        return estimate, t, only_palm, touched, normal, centroid

    # the skin's offset along the normal, fitted on the training split's palm-only balls
    _, t_tr, only_tr, _, n_tr, c_tr = geometric(train_set, 0.0)
    lift = ((t_tr - c_tr) * n_tr[:, None]).sum(-1)[only_tr]
    offset = float(lift.mean() - radius_cm)
    estimate, t, only_palm, touched, normal, _ = geometric(test, offset)

    pred = predict(model, test).numpy().reshape(-1, 2, 3)
    if cfg.match_balls:  # the better assignment of each frame, as the tables
        swapped = pred[:, ::-1]
        use = ((swapped - t) ** 2).sum((1, 2)) < ((pred - t) ** 2).sum((1, 2))
        pred = np.where(use[:, None, None], swapped, pred)
    model_err = pred - t
    geo_err = estimate - t
    n = only_palm.size
    print(f"{run} on {dataset}: {len(t)} test frames, skin offset along the palm normal {offset:+.3f} cm")
    print(f"{'balls':34s} {'share':>6s} {'model':>7s} {'geometry':>9s}  (RMSE per coordinate, cm)")
    rows = [("all", np.ones_like(touched)), ("touched", touched), ("touched, palm only", only_palm),
            ("touched, on fingers too", touched & ~only_palm), ("untouched", ~touched)]
    for label, m in rows:
        geo = f"{per_coordinate_rmse(geo_err[m]):9.3f}" if label == "touched, palm only" else f"{'':9s}"
        print(f"{label:34s} {m.sum() / n:6.1%} {per_coordinate_rmse(model_err[m]):7.3f} {geo}")
    along = (geo_err * normal[:, None]).sum(-1, keepdims=True)
    lateral = (geo_err - along * normal[:, None])[only_palm]  # in the palm's plane
    print(f"geometry, palm-only balls: across the palm {float(np.sqrt((lateral**2).sum(-1).mean() / 2)):.3f} cm "
          f"per coordinate, along its normal {float(np.sqrt((along[only_palm]**2).mean())):.3f} cm")

if __name__ == "__main__":
    main()
