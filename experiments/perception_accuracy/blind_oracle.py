"""How well can a ball that touches no taxel be located at all? An upper-bound probe.

    .venv/bin/python experiments/perception_accuracy/blind_oracle.py [--epochs 30]

Trains a plain MLP (1 thread, Adam + cosine) on information TacGNN does not have:
joint angles (the whole hand pose, 16) + all 653 readings, to predict both balls (identity
labels), on the same 80/20 split as train.py. Prints the test RMSE of seen balls (an activated
taxel within 3 cm of the centre) and blind ones. Blind-ball error this probe cannot remove is
a floor for any tactile model; TacGNN sees only the activated taxels (no hand pose).
"""
import argparse
import math

import numpy as np
import torch

torch.set_num_threads(1)
from tacgnn.datasets.store import load  # noqa: E402
from tacgnn.perception.train import load_tactile, split  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--dataset", default="data/baoding_gt50k")
ap.add_argument("--epochs", type=int, default=30)
ap.add_argument("--no-joints", action="store_true")
args = ap.parse_args()
data = load_tactile(args.dataset, "baoding")
joints = torch.from_numpy(load(args.dataset, ["joint_pos"])["joint_pos"]).float()
X = data.readings if args.no_joints else torch.cat([data.readings, joints * 3], 1)
order = torch.randperm(len(X), generator=torch.Generator().manual_seed(0))
cut = int(round(0.8 * len(X)))
tr, te = order[:cut], order[cut:]
mu, sd = X[tr].mean(0), X[tr].std(0) + 1e-3
X = (X - mu) / sd
Y = data.targets
ym = Y[tr].mean(0)
torch.manual_seed(0)
net = torch.nn.Sequential(torch.nn.Linear(X.shape[1], 256), torch.nn.ReLU(), torch.nn.Linear(256, 256),
                          torch.nn.ReLU(), torch.nn.Linear(256, 6))
opt = torch.optim.Adam(net.parameters(), lr=1e-3)
steps = args.epochs * math.ceil(len(tr) / 128)
s = 0
for ep in range(args.epochs):
    perm = tr[torch.randperm(len(tr))]
    for i in range(0, len(perm), 128):
        idx = perm[i:i + 128]
        for g in opt.param_groups:
            g["lr"] = 1e-3 * 0.5 * (1 + math.cos(math.pi * s / steps))
        loss = ((net(X[idx]) + ym - Y[idx]) ** 2).mean()
        opt.zero_grad(); loss.backward(); opt.step(); s += 1
with torch.no_grad():
    pred = net(X[te]) + ym
t = Y[te]
sq = (pred - t) ** 2
act = data.readings[te] > 0
pos = data.positions[te]
out = {"test_rmse": sq.mean().sqrt().item()}
for b in range(2):
    d = (pos - t[:, None, 3 * b:3 * b + 3]).norm(dim=-1).masked_fill(~act, float("inf")).min(1).values
    e = sq[:, 3 * b:3 * b + 3].mean(1)
    out[f"ball{b}_seen"] = e[d < 3].mean().sqrt().item()
    out[f"ball{b}_blind"] = e[d >= 3].mean().sqrt().item()
print(args, {k: round(v, 4) for k, v in out.items()})
