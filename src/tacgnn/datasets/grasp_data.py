"""The power-grasp datasets (cube, cylinder, meat can): final frames and object poses.

Per sample: taxel readings (N), taxel world positions (m), joint positions, the object's
centre (m, world axes) and rotation matrix (world from object). Grasps in which the
object left the hand (it fell, or rests more than 8 cm from the palm centre) or touches
fewer than 3 taxels are discarded and replaced, so every sample is a real grasp.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tacgnn.config import check, check_seed, to_dict
from tacgnn.datasets.store import Field, ShardedWriter
from tacgnn.envs.grasp import GraspConfig, PowerGrasp


@dataclass(frozen=True)
class GraspDataConfig:
    samples: int = 20_000
    shard_size: int = 5_000
    num_envs: int = 128
    seed: int = 0
    min_taxels: int = 3
    grasp: GraspConfig = field(default_factory=GraspConfig)

    def __post_init__(self) -> None:
        check_seed(self.seed)
        check(self.shard_size > 0, "shard_size", f"must be >= 1, got {self.shard_size}")
        check(self.samples > 0 and self.samples % self.shard_size == 0, "samples",
              f"must be a positive multiple of shard_size ({self.shard_size}), got {self.samples}")
        check(1 <= self.num_envs <= 65_536, "num_envs", f"must be in 1..65536, got {self.num_envs}")
        check(self.min_taxels >= 0, "min_taxels", "must be >= 0")


def schema(num_taxels: int) -> dict[str, Field]:
    return {
        "tactile": Field((num_taxels,)),
        "taxel_pos": Field((num_taxels, 3)),
        "joint_pos": Field((16,)),
        "object_pos": Field((3,)),
        "object_rot": Field((3, 3)),
    }


def held(sim: PowerGrasp, out: dict[str, np.ndarray], min_taxels: int) -> np.ndarray:
    """Which grasps of `sim.run`'s output kept the object: above the palm, within 8 cm of its
    centre, and pressing at least `min_taxels` taxels."""
    centre = sim.palm_axes @ np.array([0.0111, 0.0, -0.045])
    rel = (out["object_pos"] - centre) @ sim.palm_axes
    ok = (rel[:, 0] > 0) & (rel[:, 0] < 0.08) & (np.linalg.norm(rel[:, 1:], axis=1) < 0.08)
    return ok & ((out["tactile"] > 0).sum(1) >= min_taxels)


def record_shard(cfg: GraspDataConfig, index: int) -> dict[str, np.ndarray]:
    """Grasp until a shard is full; deterministic in (seed, index)."""
    sim = PowerGrasp(replace(cfg.grasp, num_envs=cfg.num_envs))
    parts: dict[str, list] = {k: [] for k in schema(sim.tactile.num_taxels)}
    count, batch = 0, 0
    while count < cfg.shard_size:
        out = sim.run(seed=(cfg.seed * 100_003 + index) * 1_000 + batch)
        batch += 1
        ok = held(sim, out, cfg.min_taxels)
        for k in parts:
            parts[k].append(out[k][ok])
        count += int(ok.sum())
    return {k: np.concatenate(v)[:cfg.shard_size] for k, v in parts.items()}


def generate(cfg: GraspDataConfig, root: str | Path, progress=None) -> Path:
    from tacgnn import __version__

    meta = {"kind": "grasp", "object": cfg.grasp.object, "num_taxels": cfg.grasp.skin.num_taxels,
            "seed": cfg.seed, "skin": to_dict(cfg.grasp.skin), "code_version": __version__,
            "config": to_dict(cfg)}
    writer = ShardedWriter(root, schema(cfg.grasp.skin.num_taxels), meta,
                           num_shards=cfg.samples // cfg.shard_size, shard_size=cfg.shard_size)
    writer.generate_missing(lambda i: record_shard(cfg, i), progress=progress)
    return Path(root)
