"""How the meat can ends a power grasp when dropped on its broad or its narrow face.

    .venv/bin/python experiments/perception_accuracy/can_faces.py [--batches 4] [--envs 64]

For each `GraspConfig.can_face`, runs batches of grasps and prints the share the dataset
would keep (`grasp_data.held`, the dataset's default of 3 pressed taxels), the share of the
kept ones whose 50 / 97 / 82 mm axis ends along the palm normal, and the mean number of
pressed taxels.
"""

from __future__ import annotations

import argparse

import numpy as np

from tacgnn.datasets.grasp_data import GraspDataConfig, held
from tacgnn.envs.grasp import GraspConfig, PowerGrasp


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batches", type=int, default=4)
    ap.add_argument("--envs", type=int, default=64)
    args = ap.parse_args()
    min_taxels = GraspDataConfig().min_taxels
    for face in ("broad", "narrow"):
        sim = PowerGrasp(GraspConfig(object="meat_can", num_envs=args.envs, can_face=face))
        normal = sim.palm_axes[:, 0]
        kept, up_axes, pressed = 0, [], []
        for seed in range(args.batches):
            out = sim.run(seed)
            ok = held(sim, out, min_taxels)
            kept += int(ok.sum())
            up_axes.append(np.abs(np.einsum("nij,i->nj", out["object_rot"][ok], normal)).argmax(1))
            pressed.append((out["tactile"][ok] > 0).sum(1))
        total = args.batches * args.envs
        up = np.bincount(np.concatenate(up_axes), minlength=3) / max(kept, 1)
        print(f"{face:6s}: kept {kept}/{total} ({100 * kept / total:.0f} %); up axis 50/97/82 mm: "
              f"{100 * up[0]:.0f} / {100 * up[1]:.0f} / {100 * up[2]:.0f} %; "
              f"pressed taxels {np.concatenate(pressed).mean():.1f}")


if __name__ == "__main__":
    main()
