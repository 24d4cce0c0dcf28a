"""MLP baseline: the readings as one flat vector."""

from __future__ import annotations

import torch
from torch import Tensor

from tacgnn.perception.models.base import PerceptionModel, mlp, reading_input


class TactileMLP(PerceptionModel):
    r"""MLP baseline on the readings: :math:`y = \mathrm{MLP}([g(f), q])`, sizes ``[T (+J), 64, 64, out]``.

    :math:`g` is ``reading_feature`` (the raw reading, the paper's, or
    :func:`~tacgnn.perception.models.base.reading_input`'s log1p); the joint angles
    :math:`q` are appended when ``joint_inputs > 0``.

    Args:
        out_dim: outputs. num_taxels: T. hidden: hidden widths (default ``(64, 64)``).
        joint_inputs: J joint angles read beside the skin (default 0).
        reading_feature: ``"raw"`` or ``"log1p"``.

    Shapes:
        - **input:** ``readings (B, T)``, ``positions (B, T, 3)`` (unused), ``joints (B, J)``
        - **output:** ``(B, out_dim)``
    """

    def __init__(self, out_dim: int = 6, num_taxels: int = 653, hidden: tuple[int, ...] = (64, 64),
                 joint_inputs: int = 0, reading_feature: str = "raw") -> None:
        super().__init__()
        self.num_taxels, self.out_dim, self.joint_inputs = num_taxels, out_dim, joint_inputs
        self.reading_feature = reading_feature
        self.mlp = mlp([num_taxels + joint_inputs, *hidden, out_dim])

    def forward(self, readings: Tensor, positions: Tensor, joints: Tensor | None = None) -> Tensor:
        readings, positions, joints = self.prepare(readings, positions, joints)
        f = reading_input(readings, self.reading_feature)
        return self.mlp(f if joints is None else torch.cat([f, joints], 1))
