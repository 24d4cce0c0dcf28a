"""Where does a trained model's test error come from? Split by how well each ball is seen.

    .venv/bin/python experiments/perception_accuracy/error_breakdown.py RUN_DIR [DATASET]

For each ball: d = distance (cm) from the ball centre to the nearest activated taxel
(inf: nothing active). Balls with d > 4 cm are not touched by any taxel ("blind").
Prints the share of the test MSE from blind / seen balls and the RMSE of each group.
Identity labels only (match_balls=false) are split exactly; for the permutation-invariant
loss the better matching is used for the whole frame.
"""
import sys

import torch

torch.set_num_threads(1)
from tacgnn.perception.train import load_model, load_tactile, predict, split  # noqa: E402

run = sys.argv[1]
model, cfg, meta = load_model(f"{run}/checkpoint.pt")
ds = sys.argv[2] if len(sys.argv) > 2 else meta["path"]
data = load_tactile(ds, cfg.task, cfg.max_samples)
test = split(data, cfg.train_fraction, cfg.seed)[1]
pred = predict(model, test)
t = test.targets
if cfg.match_balls:
    sw = t[:, [3, 4, 5, 0, 1, 2]]
    use_sw = ((pred - sw) ** 2).sum(1) < ((pred - t) ** 2).sum(1)
    t = torch.where(use_sw[:, None], sw, t)
act = test.readings > 0
sq = (pred - t) ** 2  # (N, 6)
N = len(t)
tot = sq.sum().item()
print(f"{run}: test RMSE {(tot / (6 * N)) ** 0.5:.4f} cm, N={N}")
for b in range(2):
    d = (test.positions - t[:, None, 3 * b:3 * b + 3]).norm(dim=-1).masked_fill(~act, float("inf")).min(1).values
    e = sq[:, 3 * b:3 * b + 3].sum(1)
    for lo, hi in [(0, 3.0), (3.0, 4.0), (4.0, float("inf"))]:
        m = (d >= lo) & (d < hi)
        if m.any():
            print(f" ball {b} nearest taxel in [{lo},{hi}) cm: {m.float().mean():5.1%} of frames, "
                  f"RMSE {(e[m].mean() / 3) ** 0.5:.3f} cm, share of total SE {e[m].sum() / tot:5.1%}")
