"""`tacgnn real-hand`: the ROS nodes (controller, recorders, the simulated hand) from the command line.

Light at import (argparse only), so the CLI's parser can be built without ROS, torch or
MuJoCo; each action imports what it needs.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

ACTIONS = ("run", "record-steps", "record-skin", "sim-hand")


def _positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("action", choices=ACTIONS,
                   help="run: the blind controller; record-*: recordings for sysid / calibrate-skin; "
                        "sim-hand: the simulator playing the hand")
    p.add_argument("--ros", type=int, choices=[1, 2], default=1)
    p.add_argument("--set", nargs="*", metavar="KEY=VALUE", help="RosConfig keys, e.g. tactile_topic=/skin")
    p.add_argument("--policy", help="run, sim-hand: policy file (default: the shipped one); sim-hand takes "
                                    "the hand and task config from it")
    p.add_argument("--calibration", help="run: skin calibration from calibrate-skin")
    p.add_argument("--max-step-rad", type=float, default=0.0, help="run: keep targets this close to the pose")
    p.add_argument("--max-target-rate", type=float, default=0.0, help="run: largest target speed (rad/s), 0: none")
    p.add_argument("--duration", type=float, default=0.0, help="run, sim-hand: stop after this many seconds (0: never)")
    p.add_argument("--record", help="run: write the ticks (inputs and commands) to this .bag")
    p.add_argument("--stats", help="run: write the loop's statistics (latency, missed ticks) as JSON here")
    p.add_argument("--out", default="outputs/real_recording.bag",
                   help="record-*: output file (.bag; record-steps also .npz/.csv, record-skin .npz)")
    p.add_argument("--levels-deg", type=float, nargs="+", default=[0.0, 15.0, 30.0, 45.0, 60.0])
    p.add_argument("--hold-steps", type=_positive_int, default=50)
    p.add_argument("--together", action="store_true", help="record-steps: all joints at once (default: one by one)")
    p.add_argument("--frames", type=_positive_int, default=500, help="record-skin: frames to save")
    g = p.add_argument_group("sim-hand")
    g.add_argument("--task", choices=["simple", "middle", "hard"], default="simple")
    g.add_argument("--episodes", type=_positive_int, default=64)
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--latency-ms", type=float, default=20.0, help="delay of every message the hand sends "
                   "(default: %(default)s)")
    g.add_argument("--skin", choices=["real", "ideal"], default="real",
                   help="the skin's signal chain: a resistive array sent raw, or the contact forces (default: real)")
    g.add_argument("--drop-tactile", type=float, default=0.0, help="fraction of skin messages lost")
    g.add_argument("--drop-joint-states", type=float, default=0.0, help="fraction of joint states lost")
    g.add_argument("--stray-joint-states", type=float, default=0.0,
                   help="fraction of steps whose joint state is followed by a malformed one (NaN angles)")
    g.add_argument("--joint-noise-deg", type=float, default=0.0, help="std of noise on the joint angles")
    g.add_argument("--rest-steps", type=int, default=0,
                   help="only publish this many frames of the skin at rest (no balls), then stop")
    g.add_argument("--summary", help="write the episodes' outcomes as JSON here")


def run(args: argparse.Namespace) -> int:
    """Run one action; user errors (bad files, messages, missing ROS) print one line and return 2."""
    from tacgnn.config import override, parse_overrides
    from tacgnn.real.ros_config import RosConfig

    logging.basicConfig(level=logging.INFO, format="[tacgnn] %(message)s")
    cfg = RosConfig(ros_version=args.ros)
    if args.set:
        cfg = override(cfg, parse_overrides(args.set))
    try:
        return _action(args, cfg)
    except (ImportError, ValueError, TimeoutError, OSError) as err:
        from tacgnn.config import ConfigError

        if isinstance(err, ConfigError):
            raise
        print(f"tacgnn real-hand {args.action}: {err}", file=sys.stderr)
        return 2


def _policy(args) -> str:
    from tacgnn.learning.policy import SHIPPED_POLICY

    return str(args.policy or SHIPPED_POLICY)


def _action(args, cfg) -> int:
    from tacgnn.config import ConfigError

    if args.action == "run":
        from tacgnn.real.controller import BlindController, BlindControllerConfig
        from tacgnn.real.controller_node import run_controller
        from tacgnn.real.skin import SkinCalibration, SkinProcessor

        if not args.calibration:
            raise ConfigError("real-hand run needs --calibration (from tacgnn calibrate-skin)")
        calibration = SkinCalibration.load(args.calibration)  # before the networks load: fail fast
        controller = BlindController(BlindControllerConfig(policy=_policy(args), max_step_rad=args.max_step_rad,
                                                           max_target_rate=args.max_target_rate))
        processor = SkinProcessor.for_env(calibration, controller.env_config)
        stats = run_controller(cfg, controller, processor, duration_s=args.duration, record=args.record,
                               stats_path=args.stats)
        print(f"{stats.ticks} ticks, {stats.commands} commands, {stats.missed} missed "
              f"({stats.held} held on stale data, {stats.overruns} overruns), {stats.episodes} episodes; "
              f"malformed messages dropped: {stats.malformed_joint_states} joint states, {stats.malformed_skin} skin")
    elif args.action == "record-steps":
        from tacgnn.hand.allegro import HandConfig
        from tacgnn.real.collect import record_steps
        from tacgnn.real.sysid import StepProtocol

        protocol = StepProtocol(tuple(args.levels_deg), args.hold_steps, sequential=not args.together)
        targets = protocol.targets(HandConfig())
        print(f"commanding {len(targets)} steps ({len(targets) / cfg.rate_hz:.0f} s)")
        print(f"wrote {record_steps(cfg, targets, args.out)}")
    elif args.action == "record-skin":
        from tacgnn.real.collect import record_skin

        print(f"wrote {record_skin(cfg, args.frames, args.out)}")
    else:
        from tacgnn.learning.policy import load_policy
        from tacgnn.real.sim_hand import SimHand, SimHandConfig

        _, env_config = load_policy(_policy(args))
        hand = SimHandConfig(task=args.task, episodes=args.episodes, seed=args.seed, latency_s=args.latency_ms / 1e3,
                             drop_tactile=args.drop_tactile, drop_joint_states=args.drop_joint_states,
                             stray_joint_states=args.stray_joint_states,
                             joint_noise_rad=float(args.joint_noise_deg) * 3.141592653589793 / 180,
                             skin=args.skin, rest_steps=args.rest_steps,
                             duration_s=args.duration)
        summary = SimHand(env_config, hand, cfg).run(args.summary)
        if not args.rest_steps:
            print(f"{summary['episodes']} episodes on {summary['task']}: success {summary['success_rate']:.3f}, "
                  f"falls {summary['fall_rate']:.3f}; {summary['commands_received']} commands received, "
                  f"{summary['late_steps']} late steps; command lag (steps: count) {summary['command_lag_steps']}, "
                  f"state-to-command {summary['response_ms']} ms")
        if args.summary:
            print(f"wrote {Path(args.summary)}")
    return 0
