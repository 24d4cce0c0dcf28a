"""The `tacgnn` command line: one sub-command per user-facing job.

    tacgnn demo                      the shipped TacGNN policy on Simple: success rate and a video
    tacgnn render --out ep.mp4       video of an episode (MP4 or GIF) and a skin picture
    tacgnn view                      interactive MuJoCo viewer (needs a display)
    tacgnn config                    print the default Baoding config as YAML
    tacgnn make-dataset baoding --out data/baoding      skin frames + ball positions (HDF5 shards)
    tacgnn make-dataset grasp --object cube --out data/cube   power grasps + object poses
    tacgnn train-perception --task baoding --model tacgnn --dataset data/baoding --run runs/p1
    tacgnn eval-perception --checkpoint runs/p1/checkpoint.pt --dataset data/baoding [--dead 0.1]
    tacgnn train-policy --run-dir runs/gt --env obs_mode=groundtruth --ppo max_iterations=2000 [--resume]
    tacgnn evaluate runs/gt/model_002000.pt --task middle --episodes 500

Every command takes ``--config FILE.yaml`` and ``--set key=value`` (dotted keys, e.g.
``--set task=middle sim.timestep=0.004``); unknown keys fail before anything runs.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from tacgnn.config import ConfigError, load_yaml, override, parse_overrides, to_dict


def _baoding_config(args):
    from tacgnn.envs.baoding import BaodingConfig

    cfg = load_yaml(BaodingConfig, args.config) if args.config else BaodingConfig()
    updates = parse_overrides(args.set or [])
    if getattr(args, "envs", None):
        updates["num_envs"] = args.envs
    return override(cfg, updates) if updates else cfg


def _make_env(args):
    from tacgnn.envs.baoding import BaodingEnv

    return BaodingEnv(_baoding_config(args))


def cmd_config(args) -> int:
    print(yaml.safe_dump(to_dict(_baoding_config(args)), sort_keys=False))
    return 0


SHIPPED_POLICY = Path(__file__).parent / "assets" / "baoding_policy.pt"


def cmd_demo(args) -> int:
    """Run the shipped policy (or the scripted controller) on Simple; print results; write a video."""
    policy_file = None if args.scripted else Path(args.policy or SHIPPED_POLICY)
    if policy_file is not None and not policy_file.is_file():
        if args.policy:
            raise ConfigError(f"policy file not found: {policy_file}")
        print(f"(no shipped policy at {policy_file}: running the scripted controller)")
        policy_file = None
    if policy_file is None:
        return _demo_scripted(args)
    from dataclasses import replace

    from tacgnn.envs.baoding import BaodingEnv
    from tacgnn.learning.evaluate import evaluate
    from tacgnn.learning.ppo import load_perception, load_policy

    policy, env_cfg = load_policy(policy_file)
    perception = load_perception(policy_file)
    start = time.perf_counter()
    result = evaluate(policy_file, "simple", episodes=args.episodes, num_envs=min(args.envs, args.episodes),
                      seed=args.seed, perception=perception)
    seconds = time.perf_counter() - start
    seen = "perceived by the skin (TacGNN)" if perception is not None else f"from '{env_cfg.obs_mode}'"
    print(f"Baoding, Simple task, policy {policy_file.name}: ball positions {seen}")
    print(f"  success rate:          {100 * result['success_rate']:.1f} % of {result['episodes']} episodes "
          f"(95 % CI {100 * result['ci95'][0]:.1f}-{100 * result['ci95'][1]:.1f})")
    print(f"  mean steps to success: {result['mean_steps_to_success']:.1f} (control at 50 Hz)")
    print(f"  falls:                 {100 * result['fall_rate']:.1f} %   ({seconds:.1f} s)")
    if args.video:
        from tacgnn.tools.render import render_episode

        env = BaodingEnv(replace(env_cfg, num_envs=1, task="simple", tactile=True), perception=perception)
        obs, _ = env.reset(seed=args.seed)
        summary = render_episode(env, policy, args.video, steps=args.video_steps, obs=obs)
        print(f"  video: {args.video} ({summary['frames']} frames, skin panel beside the hand, "
              f"{summary['mean_active_taxels']:.1f} activated taxels/frame)")
    return 0


def _demo_scripted(args) -> int:
    from tacgnn.envs.scripted import FingerWave

    env = _make_env(args)
    obs, _ = env.reset(seed=args.seed)
    controller = FingerWave(env.last_action[0], env.num_envs, seed=args.seed)
    active, angles, falls, episodes = [], [], 0, 0
    start = time.perf_counter()
    for _ in range(args.steps):
        obs, _, terminated, truncated, info = env.step(controller(obs))
        active.append((info["tactile"] > 0).sum(1).mean())
        done = terminated | truncated
        episodes += int(done.sum())
        falls += int(info["fall"].sum())
        angles.extend(np.abs(info["angle_deg"][done]))
    seconds = time.perf_counter() - start
    print(f"Baoding, scripted finger wave, {env.num_envs} envs x {args.steps} steps "
          f"({env.substeps} physics substeps each)")
    print(f"  env steps/s:              {args.steps * env.num_envs / seconds:,.0f}")
    print(f"  activated taxels / step:  {np.mean(active):.1f} of {env.tactile.num_taxels}")
    print(f"  episodes ended:           {episodes} (falls {falls})")
    if angles:
        print(f"  |rotation| at episode end: mean {np.mean(angles):.1f} deg, max {np.max(angles):.1f} deg")
    if args.video:
        from tacgnn.tools.render import render_episode

        env1 = _make_env(argparse.Namespace(**{**vars(args), "envs": 1}))
        env1.reset(seed=args.seed)
        summary = render_episode(env1, FingerWave(env1.last_action[0], 1, seed=args.seed), args.video,
                                 steps=args.video_steps)
        print(f"  video: {args.video} ({summary['frames']} frames)")
    return 0


def cmd_render(args) -> int:
    from tacgnn.envs.scripted import FingerWave
    from tacgnn.tools.render import render_episode, save_skin_picture

    env = _make_env(argparse.Namespace(**{**vars(args), "envs": 1}))
    env.reset(seed=args.seed)
    summary = render_episode(env, FingerWave(env.last_action[0], 1, seed=args.seed), args.out, steps=args.steps)
    print(f"wrote {args.out}: {summary['frames']} frames, final angle {summary['final_angle_deg']:.1f} deg, "
          f"{summary['mean_active_taxels']:.1f} activated taxels/frame")
    if args.skin_picture:
        save_skin_picture(env, args.skin_picture)
        print(f"wrote {args.skin_picture}")
    return 0


def cmd_view(args) -> int:
    from tacgnn.envs.scripted import FingerWave
    from tacgnn.tools.render import launch_viewer

    env = _make_env(argparse.Namespace(**{**vars(args), "envs": 1}))
    env.reset(seed=args.seed)
    launch_viewer(env, FingerWave(env.last_action[0], 1, seed=args.seed))
    return 0


def cmd_make_dataset(args) -> int:
    """Generate (or resume generating) a dataset; only missing shards are made."""
    from tqdm import tqdm

    from tacgnn.datasets import baoding_data, grasp_data
    from tacgnn.envs.grasp import GraspConfig

    progress = (lambda it: tqdm(it, desc=f"shards of {args.shard_size}", unit="shard"))
    if args.kind == "baoding":
        env = override(_baoding_config(args), {"obs_mode": "tactile"})
        cfg = baoding_data.BaodingDataConfig(samples=args.samples, shard_size=args.shard_size,
                                             seed=args.seed, env=env, policy_checkpoint=args.policy or "",
                                             settle_steps=args.settle_steps)
        baoding_data.generate(cfg, args.out, progress=progress)
    else:
        cfg = grasp_data.GraspDataConfig(samples=args.samples, shard_size=args.shard_size, seed=args.seed,
                                         grasp=GraspConfig(object=args.object))
        grasp_data.generate(cfg, args.out, progress=progress)
    print(f"dataset complete: {args.out} ({args.samples} samples)")
    return 0


def cmd_train_perception(args) -> int:
    from tacgnn.perception.train import PerceptionTrainConfig, train

    cfg = PerceptionTrainConfig.for_task(args.task, args.model, epochs=args.epochs, seed=args.seed,
                                         max_samples=args.max_samples,
                                         model_kw={"channels": args.channels} if args.channels else {})
    if args.set:
        cfg = override(cfg, parse_overrides(args.set))
    final = train(cfg, args.dataset, args.run, resume=args.resume)
    print("final:", {k: round(v, 4) for k, v in final.items() if isinstance(v, float)})
    return 0


def cmd_eval_perception(args) -> int:
    from tacgnn.perception.train import evaluate

    for dead in args.dead:
        metrics = evaluate(args.checkpoint, args.dataset, dead_fraction=dead, seed=args.seed, whole=args.whole)
        print(f"dead taxels {dead:.0%}: " + ", ".join(f"{k} {v:.4f}" for k, v in metrics.items()))
    return 0


def cmd_train_policy(args) -> int:
    from tacgnn.learning import ppo

    return ppo.main(args.rest)


def cmd_evaluate(args) -> int:
    from tacgnn.learning import evaluate

    return evaluate.main(args.rest)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tacgnn", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)

    def add(name: str, fn, help: str) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help)
        p.add_argument("--config", help="YAML file with Baoding config keys")
        p.add_argument("--set", nargs="*", metavar="KEY=VALUE", help="override config keys")
        p.add_argument("--seed", type=int, default=0)
        p.set_defaults(fn=fn)
        return p

    p = add("demo", cmd_demo, "run the shipped Baoding policy (TacGNN perception) and write a video")
    p.add_argument("--policy", help=f"policy or checkpoint file (default: the shipped {SHIPPED_POLICY.name})")
    p.add_argument("--scripted", action="store_true", help="the scripted finger wave instead of a policy")
    p.add_argument("--episodes", type=int, default=64)
    p.add_argument("--envs", type=int, default=64)
    p.add_argument("--steps", type=int, default=200, help="scripted: control steps")
    p.add_argument("--video", default="outputs/demo.mp4", help="'' to skip the video")
    p.add_argument("--video-steps", type=int, default=100)
    p = add("render", cmd_render, "write a video of one episode and a skin picture")
    p.add_argument("--out", default="outputs/episode.mp4")
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--skin-picture", default="outputs/skin.png")
    add("view", cmd_view, "interactive viewer (needs a display)")
    add("config", cmd_config, "print the default config as YAML")
    p = add("make-dataset", cmd_make_dataset, "generate a tactile dataset (resumes if interrupted)")
    p.add_argument("kind", choices=["baoding", "grasp"])
    p.add_argument("--out", required=True)
    p.add_argument("--samples", type=int, default=25_000)
    p.add_argument("--shard-size", type=int, default=5_000)
    p.add_argument("--object", choices=["cube", "cylinder", "meat_can"], default="cube")
    p.add_argument("--policy", help="baoding: a ground-truth PPO checkpoint drives the balls")
    p.add_argument("--settle-steps", type=int, default=5,
                   help="baoding: skip this many first steps of each episode (0 keeps the dropping balls)")

    p = sub.add_parser("train-perception", help="train a perception model on a dataset")
    p.add_argument("--task", choices=["baoding", "cube", "cylinder", "meat_can"], default="baoding")
    p.add_argument("--model", choices=["tacgnn", "mlp", "cnn", "gcn"], default="tacgnn")
    p.add_argument("--dataset", required=True)
    p.add_argument("--run", required=True, help="run folder: checkpoint, history, TensorBoard")
    p.add_argument("--epochs", type=int, default=10)
    p.add_argument("--channels", type=int, default=0, help="TacGNN channels (16/32/64/128)")
    p.add_argument("--max-samples", type=int, default=0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--resume", action="store_true")
    p.add_argument("--set", nargs="*", metavar="KEY=VALUE", help="override training config keys")
    p.set_defaults(fn=cmd_train_perception)

    for name, fn, text in (("train-policy", cmd_train_policy, "train PPO on the Baoding env (see --help)"),
                           ("evaluate", cmd_evaluate, "success rate of a policy on simple/middle/hard")):
        p = sub.add_parser(name, help=text, add_help=False)
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(fn=fn)

    p = sub.add_parser("eval-perception", help="errors of a trained perception model")
    p.add_argument("--checkpoint", required=True)
    p.add_argument("--dataset", required=True)
    p.add_argument("--dead", type=float, nargs="*", default=[0.0], help="fractions of dead taxels")
    p.add_argument("--whole", action="store_true", help="use the whole dataset, not its test split")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(fn=cmd_eval_perception)
    return parser


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("MUJOCO_GL", "egl")
    argv = sys.argv[1:] if argv is None else argv
    passthrough = {"train-policy": cmd_train_policy, "evaluate": cmd_evaluate}
    if argv and argv[0] in passthrough:  # these parse their own flags (--help included)
        return passthrough[argv[0]](argparse.Namespace(rest=argv[1:]))
    args = build_parser().parse_args(argv)
    for name in ("video", "out", "skin_picture"):
        value = getattr(args, name, None)
        if value:
            Path(value).parent.mkdir(parents=True, exist_ok=True)
    try:
        return args.fn(args)
    except ConfigError as err:
        print(f"tacgnn: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
