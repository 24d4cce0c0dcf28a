"""The `tacgnn` command line: one sub-command per user-facing job.

    tacgnn demo                      the shipped TacGNN policy on Simple: success rate and a video
    tacgnn render --out ep.mp4       video of an episode (MP4 or GIF) and a skin picture
    tacgnn view                      interactive MuJoCo viewer (needs a display)
    tacgnn config                    print the default Baoding config as YAML
    tacgnn make-dataset baoding --out data/baoding      skin frames + ball positions (HDF5 shards)
    tacgnn make-dataset grasp --object cube --out data/cube   power grasps + object poses
    tacgnn train-perception --task baoding --model tacgnn --dataset data/baoding --run runs/p1
    tacgnn eval-perception --checkpoint runs/p1/checkpoint.pt --dataset data/baoding [--dead 0.1] [--lose-patch palm]
    tacgnn train-policy --run-dir runs/gt --env obs_mode=groundtruth --ppo max_iterations=2000 [--resume]
    tacgnn evaluate runs/gt/model_002000.pt --task middle --episodes 500
    tacgnn sysid recording.npz --out outputs/sysid_hand.yaml    per-joint stiffness/damping from steps
    tacgnn sysid --make-recording rec.npz --random-truth        a simulated recording to try it on
    tacgnn calibrate-skin rest.npz --out skin_calibration.npz   real skin: baseline, thresholds, gains
    tacgnn real-hand run --calibration skin_calibration.npz     the blind policy on a real hand (ROS)

Every command takes ``--config FILE.yaml`` and ``--set key=value`` (dotted keys, e.g.
``--set task=middle sim.timestep=0.004``); unknown keys fail before anything runs.
A wrong file, key or value is reported in one line (exit code 2); ``--debug`` shows the traceback.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

# Idle OpenMP workers of torch's libgomp spin by default. With two jobs on this 2-core
# machine that made a 1-thread perception epoch 3-4x slower (15.7-17.1 s against
# 4.2-5.4 s with PASSIVE, same load). Read when torch loads, so set before any import of it.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np
import yaml

from tacgnn.config import ConfigError, load_yaml, override, parse_overrides, to_dict
from tacgnn.learning.policy import SHIPPED_POLICY
from tacgnn.user_errors import report_user_errors


def _config(cls, args, **given):
    """`cls` from --config (YAML) or its defaults, then --set, then the keys of the command's
    own flags `given` (None = flag not given), which win."""
    cfg = load_yaml(cls, args.config) if args.config else cls()
    updates = {**parse_overrides(args.set or []), **{k: v for k, v in given.items() if v is not None}}
    return override(cfg, updates) if updates else cfg


def _baoding_config(args):
    from tacgnn.envs.baoding import BaodingConfig

    return _config(BaodingConfig, args, num_envs=getattr(args, "envs", None) or None)


def _make_env(args):
    from tacgnn.envs.baoding import BaodingEnv

    return BaodingEnv(_baoding_config(args))


def cmd_config(args) -> int:
    print(yaml.safe_dump(to_dict(_baoding_config(args)), sort_keys=False))
    return 0




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
    from tacgnn.learning.policy import load_perception, load_policy

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
        active.append((env.skin_to_host(info["tactile"]) > 0).sum(1).mean())
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

    def progress(it):
        return tqdm(it, desc=f"shards of {args.shard_size}", unit="shard")

    if args.kind == "baoding":
        env = override(_baoding_config(args), {"obs_mode": "tactile"})
        cfg = baoding_data.BaodingDataConfig(samples=args.samples, shard_size=args.shard_size,
                                             seed=args.seed, env=env, policy_checkpoint=args.policy or "",
                                             settle_steps=args.settle_steps, keep_every=args.keep_every,
                                             num_envs=args.envs or baoding_data.BaodingDataConfig.num_envs)
        policy = None
        if args.policy:
            from dataclasses import replace

            from tacgnn.learning.checkpoint import check_policy_fits, load_policy_file, stored_env_config
            from tacgnn.learning.policy import policy_from_checkpoint

            data = load_policy_file(args.policy)
            policy_env = stored_env_config(data, args.policy)
            if policy_env.obs_mode != "groundtruth":
                raise ConfigError(f"--policy {args.policy}: a '{policy_env.obs_mode}' policy; recording needs "
                                  "a 'groundtruth' one (it reads the true ball positions)")
            # the policy acts on the recording env's ground-truth view: the balls shown as it was trained
            check_policy_fits(data, replace(env, obs_mode="groundtruth"), args.policy)
            policy = policy_from_checkpoint(data, args.policy)
        baoding_data.generate(cfg, args.out, progress=progress, policy=policy)
    else:
        grasp_cfg = grasp_data.GraspDataConfig(samples=args.samples, shard_size=args.shard_size, seed=args.seed,
                                               grasp=_config(GraspConfig, args, object=args.object))
        grasp_data.generate(grasp_cfg, args.out, progress=progress)
    print(f"dataset complete: {args.out} ({args.samples} samples)")
    return 0


def cmd_train_perception(args) -> int:
    from tacgnn.perception.train_config import PerceptionTrainConfig
    from tacgnn.perception.training import train

    if args.temporal or args.by_episode:
        return _train_sequence_perception(args)
    if args.window is not None or args.burn_in is not None:
        raise ConfigError("--window and --burn-in go with --temporal")
    cfg = PerceptionTrainConfig.for_task(args.task, args.model, epochs=args.epochs, seed=args.seed,
                                         max_samples=args.max_samples,
                                         model_kw={"channels": args.channels} if args.channels else {})
    if args.set:
        cfg = override(cfg, parse_overrides(args.set))
    final = train(cfg, args.dataset, args.run, resume=args.resume)
    print("final:", {k: round(v, 4) for k, v in final.items() if isinstance(v, float)})
    return 0


def _train_sequence_perception(args) -> int:
    """train-perception --temporal / --by-episode: windows of episodes (tacgnn.perception.sequence_training)."""
    from tacgnn.perception.models.temporal import TemporalModelConfig
    from tacgnn.perception.sequence_train_config import SequenceTrainConfig
    from tacgnn.perception.sequence_training import train_sequence
    from tacgnn.perception.train_config import default_model_config

    if args.task != "baoding":
        raise ConfigError(f"--temporal/--by-episode train on Baoding sequences (--task baoding), not {args.task!r}")
    if args.temporal and args.by_episode:
        raise ConfigError("--temporal and --by-episode exclude each other (--by-episode is the single-frame model)")
    if args.by_episode and (args.window is not None or args.burn_in is not None):
        raise ConfigError("--window and --burn-in go with --temporal")
    frame = default_model_config(name=args.model, **({"channels": args.channels} if args.channels else {}))
    given = {"window": args.window, "burn_in": args.burn_in}
    batch: dict[str, Any] = {} if args.temporal else {"batch_size": 32}
    cfg = SequenceTrainConfig(model=TemporalModelConfig(frame=frame), temporal=args.temporal, epochs=args.epochs,
                              seed=args.seed, max_frames=args.max_samples, **batch,
                              **{k: v for k, v in given.items() if v is not None})
    if args.set:
        cfg = override(cfg, parse_overrides(args.set))
    final = train_sequence(cfg, args.dataset, args.run, resume=args.resume)
    print("final:", {k: round(v, 4) for k, v in final.items() if isinstance(v, float)})
    return 0


def cmd_eval_perception(args) -> int:
    from tacgnn.datasets.store import read_manifest
    from tacgnn.perception.evaluation import evaluate, patch_loss, patch_taxels
    from tacgnn.perception.sequence_checkpoint import is_sequence_checkpoint

    if is_sequence_checkpoint(args.checkpoint):  # temporal or --by-episode: whole test episodes
        from tacgnn.perception.sequence_evaluation import evaluate_sequence

        if args.lose_patch or args.dead != [0.0]:
            raise ConfigError(f"{args.checkpoint}: --dead and --lose-patch take single-frame checkpoints")
        metrics = evaluate_sequence(args.checkpoint, args.dataset, whole=args.whole)
        print(", ".join(f"{k} {v:.4f}" for k, v in metrics.items()))
        return 0
    for patch in args.lose_patch:  # an unknown patch name fails before any evaluation
        patch_taxels(read_manifest(args.dataset)["metadata"]["skin"], patch)
    for dead in args.dead:
        metrics = evaluate(args.checkpoint, args.dataset, dead_fraction=dead, seed=args.seed, whole=args.whole)
        print(f"dead taxels {dead:.0%}: " + ", ".join(f"{k} {v:.4f}" for k, v in metrics.items()))
    for patch in args.lose_patch:
        metrics = patch_loss(args.checkpoint, args.dataset, patch, whole=args.whole)
        print(f"without the {patch}: position_rmse_cm {metrics[f'position_rmse_cm_without_{patch}']:.4f} "
              f"(intact {metrics['position_rmse_cm']:.4f}, ratio {metrics['rmse_ratio']:.2f})")
    return 0


def cmd_train_policy(args) -> int:
    from tacgnn.learning import train

    return train.main(args.rest, parser_class=_Parser)


def cmd_evaluate(args) -> int:
    from tacgnn.learning import evaluate

    return evaluate.main(args.rest, parser_class=_Parser)


def _per_joint_arg(values: list[float], name: str):
    if len(values) not in (1, 16):
        raise ConfigError(f"--{name} takes 1 value or 16 per-joint values, got {len(values)}")
    return values[0] if len(values) == 1 else tuple(values)


def _gain_override(value) -> str:
    return repr(float(value)) if not isinstance(value, tuple) else "[" + ",".join(f"{v:g}" for v in value) + "]"


def cmd_sysid(args) -> int:
    """Identify per-joint stiffness/damping from a recording, or make a simulated recording."""
    from dataclasses import replace

    from tacgnn.envs.baoding import BAODING_RANGES, BaodingConfig
    from tacgnn.real import sysid
    from tacgnn.real.joint_recording import load_recording, save_recording

    grid = sysid.SysIdGrid(tuple(args.stiffness), tuple(args.damping))
    cfg = sysid.SysIdConfig(grid=grid, refine_passes=args.refine_passes)
    if args.set:
        cfg = override(cfg, parse_overrides(args.set))
    if args.make_recording:
        protocol = sysid.StepProtocol(tuple(args.levels_deg), args.hold_steps, sequential=args.sequential)
        if args.random_truth:
            rng = np.random.default_rng(args.seed)
            pairs = grid.candidates()[rng.integers(len(grid.candidates()), size=16)]
            true_k, true_d = tuple(pairs[:, 0]), tuple(pairs[:, 1])
        else:
            true_k = _per_joint_arg(args.true_stiffness, "true-stiffness")
            true_d = _per_joint_arg(args.true_damping, "true-damping")
        rec = sysid.make_recording(true_k, true_d, protocol, cfg.hand, cfg.sim, args.noise_deg, args.seed)
        path = save_recording(rec, args.make_recording)
        print(f"wrote {path}: {rec.num_samples} samples at {1 / rec.period:.0f} Hz, noise {args.noise_deg} deg, "
              f"true stiffness {_gain_override(true_k)}, damping {_gain_override(true_d)}")
        print(f"identify it with: tacgnn sysid {path}")
        return 0
    if not args.recording:
        raise ConfigError("sysid needs a recording file (or --make-recording PATH to make one in simulation)")
    rec = load_recording(args.recording)
    start = time.perf_counter()
    result = sysid.identify(rec, cfg)
    print(f"{rec.source}: {rec.num_samples} samples, grid {len(grid.stiffness)} x {len(grid.damping)}, "
          f"{result.passes} simulation passes ({time.perf_counter() - start:.1f} s)")
    print(sysid.summary(result, rec))
    refined = None
    if args.refine:
        from tacgnn.real.sysid_refine import refine, refine_summary

        start = time.perf_counter()
        refined = refine(rec, result.stiffness, result.damping, cfg)
        print(f"refined off the grid by least squares (mujoco.sysid, {time.perf_counter() - start:.0f} s):")
        print(refine_summary(refined, rec))
    base = replace(cfg.hand, joint_ranges=BAODING_RANGES)  # the task's ranges; the replay used the full ones
    hand_path, report_path = sysid.write_outputs(result, rec, args.out, base, refined)
    hand = load_yaml(BaodingConfig, hand_path).hand
    print(f"wrote {hand_path} (hand config for --config) and {report_path} (error tables)")
    print("train with the identified hand and domain randomisation:\n  tacgnn train-policy --run-dir runs/dr --env "
          f"randomization.enabled=true 'hand.stiffness={_gain_override(hand.stiffness)}' "
          f"'hand.damping={_gain_override(hand.damping)}'")
    return 0


def cmd_calibrate_skin(args) -> int:
    """Skin calibration from rest frames; report dead and never-activated taxels."""
    from tacgnn.real.skin import CalibrationError, SkinProcessor, calibrate, load_raw_frames, patch_gain_from_load

    rest = load_raw_frames(args.rest)
    calib = calibrate(rest, sigmas=args.sigmas, min_threshold=args.min_threshold, gain=args.gain)
    if args.load:
        if not (args.load_patch and args.load_newtons):
            raise CalibrationError("--load needs --load-patch and --load-newtons")
        calib = patch_gain_from_load(calib, load_raw_frames(args.load), args.load_patch, args.load_newtons)
    processor = SkinProcessor(calib)
    dead = np.flatnonzero(calib.dead)
    print(f"{len(rest)} rest frames: mean threshold {calib.threshold.mean():.4g} raw units; "
          f"{len(dead)} dead taxels (always 0){': ' + ', '.join(processor.describe(dead)) if len(dead) else ''}")
    if args.contact:
        quiet = processor.never_active(load_raw_frames(args.contact))
        print(f"{len(quiet)} live taxels never active in {args.contact}"
              f"{': ' + ', '.join(processor.describe(quiet)) if len(quiet) else ''}")
    calib.save(args.out)
    print(f"wrote {args.out}")
    return 0


def cmd_real_hand(args) -> int:
    """ROS nodes for a real hand, or the simulator playing one (tacgnn.real.command)."""
    from tacgnn.real import command

    return command.run(args)


def _fraction(text: str) -> float:
    """argparse type: a number in [0, 1]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1], got {text!r}") from None
    if not 0.0 <= value <= 1.0:  # NaN fails too
        raise argparse.ArgumentTypeError(f"must be a fraction in [0, 1], got {text}")
    return value


def _count(minimum: int):
    """argparse type: an integer >= `minimum`."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        return value

    parse.__name__ = f"integer >= {minimum}"
    return parse


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: the wrong argument and where to look, not the whole usage."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="tacgnn", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--debug", action="store_true",
                        help="show the traceback of an error (taken anywhere in the arguments)")
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
    p.add_argument("--episodes", type=_count(1), default=64)
    p.add_argument("--envs", type=_count(1), default=64)
    p.add_argument("--steps", type=_count(1), default=200, help="scripted: control steps")
    p.add_argument("--video", default="outputs/demo.mp4", help="'' to skip the video")
    p.add_argument("--video-steps", type=_count(1), default=100)
    p = add("render", cmd_render, "write a video of one episode and a skin picture")
    p.add_argument("--out", default="outputs/episode.mp4")
    p.add_argument("--steps", type=_count(1), default=100)
    p.add_argument("--skin-picture", default="outputs/skin.png")
    add("view", cmd_view, "interactive viewer (needs a display)")
    add("config", cmd_config, "print the default config as YAML")
    p = add("make-dataset", cmd_make_dataset, "generate a tactile dataset (resumes if interrupted)")
    p.add_argument("kind", choices=["baoding", "grasp"])
    p.add_argument("--out", required=True)
    p.add_argument("--samples", type=_count(1), default=25_000)
    p.add_argument("--shard-size", type=_count(1), default=5_000)
    p.add_argument("--object", choices=["cube", "cylinder", "meat_can"],
                   help="grasp: the object (default cube); --config/--set take GraspConfig keys for grasps, "
                        "e.g. --set can_face=narrow")
    p.add_argument("--policy", help="baoding: a ground-truth PPO checkpoint drives the balls")
    p.add_argument("--settle-steps", type=_count(0), default=5,
                   help="baoding: skip this many first steps of each episode (0 keeps the dropping balls)")
    p.add_argument("--keep-every", type=_count(1), default=2,
                   help="baoding: record every k-th step of each env; 1 keeps every frame (sequence models)")
    p.add_argument("--envs", type=_count(1), help="baoding: envs stepped together (default 64; fewer give "
                   "longer episodes per shard)")

    p = sub.add_parser("train-perception", help="train a perception model on a dataset")
    p.add_argument("--task", choices=["baoding", "cube", "cylinder", "meat_can"], default="baoding")
    p.add_argument("--model", choices=["tacgnn", "mlp", "cnn", "gcn"], default="tacgnn")
    p.add_argument("--dataset", required=True)
    p.add_argument("--run", required=True, help="run folder: checkpoint, history, TensorBoard")
    p.add_argument("--epochs", type=_count(1), default=10)
    p.add_argument("--channels", type=_count(0), default=0, help="TacGNN channels (16/32/64/128)")
    p.add_argument("--max-samples", type=_count(0), default=0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--resume", action="store_true")
    p.add_argument("--set", nargs="*", metavar="KEY=VALUE", help="override training config keys")
    p.add_argument("--temporal", action="store_true",
                   help="baoding: a GRU over --model's per-frame features, trained on windows of episodes "
                        "(a dataset made with --keep-every 1; split by episode)")
    p.add_argument("--by-episode", action="store_true",
                   help="baoding: the single-frame --model on the same episode split and budget as --temporal")
    p.add_argument("--window", type=_count(1), help="--temporal: frames per window with gradient (default 16)")
    p.add_argument("--burn-in", type=_count(0), help="--temporal: frames before a window that warm the state "
                   "without gradient (default 16)")
    p.set_defaults(fn=cmd_train_perception)

    for name, fn, text in (("train-policy", cmd_train_policy, "train PPO on the Baoding env (see --help)"),
                           ("evaluate", cmd_evaluate, "success rate of a policy on simple/middle/hard")):
        p = sub.add_parser(name, help=text, add_help=False)
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(fn=fn)

    p = sub.add_parser("eval-perception", help="errors of a trained perception model")
    p.add_argument("--checkpoint", required=True)
    p.add_argument("--dataset", required=True)
    p.add_argument("--dead", type=_fraction, nargs="*", default=[0.0], help="fractions of dead taxels, in [0, 1]")
    p.add_argument("--whole", action="store_true", help="use the whole dataset, not its test split")
    p.add_argument("--lose-patch", nargs="*", default=[], metavar="PATCH",
                   help="also report the error with every taxel of these skin patches at 0 (e.g. palm)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(fn=cmd_eval_perception)

    p = sub.add_parser("sysid", help="identify per-joint stiffness/damping from a position-step recording")
    p.add_argument("recording", nargs="?", help=".npz or .csv recording (format: tacgnn.real.joint_recording)")
    p.add_argument("--out", default="outputs/sysid_hand.yaml", help="hand config YAML; the report goes beside it")
    p.add_argument("--stiffness", type=float, nargs="+", default=[1.0, 3.0, 5.0], help="grid of kp (N m/rad)")
    p.add_argument("--damping", type=float, nargs="+", default=[0.0, 0.1, 0.5], help="grid of damping (N m s/rad)")
    p.add_argument("--refine-passes", type=int, default=3, help="passes with the other joints at their best")
    p.add_argument("--refine", action="store_true",
                   help="then fit every joint's gains off the grid (least squares, mujoco.sysid) with 95 %% intervals")
    p.add_argument("--set", nargs="*", metavar="KEY=VALUE", help="SysIdConfig keys, e.g. hand.armature=0.002")
    g = p.add_argument_group("simulated recording (no hardware)")
    g.add_argument("--make-recording", metavar="PATH", help="write a simulated recording (.npz/.csv) and exit")
    g.add_argument("--true-stiffness", type=float, nargs="+", default=[3.0], help="1 or 16 values")
    g.add_argument("--true-damping", type=float, nargs="+", default=[0.1], help="1 or 16 values")
    g.add_argument("--random-truth", action="store_true", help="draw each joint's true pair from the grid")
    g.add_argument("--noise-deg", type=float, default=0.0, help="std of measurement noise (deg)")
    g.add_argument("--levels-deg", type=float, nargs="+", default=[0.0, 15.0, 30.0, 45.0, 60.0])
    g.add_argument("--hold-steps", type=int, default=50)
    g.add_argument("--sequential", action="store_true", help="step one joint at a time")
    g.add_argument("--seed", type=int, default=0)
    p.set_defaults(fn=cmd_sysid)

    p = sub.add_parser("calibrate-skin", help="real skin: baseline, thresholds, gains from rest frames")
    p.add_argument("rest", help=".npz of raw frames at rest (one (N, size) array per patch, or 'raw' (N, 653))")
    p.add_argument("--out", default="outputs/skin_calibration.npz")
    p.add_argument("--sigmas", type=float, default=4.0, help="threshold = sigmas x rest noise std")
    p.add_argument("--min-threshold", type=float, default=0.0, help="lowest threshold (raw units)")
    p.add_argument("--gain", type=float, default=1.0, help="newtons per raw unit for every taxel")
    p.add_argument("--load", help="frames with a known force on one patch: sets that patch's gain")
    p.add_argument("--load-patch", help="the loaded patch, e.g. palm")
    p.add_argument("--load-newtons", type=float, help="the known normal force (N)")
    p.add_argument("--contact", help="frames pressing every patch: report taxels that never activate")
    p.set_defaults(fn=cmd_calibrate_skin)

    p = sub.add_parser("real-hand", help="ROS nodes for a real hand, or the simulator as the hand (ROS 1)")
    from tacgnn.real.command import add_arguments as add_real_hand_arguments

    add_real_hand_arguments(p)
    p.set_defaults(fn=cmd_real_hand)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one sub-command. User errors (wrong file, key or value) print one line on stderr and
    return 2; ``--debug`` (anywhere in the arguments) shows their traceback instead."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    command = argv[0] if argv else ""

    def run() -> int:
        passthrough = {"train-policy": cmd_train_policy, "evaluate": cmd_evaluate}
        if command in passthrough:  # these parse their own flags (--help included)
            return passthrough[command](argparse.Namespace(rest=argv[1:]))
        args = build_parser().parse_args(argv)
        for name in ("video", "out", "skin_picture"):
            value = getattr(args, name, None)
            if value:
                Path(value).parent.mkdir(parents=True, exist_ok=True)
        return args.fn(args)

    return report_user_errors(run, " ".join(["tacgnn", command][:1 + bool(command)]), debug)


if __name__ == "__main__":
    sys.exit(main())
