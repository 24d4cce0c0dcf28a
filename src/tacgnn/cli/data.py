"""Commands on the data -> perception path: record a dataset, train and evaluate a perception model."""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

from tacgnn.cli.common import add_config_options, baoding_config, build_config, count, fraction, seed
from tacgnn.config import ConfigError, override, parse_overrides
from tacgnn.files import atomic_write_text, check_writable


def cmd_make_dataset(args) -> int:
    """Generate (or resume generating) a dataset; only missing shards are made."""
    from tqdm import tqdm

    from tacgnn.datasets import baoding_data, grasp_data
    from tacgnn.envs.grasp import GraspConfig

    def progress(it):
        return tqdm(it, desc=f"shards of {args.shard_size}", unit="shard")

    if args.kind == "baoding":
        if args.object:
            raise ConfigError("--object goes with 'make-dataset grasp'")
        # the recording env: BaodingConfig keys, --envs; --seed is the dataset's (shard i from seed, i)
        env = override(baoding_config(argparse.Namespace(**{**vars(args), "seed": None})), {"obs_mode": "tactile"})
        given = {"settle_steps": args.settle_steps, "keep_every": args.keep_every, "num_envs": args.envs,
                 "scripted": args.scripted}
        if args.policy and args.scripted:
            raise ConfigError("--scripted names the controller used without --policy; give one of them")
        cfg = baoding_data.BaodingDataConfig(samples=args.samples, shard_size=args.shard_size, seed=args.seed,
                                             env=env, policy_checkpoint=args.policy or "",
                                             **{k: v for k, v in given.items() if v is not None})
        policy, perception = _recording_policy(args.policy, env) if args.policy else (None, None)
        if perception is not None:  # a blind policy: the recording env shows it what its perception makes
            cfg = replace(cfg, env=replace(env, obs_mode="perceived"))
        check_writable(args.out, "dataset folder")
        baoding_data.generate(cfg, args.out, progress=progress, policy=policy, perception=perception)
    else:
        for flag, value in (("--policy", args.policy), ("--scripted", args.scripted),
                            ("--settle-steps", args.settle_steps), ("--keep-every", args.keep_every),
                            ("--envs", args.envs)):
            if value is not None:
                raise ConfigError(f"{flag} goes with 'make-dataset baoding' (grasps take GraspConfig keys: --set)")
        grasp_cfg = grasp_data.GraspDataConfig(samples=args.samples, shard_size=args.shard_size, seed=args.seed,
                                               grasp=build_config(GraspConfig, args, object=args.object))
        check_writable(args.out, "dataset folder")
        grasp_data.generate(grasp_cfg, args.out, progress=progress)
    print(f"dataset complete: {args.out} ({args.samples} samples)")
    return 0


def _recording_policy(path: str, env) -> tuple[Any, Any]:
    """The policy that drives the balls, checked against the recording env, and for a blind
    policy what makes its perception afresh (each shard starts its memory from nothing)."""
    from tacgnn.learning.checkpoint import check_policy_fits, load_policy_file, stored_env_config
    from tacgnn.learning.policy import perception_from_checkpoint, policy_from_checkpoint

    data = load_policy_file(path)
    mode = stored_env_config(data, path).obs_mode
    if mode not in ("groundtruth", "perceived"):
        raise ConfigError(f"--policy {path}: a '{mode}' policy; recording needs a 'groundtruth' one "
                          "(it reads the true ball positions) or a 'perceived' one (its own perception's)")
    # the policy acts on the recording env's view of the balls, shown as it was trained
    check_policy_fits(data, replace(env, obs_mode=mode), path)
    perception = None if mode == "groundtruth" else (lambda: perception_from_checkpoint(data, path))
    return policy_from_checkpoint(data, path), perception


def cmd_train_perception(args) -> int:
    """Train a perception model: single-frame (split by frame, or --by-episode) or --temporal."""
    import dataclasses

    from tacgnn.perception.train_config import TEMPORAL_ROUTE, PerceptionTrainConfig

    if args.temporal and args.by_episode:
        raise ConfigError("--temporal and --by-episode exclude each other (--by-episode is the single-frame model)")
    if not args.temporal and (args.window is not None or args.burn_in is not None):
        raise ConfigError("--window and --burn-in go with --temporal")
    cfg = PerceptionTrainConfig.for_task(args.task, args.model, epochs=args.epochs, seed=args.seed,
                                         max_samples=args.max_samples,
                                         model_kw={"channels": args.channels} if args.channels else {})
    given = {"window": args.window, "burn_in": args.burn_in}
    route: dict[str, Any] = {**TEMPORAL_ROUTE, **{k: v for k, v in given.items() if v is not None}} \
        if args.temporal else {"split": "episode"} if args.by_episode else {}
    if route and args.task != "baoding":
        raise ConfigError(f"--temporal/--by-episode train on Baoding sequences (--task baoding), not {args.task!r}")
    cfg = dataclasses.replace(cfg, **route)
    if args.set:
        cfg = override(cfg, parse_overrides(args.set))
    check_writable(args.run, "run folder")
    from tacgnn.perception.training import train

    final = train(cfg, args.dataset, args.run, resume=args.resume, init_from=args.init_from)
    print("final:", {k: round(v, 4) for k, v in final.items() if isinstance(v, float)})
    print(f"saved {args.run}/checkpoint.pt")
    return 0


def cmd_eval_perception(args) -> int:
    from tacgnn.datasets.store import read_manifest
    from tacgnn.perception.evaluation import evaluate, patch_loss, patch_taxels

    for patch in args.lose_patch:  # an unknown patch name fails before any evaluation
        patch_taxels(read_manifest(args.dataset)["metadata"]["skin"], patch)
    if args.out:
        check_writable(Path(args.out).parent)
    rows: list[dict[str, Any]] = []
    for dead in args.dead:
        metrics = evaluate(args.checkpoint, args.dataset, dead_fraction=dead, seed=args.seed, whole=args.whole)
        print(f"dead taxels {dead:.0%}: " + ", ".join(f"{k} {v:.4f}" for k, v in metrics.items()))
        rows.append({"dead_fraction": dead, **metrics})
    for patch in args.lose_patch:
        metrics = patch_loss(args.checkpoint, args.dataset, patch, whole=args.whole)
        print(f"without the {patch}: position_rmse_cm {metrics[f'position_rmse_cm_without_{patch}']:.4f} "
              f"(intact {metrics['position_rmse_cm']:.4f}, ratio {metrics['rmse_ratio']:.2f})")
        rows.append({"lost_patch": patch, **metrics})
    if args.out:
        from tacgnn.provenance import provenance

        result = {"rows": rows, "provenance": provenance({"checkpoint": args.checkpoint}, args.seed,
                                                         {"dataset": args.dataset, "whole": args.whole})}
        atomic_write_text(args.out, json.dumps(result, indent=1))
    return 0


def register(sub) -> None:
    """The sub-commands of this module, with their options."""
    p = sub.add_parser("make-dataset", help="generate a tactile dataset (resumes if interrupted)")
    p.add_argument("kind", choices=["baoding", "grasp"])
    add_config_options(p, "BaodingConfig (baoding) or GraspConfig (grasp)")
    p.add_argument("--seed", type=seed, default=0, help="the dataset's seed (shard i is made from seed, i)")
    p.add_argument("--out", required=True, help="dataset folder")
    p.add_argument("--samples", type=count(1), default=25_000, help="samples in the dataset")
    p.add_argument("--shard-size", type=count(1), default=5_000, help="samples per shard file")
    p.add_argument("--object", choices=["cube", "cylinder", "meat_can"],
                   help="grasp: the object (default: cube); --config/--set take GraspConfig keys for grasps, "
                        "e.g. --set can_face=narrow")
    p.add_argument("--policy", help="baoding: a PPO checkpoint drives the balls, a ground-truth one or a blind "
                                    "one on its own perception (default: the --scripted controller)")
    p.add_argument("--scripted", choices=["wave", "random"], help="baoding, without --policy: the finger wave or "
                   "smooth random motion of every joint (default: wave)")
    p.add_argument("--settle-steps", type=count(0), help="baoding: skip this many first steps of each episode "
                   "(0 keeps the dropping balls; default: 5)")
    p.add_argument("--keep-every", type=count(1), help="baoding: record every k-th step of each env; 1 keeps "
                   "every frame, for sequence models (default: 2)")
    p.add_argument("--envs", type=count(1), help="baoding: envs stepped together (default: 64; fewer give "
                   "longer episodes per shard)")
    p.set_defaults(fn=cmd_make_dataset)

    p = sub.add_parser("train-perception", help="train a perception model on a dataset")
    p.add_argument("--task", choices=["baoding", "cube", "cylinder", "meat_can"], default="baoding",
                   help="what the dataset holds")
    p.add_argument("--model", choices=["tacgnn", "mlp", "cnn", "gcn"], default="tacgnn", help="model family")
    p.add_argument("--dataset", required=True, help="dataset folder (make-dataset)")
    p.add_argument("--run", required=True, help="run folder: checkpoint, history, TensorBoard")
    p.add_argument("--epochs", type=count(1, 100_000), default=10, help="passes over the training split")
    p.add_argument("--channels", type=count(0), default=0, help="TacGNN channels (16/32/64/128); 0: the model's")
    p.add_argument("--max-samples", type=count(0), default=0, help="use the first this-many samples; 0: all")
    p.add_argument("--seed", type=seed, default=0, help="split, initialisation and batches")
    p.add_argument("--resume", action="store_true", help="continue the run in --run")
    p.add_argument("--init-from", help="start from the weights of this perception checkpoint, or of the perception "
                   "inside this blind policy file (the same network)")
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                   help="override training config keys (e.g. lr=1e-3 model.joint_inputs=16)")
    p.add_argument("--temporal", action="store_true",
                   help="baoding: a GRU over --model's per-frame features, trained on windows of episodes "
                        "(a dataset made with --keep-every 1; split by episode)")
    p.add_argument("--by-episode", action="store_true",
                   help="baoding: the single-frame --model on the same episode split and budget as --temporal")
    p.add_argument("--window", type=count(1), help="--temporal: frames per window with gradient (default: 16)")
    p.add_argument("--burn-in", type=count(0), help="--temporal: frames before a window that warm the state "
                   "without gradient (default: 16)")
    p.set_defaults(fn=cmd_train_perception)

    p = sub.add_parser("eval-perception", help="errors of a trained perception model")
    p.add_argument("--checkpoint", required=True, help="checkpoint.pt of a train-perception run")
    p.add_argument("--dataset", required=True, help="dataset folder")
    p.add_argument("--dead", type=fraction, nargs="*", default=[0.0], help="fractions of dead taxels, in [0, 1]")
    p.add_argument("--whole", action="store_true", help="use the whole dataset, not its test split")
    p.add_argument("--lose-patch", nargs="*", default=[], metavar="PATCH",
                   help="also report the error with every taxel of these skin patches at 0 (e.g. palm)")
    p.add_argument("--seed", type=seed, default=0, help="which taxels are dead")
    p.add_argument("--out", help="also write the figures as JSON here, with their provenance")
    p.set_defaults(fn=cmd_eval_perception)
