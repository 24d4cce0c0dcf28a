"""Where a meat-can orientation model errs: by tilt and by yaw on the palm.

    .venv/bin/python experiments/perception_accuracy/meat_can_yaw.py \
        runs/perception/ours/meat_can/all/tacgnn-32/seed0/checkpoint.pt data/meat_can_20000

Prints the test split's orientation RMSE by the can's tilt from its resting face and the
yaw error of its long (97 mm) axis about the palm normal, per 30-degree bin of the true yaw.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from tacgnn.perception.objectives import Objective, _rotation_from_6d
from tacgnn.perception.train import load_model, load_tactile, predict, split


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("checkpoint")
    ap.add_argument("dataset")
    args = ap.parse_args()
    torch.set_num_threads(1)
    model, cfg, _ = load_model(args.checkpoint)
    _, test = split(load_tactile(args.dataset, "meat_can"), cfg.train_fraction, cfg.seed)
    pred, target = predict(model, test), test.targets
    objective = Objective("meat_can")
    print(objective.metrics(pred, target))

    rot = torch.stack([target[:, 3:6], target[:, 6:9], torch.cross(target[:, 3:6], target[:, 6:9], dim=1)], 2)
    up = rot[:, :, 0].mean(0)  # the short (50 mm) axis points up at the drop
    up /= up.norm()
    tilt = torch.rad2deg(torch.arccos((rot[:, :, 0] @ up).abs().clamp(max=1)))
    r_pred = _rotation_from_6d(pred[:, 3:])
    cands = objective._orientation_candidates(target)
    r_true = torch.stack([cands[..., :3], cands[..., 3:], torch.cross(cands[..., :3], cands[..., 3:], dim=-1)], -1)
    trace = (r_pred[:, None].transpose(-1, -2) @ r_true).diagonal(dim1=-2, dim2=-1).sum(-1)
    angle = torch.rad2deg(torch.arccos(((trace - 1) / 2).max(1).values.clamp(-1, 1)))
    for lo, hi in [(0, 10), (10, 30), (30, 91)]:
        m = (tilt >= lo) & (tilt < hi)
        if m.any():
            print(f"tilt {lo}-{hi} deg: {int(m.sum())} grasps, orientation RMSE {float(angle[m].pow(2).mean().sqrt()):.1f} "
                  f"deg, median {float(angle[m].median()):.1f}")

    e1 = torch.tensor([1.0, 0.0, 0.0]) - up[0] * up
    e1 /= e1.norm()
    e2 = torch.cross(up, e1, dim=0)

    def yaw(y_axis: torch.Tensor) -> torch.Tensor:
        return torch.rad2deg(torch.atan2(y_axis @ e2, y_axis @ e1)) % 180

    true_yaw = yaw(rot[:, :, 1])
    err = (yaw(r_pred[:, :, 1]) - true_yaw + 90) % 180 - 90
    for lo in range(0, 180, 30):
        m = (true_yaw >= lo) & (true_yaw < lo + 30)
        print(f"true yaw {lo:3d}-{lo + 30:3d} deg: {int(m.sum())} grasps, yaw error RMSE "
              f"{float(err[m].pow(2).mean().sqrt()):.1f} deg, beyond 60 deg: {float((err[m].abs() > 60).float().mean()):.2f}")
    print("yaw error histogram, bins -90/-60/-30/-10/10/30/60/90:",
          np.histogram(err.numpy(), bins=[-90, -60, -30, -10, 10, 30, 60, 90])[0].tolist())


if __name__ == "__main__":
    main()
