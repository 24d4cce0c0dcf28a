"""Commands towards a real hand: system identification, skin calibration, the ROS nodes."""

from __future__ import annotations

import time

import numpy as np

from tacgnn.cli.common import count, seed
from tacgnn.config import ConfigError, load_yaml, override, parse_overrides


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


def register(sub) -> None:
    """The sub-commands of this module, with their options."""
    p = sub.add_parser("sysid", help="identify per-joint stiffness/damping from a position-step recording")
    p.add_argument("recording", nargs="?", help=".npz or .csv recording (format: tacgnn.real.joint_recording)")
    p.add_argument("--out", default="outputs/sysid_hand.yaml", help="hand config YAML; the report goes beside it")
    p.add_argument("--stiffness", type=float, nargs="+", default=[1.0, 3.0, 5.0], help="grid of kp (N m/rad)")
    p.add_argument("--damping", type=float, nargs="+", default=[0.0, 0.1, 0.5], help="grid of damping (N m s/rad)")
    p.add_argument("--refine-passes", type=count(0), default=3, help="passes with the other joints at their best")
    p.add_argument("--refine", action="store_true",
                   help="then fit every joint's gains off the grid (least squares, mujoco.sysid) with 95 %% intervals")
    p.add_argument("--set", nargs="*", metavar="KEY=VALUE", help="SysIdConfig keys, e.g. hand.armature=0.002")
    g = p.add_argument_group("simulated recording (no hardware)")
    g.add_argument("--make-recording", metavar="PATH", help="write a simulated recording (.npz/.csv) and exit")
    g.add_argument("--true-stiffness", type=float, nargs="+", default=[3.0], help="1 or 16 values")
    g.add_argument("--true-damping", type=float, nargs="+", default=[0.1], help="1 or 16 values")
    g.add_argument("--random-truth", action="store_true", help="draw each joint's true pair from the grid")
    g.add_argument("--noise-deg", type=float, default=0.0, help="std of measurement noise (deg)")
    g.add_argument("--levels-deg", type=float, nargs="+", default=[0.0, 15.0, 30.0, 45.0, 60.0],
                   help="step targets (deg)")
    g.add_argument("--hold-steps", type=count(1), default=50, help="control steps each level is held")
    g.add_argument("--sequential", action="store_true", help="step one joint at a time")
    g.add_argument("--seed", type=seed, default=0, help="noise and --random-truth")
    p.set_defaults(fn=cmd_sysid)

    p = sub.add_parser("calibrate-skin", help="real skin: baseline, thresholds, gains from rest frames")
    p.add_argument("rest", help=".npz of raw frames at rest (one (N, size) array per patch, or 'raw' (N, 653))")
    p.add_argument("--out", default="outputs/skin_calibration.npz", help="calibration file")
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
