"""Sequence data of the teacher's long holds only: episodes still running at a given step.

The temporal TacGNN's test error on the ground-truth hold policy's episodes is a tail: the
episodes that run past step 150 (about 1 % of them; both balls stuck in a grip the policy
cannot turn out of) are placed at 0.9-1.8 cm against 0.15 cm for the rest, and the training
episodes hold 13 of them (``experiments/temporal_diagnosis.py``). This makes more of them:
the same policy, env, skin and action noise as the dataset given with ``--like``, another
seed, and only the episodes still running at ``--min-steps`` kept (every frame from their
start, so a temporal model reads them as in the env). Training adds them to the training
episodes only (``--set extra_train=[...]``), so the test episodes stay the same::

    .venv/bin/python experiments/temporal_long_holds.py --like data/baoding_seq2 \\
        --out data/baoding_long_s2 --seed 2 --samples 20000 --min-steps 150
    tacgnn train-perception --dataset data/baoding_seq2 --run runs/perception/temporal_long/tacgnn32_temporal \\
        --temporal --model tacgnn --channels 32 --epochs 17 --window 32 --burn-in 200 \\
        --set batch_size=16 lr_decay=0.826 "extra_train=[data/baoding_long_s2]"
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from tacgnn.config import ConfigError, from_dict
from tacgnn.datasets.baoding_data import BaodingDataConfig, generate
from tacgnn.datasets.store import load, read_manifest
from tacgnn.user_errors import run_script


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--like", required=True, help="a sequence dataset whose config and policy to reuse")
    parser.add_argument("--out", required=True)
    parser.add_argument("--seed", type=int, required=True, help="another seed than --like's: new episodes")
    parser.add_argument("--samples", type=int, default=20_000)
    parser.add_argument("--shard-size", type=int, default=5_000)
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--min-steps", type=int, default=150, help="keep episodes still running at this step")
    args = parser.parse_args()

    meta = read_manifest(args.like)["metadata"]
    base = from_dict(BaodingDataConfig, meta["config"])
    if args.seed == base.seed:
        raise ConfigError(f"--seed {args.seed}: {args.like} was made with this seed; its episodes would repeat")
    cfg = replace(base, seed=args.seed, samples=args.samples, shard_size=args.shard_size, num_envs=args.envs,
                  min_episode_steps=args.min_steps)
    policy = None
    if cfg.policy_checkpoint:
        from tacgnn.learning.policy import load_policy

        policy, _ = load_policy(cfg.policy_checkpoint)
    from tqdm import tqdm

    generate(cfg, args.out, progress=lambda it: tqdm(it, desc=f"shards of {cfg.shard_size}", unit="shard"),
             policy=policy)
    data = load(args.out, ["episode", "step"])
    ids, counts = np.unique(data["episode"], return_counts=True)
    last = np.array([data["step"][data["episode"] == e].max() for e in ids])
    print(f"{args.out}: {len(data['step'])} frames in {len(ids)} episodes; frames per episode median "
          f"{int(np.median(counts))}; episodes at the step limit: {int((last >= cfg.env.max_episode_steps - 1).sum())}")


if __name__ == "__main__":
    raise SystemExit(run_script(main))
