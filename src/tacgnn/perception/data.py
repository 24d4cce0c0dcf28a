"""A tactile dataset in memory, as a perception model reads it, and its train/test split."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, TypeVar

import torch

from tacgnn.datasets.store import DatasetError, load, read_manifest
from tacgnn.perception.objectives import CM, TaskName, targets


@dataclass
class TactileData:
    """Readings (N, T) in N, taxel positions (N, T, 3) in cm, targets (N, D), and joint
    angles (N, 16) in rad for models that read them (else None)."""

    readings: torch.Tensor
    positions: torch.Tensor
    targets: torch.Tensor
    joints: torch.Tensor | None = None

    def __len__(self) -> int:
        return len(self.targets)

    def subset(self, idx) -> TactileData:
        joints = None if self.joints is None else self.joints[idx]
        return TactileData(self.readings[idx], self.positions[idx], self.targets[idx], joints)

    def with_readings(self, readings: torch.Tensor) -> TactileData:
        """The same frames with other readings (dead taxels, a lost patch)."""
        return TactileData(readings, self.positions, self.targets, self.joints)

    def batch(self, idx) -> tuple[torch.Tensor, ...]:
        """A model's inputs for rows `idx`: (readings, positions) or (readings, positions, joints)."""
        inputs = (self.readings[idx], self.positions[idx])
        return inputs if self.joints is None else (*inputs, self.joints[idx])


def dataset_kind(task: TaskName) -> str:
    return "baoding" if task == "baoding" else "grasp"


def load_tactile(root: str | Path, task: TaskName, max_samples: int = 0, joints: bool = False) -> TactileData:
    """Read a dataset for `task`; `joints` also reads the joint angles.

    Raises :class:`~tacgnn.datasets.store.DatasetError` naming the folder when the dataset
    is missing, corrupt, or of another kind than the task needs.
    """
    meta = read_manifest(root)["metadata"]
    kind = dataset_kind(task)
    if meta.get("kind") != kind or (kind == "grasp" and meta.get("object") != task):
        raise DatasetError(f"{root}: dataset is kind={meta.get('kind')!r} object={meta.get('object')!r}, "
                         f"task '{task}' needs kind={kind!r}" + ("" if kind == "baoding" else f" object={task!r}"))
    fields = ["tactile", "taxel_pos", "ball_pos"] if kind == "baoding" else \
        ["tactile", "taxel_pos", "object_pos", "object_rot"]
    data = load(root, fields + (["joint_pos"] if joints else []))
    if max_samples:
        data = {k: v[:max_samples] for k, v in data.items()}
    return TactileData(torch.from_numpy(data["tactile"]), torch.from_numpy(data["taxel_pos"] * CM),
                       torch.from_numpy(targets(data, task)),
                       torch.from_numpy(data["joint_pos"]).float() if joints else None)


class Rows(Protocol):
    def __len__(self) -> int: ...

    def subset(self, idx: torch.Tensor): ...


R = TypeVar("R", bound=Rows)


def split(data: R, train_fraction: float, seed: int) -> tuple[R, R]:
    """Seeded random split into (train, test) by frame (of frames or sequence data); each side keeps
    at least one frame."""
    if len(data) < 2:
        raise DatasetError(f"the data holds {len(data)} frame(s); a train/test split needs at least 2")
    order = torch.randperm(len(data), generator=torch.Generator().manual_seed(seed))
    cut = min(max(1, int(round(train_fraction * len(data)))), len(data) - 1)
    return data.subset(order[:cut]), data.subset(order[cut:])
