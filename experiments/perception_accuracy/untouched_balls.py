"""Which balls of a Baoding dataset touch no taxel, and which skin patches fire.

    .venv/bin/python experiments/perception_accuracy/untouched_balls.py data/baoding_gt_25000

A ball is untouched when no activated taxel lies within 3 cm of its centre (as
`tacgnn.perception.train.ball_visibility_errors`), over all shards.
"""

from __future__ import annotations

import sys
from pathlib import Path

import h5py
import numpy as np

from tacgnn.datasets.store import read_manifest
from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.config import from_dict


def main() -> None:
    root = Path(sys.argv[1])
    skin = from_dict(SkinLayout, read_manifest(root)["metadata"]["skin"])
    balls, active, nearest = [], [], []
    for shard in sorted(root.glob("shard_*.h5")):
        with h5py.File(shard, "r") as f:
            b, on, taxels = f["ball_pos"][:], f["tactile"][:] > 0, f["taxel_pos"][:]
        dist = np.linalg.norm(taxels[:, None] - b[:, :, None], axis=-1)  # (frames, ball, taxel)
        nearest.append(np.where(on[:, None], dist, np.inf).min(-1))
        balls.append(b)
        active.append(on)
    balls, active, nearest = np.concatenate(balls), np.concatenate(active), np.concatenate(nearest)
    print(f"{len(balls)} frames; untouched balls: {100 * (nearest >= 0.03).mean():.1f} %")
    for b in range(2):
        seen = nearest[:, b] < 0.03
        print(f"ball {b}: untouched in {100 * (1 - seen.mean()):.1f} % of frames; mean height "
              f"{100 * balls[~seen, b, 2].mean():.2f} cm untouched, {100 * balls[seen, b, 2].mean():.2f} cm touched")
    offsets = skin.offsets()
    for i, patch in enumerate(skin.patches):
        share = active[:, offsets[i]:offsets[i + 1]].any(1).mean()
        print(f"{patch.name:16s} frames with an activated taxel: {100 * share:.0f} %")


if __name__ == "__main__":
    main()
