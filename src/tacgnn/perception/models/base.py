"""What every perception model shares: the call signature, input checks and dtype, small helpers.

All models map one tactile frame to an object state::

    model(readings, positions[, joints]) -> state
    readings  (B, T)     normal force per taxel (N), 0 where nothing presses
    positions (B, T, 3)  world position of every taxel (the callers pass cm)
    joints    (B, J)     hand joint angles (rad), only for models built with joint_inputs = J
    state     (B, out_dim)
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

#: ``log1p`` reading feature: ``log(1 + f / READING_LOG_SCALE)``; readings well above it are
#: compressed like a log.
READING_LOG_SCALE = 0.01  # N


class PerceptionModel(nn.Module):
    """Base class: checks the inputs and brings them to the model's dtype."""

    num_taxels: int
    out_dim: int
    joint_inputs: int = 0
    """Hand joint angles (rad) the model reads beside the skin; 0 = the skin alone."""

    @property
    def dtype(self) -> torch.dtype:
        """The dtype of the model's weights, which its inputs are cast to."""
        p = next(self.parameters(), None)
        return torch.get_default_dtype() if p is None else p.dtype

    def prepare(self, readings: Tensor, positions: Tensor,
                joints: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor | None]:
        """Check shapes and values; return the inputs in the model's dtype.

        Any strided or float dtype is accepted (a float64 batch, a slice of a larger
        tensor), so callers need not know how the model stores its weights.
        """
        T = self.num_taxels
        if readings.dim() != 2 or readings.shape[1] != T:
            raise ValueError(f"readings must be (B, {T}), got {tuple(readings.shape)}")
        if positions.shape != (readings.shape[0], T, 3):
            raise ValueError(f"positions must be (B, {T}, 3), got {tuple(positions.shape)}")
        dtype = self.dtype
        readings, positions = readings.to(dtype), positions.to(dtype)
        # one reduction instead of a full mask: NaN anywhere makes the sum NaN
        if torch.isnan(readings.sum()) and torch.isnan(readings).any():
            raise ValueError("readings contain NaN")
        if self.joint_inputs:
            if joints is None:
                raise ValueError(f"this model reads {self.joint_inputs} joint angles: pass joints (B, "
                                 f"{self.joint_inputs})")
            if joints.shape != (readings.shape[0], self.joint_inputs):
                raise ValueError(f"joints must be (B, {self.joint_inputs}), got {tuple(joints.shape)}")
            joints = joints.to(dtype)
            if not torch.isfinite(joints.sum()):
                raise ValueError("joints contain NaN or inf")
        elif joints is not None:
            raise ValueError("this model was built without joint inputs (joint_inputs=0) but was given joints")
        return readings, positions, joints

    def reset_parameters(self) -> None:
        """Re-draw every weight as at construction."""
        for m in self.modules():
            reset = getattr(m, "reset_parameters", None)
            if m is not self and reset is not None:
                reset()


def reading_input(readings: Tensor, kind: str) -> Tensor:
    """The dense models' force input from the readings (N): see ``config.READING_FEATURES``."""
    if kind == "raw":
        return readings
    return torch.log1p(readings.clamp_min(0.0) / READING_LOG_SCALE)


def mlp(sizes: list[int]) -> nn.Sequential:
    """Linear layers of the given widths with ReLU in between (none after the last)."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)
