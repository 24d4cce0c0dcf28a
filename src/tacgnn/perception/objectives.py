"""What a perception model predicts for each task, its loss, and the reported errors.

* baoding: both ball centres (6 values, cm). The balls look alike, so by default the loss
  is the smaller of the two matchings (ball a -> label 0 or label 1): permutation-invariant.
  With ``match_balls=False`` the balls keep their identity (ball 0 starts on the index
  side; in a 180-degree turn each ball keeps to its own half of the circle), which is
  what a policy trained on true positions expects.
* cube, meat_can: centre (cm) + orientation as the first two columns of the rotation
  matrix (the continuous 6D representation; no jump anywhere). Symmetric objects have
  several rotations that look the same (cube: 4 turns about its vertical axis in the
  sampled range, box-shaped can: the 4 half-turns), so loss and error take the
  closest equivalent label.
* cylinder: centre (cm) + axis direction (3); the axis sign and the rotation about the
  axis are ignored, as in the paper.

Errors are RMSEs: position over all coordinates (cm, as the paper's "RMSE" over the
output vector), orientation over samples of the geodesic angle (degrees).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import torch
from torch import Tensor

TaskName = Literal["baoding", "cube", "cylinder", "meat_can"]
OUT_DIM = {"baoding": 6, "cube": 9, "meat_can": 9, "cylinder": 6}
CM = 100.0


def _rot_z(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


SYMMETRIES = {
    "cube": np.stack([_rot_z(a) for a in (0, 90, 180, 270)]),
    "meat_can": np.stack([np.eye(3), np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])]),
}


def targets(data: dict[str, np.ndarray], task: TaskName) -> np.ndarray:
    """(N, OUT_DIM[task]) float32 labels from a dataset's arrays."""
    if task == "baoding":
        return (data["ball_pos"].reshape(-1, 6) * CM).astype(np.float32)
    pos = data["object_pos"] * CM
    rot = data["object_rot"]
    if task == "cylinder":
        return np.concatenate([pos, rot[:, :, 2]], 1).astype(np.float32)
    return np.concatenate([pos, rot[:, :, 0], rot[:, :, 1]], 1).astype(np.float32)


def _rotation_from_6d(x: Tensor) -> Tensor:
    """Gram-Schmidt: two 3-vectors -> rotation matrix with them as its first columns (B, 3, 3)."""
    a = torch.nn.functional.normalize(x[:, :3], dim=1)
    b = x[:, 3:6] - (a * x[:, 3:6]).sum(1, keepdim=True) * a
    b = torch.nn.functional.normalize(b, dim=1)
    return torch.stack([a, b, torch.cross(a, b, dim=1)], dim=2)


class Objective:
    """Loss and metrics of one task; `loss(pred, target)` is what training minimises."""

    def __init__(self, task: TaskName, match_balls: bool = True):
        if task not in OUT_DIM:
            raise ValueError(f"unknown task {task!r}; one of {list(OUT_DIM)}")
        self.task = task
        self.match_balls = match_balls  # baoding: loss over the better ball matching (else by identity)
        self.out_dim = OUT_DIM[task]
        sym = SYMMETRIES.get(task)
        self._sym = None if sym is None else torch.tensor(sym, dtype=torch.float32)

    def _orientation_candidates(self, target: Tensor) -> Tensor:
        """(B, S, 6): the 6D labels of all symmetric equivalents of each target rotation."""
        rot = torch.stack([target[:, 3:6], target[:, 6:9], torch.cross(target[:, 3:6], target[:, 6:9], dim=1)], 2)
        assert self._sym is not None, f"no rotation symmetries listed for {self.task!r}"
        eq = rot[:, None] @ self._sym.to(rot)  # (B, S, 3, 3)
        return torch.cat([eq[..., 0], eq[..., 1]], dim=-1)

    def _per_sample_sq(self, pred: Tensor, target: Tensor) -> tuple[Tensor, Tensor]:
        """Per-sample summed squared errors (position part, orientation part)."""
        if self.task == "baoding":
            straight = ((pred - target) ** 2).sum(1)
            if not self.match_balls:
                return straight, torch.zeros_like(straight)
            swapped = ((pred - target[:, [3, 4, 5, 0, 1, 2]]) ** 2).sum(1)
            return torch.minimum(straight, swapped), torch.zeros_like(straight)
        pos = ((pred[:, :3] - target[:, :3]) ** 2).sum(1)
        if self.task == "cylinder":
            ori = torch.minimum(((pred[:, 3:] - target[:, 3:]) ** 2).sum(1),
                                ((pred[:, 3:] + target[:, 3:]) ** 2).sum(1))
        else:
            cands = self._orientation_candidates(target)
            ori = ((pred[:, None, 3:] - cands) ** 2).sum(-1).min(1).values
        return pos, ori

    def loss(self, pred: Tensor, target: Tensor) -> Tensor:
        pos, ori = self._per_sample_sq(pred, target)
        return (pos + ori).mean() / self.out_dim

    @torch.no_grad()
    def metrics(self, pred: Tensor, target: Tensor) -> dict[str, float]:
        """{'position_rmse_cm', and for objects 'orientation_rmse_deg'}."""
        pos, _ = self._per_sample_sq(pred, target)
        npos = 6 if self.task == "baoding" else 3
        out = {"position_rmse_cm": float(torch.sqrt(pos.sum() / (npos * len(pos))))}
        if self.task == "baoding":
            return out
        if self.task == "cylinder":
            cos = (torch.nn.functional.normalize(pred[:, 3:], dim=1) * target[:, 3:]).sum(1).abs()
        else:
            r_pred = _rotation_from_6d(pred[:, 3:])
            cands = self._orientation_candidates(target)
            r_true = torch.stack([cands[..., :3], cands[..., 3:],
                                  torch.cross(cands[..., :3], cands[..., 3:], dim=-1)], -1)  # (B, S, 3, 3)
            trace = (r_pred[:, None].transpose(-1, -2) @ r_true).diagonal(dim1=-2, dim2=-1).sum(-1)
            cos = ((trace - 1) / 2).max(1).values
        angle = torch.rad2deg(torch.arccos(cos.clamp(-1.0, 1.0)))
        out["orientation_rmse_deg"] = float(torch.sqrt((angle**2).mean()))
        return out
