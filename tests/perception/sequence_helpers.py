"""Synthetic Baoding-like episodes for the sequence tests: balls that the skin sometimes stops feeling.

Taxels lie on a fixed random plane patch (cm). Each ball wanders while a taxel blob under it
reads > 0, and stands still while untouched: where it is then follows from where it was
last felt, which a temporal model can learn and a single-frame model cannot.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from tacgnn.datasets.baoding_data import schema
from tacgnn.datasets.store import ShardedWriter
from tacgnn.perception.data import TactileData
from tacgnn.perception.sequences import SequenceData

T = 96


def taxels(seed: int = 0) -> np.ndarray:
    g = np.random.default_rng(seed)
    return np.stack([g.uniform(0, 14, T), g.uniform(0, 8, T), np.zeros(T)], 1)  # cm


def episodes(n_episodes: int, length: int | tuple[int, int], seed: int, blind: float = 0.4) -> dict[str, np.ndarray]:
    """Arrays in the dataset's schema (metres, N), episodes of `length` frames (or a range)."""
    g = np.random.default_rng(seed)
    pos = taxels()
    out: dict[str, list] = {k: [] for k in schema(T)}
    for e in range(n_episodes):
        n = length if isinstance(length, int) else int(g.integers(*length))
        centre = np.array([[3.5, 4.0, 0.0], [10.5, 4.0, 0.0]]) + np.c_[g.uniform(-2, 2, (2, 2)), np.zeros(2)]
        touch = np.ones(2, bool)
        for step in range(1, n + 1):
            if step > 1:
                touch = np.where(g.random(2) < 0.15, ~touch, touch) if blind else touch
                if blind == 0:
                    touch[:] = True
                move = np.c_[g.normal(0, 0.4, (2, 2)), np.zeros(2)]
                centre = centre + move * touch[:, None]  # an untouched ball stands still
                centre[:, 0] = np.clip(centre[:, 0], [1, 8], [6, 13])
                centre[:, 1] = np.clip(centre[:, 1], 1, 7)
            readings = np.zeros(T, np.float32)
            for b in range(2):
                if touch[b]:
                    near = np.linalg.norm(pos - centre[b], axis=1) < 1.2
                    readings[near] = 0.5
            out["tactile"].append(readings)
            out["taxel_pos"].append(pos / 100.0)
            out["joint_pos"].append(np.zeros(16))
            out["joint_vel"].append(np.zeros(16))
            out["ball_pos"].append(centre / 100.0)
            out["action"].append(np.zeros(16))
            out["episode"].append(e + 1000 * seed)
            out["step"].append(step)
    return {k: np.asarray(v) for k, v in out.items()}


def to_sequence_data(arrays: dict[str, np.ndarray]) -> SequenceData:
    frames = TactileData(torch.from_numpy(arrays["tactile"]).float(),
                         torch.from_numpy(arrays["taxel_pos"] * 100).float(),
                         torch.from_numpy(arrays["ball_pos"].reshape(-1, 6) * 100).float(),
                         torch.from_numpy(arrays["joint_pos"]).float())
    return SequenceData(frames, torch.from_numpy(arrays["action"]).float(), torch.from_numpy(arrays["episode"]),
                        torch.from_numpy(arrays["step"]))


def write_dataset(root: Path, arrays: dict[str, np.ndarray], shards: int = 2) -> Path:
    """A dataset folder holding `arrays` in `shards` shards (frames shuffled: the loader sorts them)."""
    n = len(arrays["episode"])
    assert n % shards == 0, f"{n} frames do not fill {shards} shards"
    order = np.random.default_rng(0).permutation(n)
    writer = ShardedWriter(root, schema(T), {"kind": "baoding", "num_taxels": T}, num_shards=shards,
                           shard_size=n // shards)
    size = n // shards
    writer.generate_missing(lambda i: {k: v[order[i * size:(i + 1) * size]] for k, v in arrays.items()})
    return root
