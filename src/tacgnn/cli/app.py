"""The `tacgnn` command line: one sub-command per user-facing job.

    tacgnn demo                      the shipped TacGNN policy on Simple: success rate and a video
    tacgnn render --out ep.mp4       video of an env (scripted, or --policy FILE) and a skin picture
    tacgnn view                      interactive MuJoCo viewer (needs a display)
    tacgnn config                    print the default Baoding config as YAML
    tacgnn make-dataset baoding --out data/baoding      skin frames + ball positions (HDF5 shards)
    tacgnn make-dataset grasp --object cube --out data/cube   power grasps + object poses
    tacgnn train-perception --task baoding --model tacgnn --dataset data/baoding --run runs/p1
    tacgnn eval-perception --checkpoint runs/p1/checkpoint.pt --dataset data/baoding [--dead 0.1] [--lose-patch palm]
    tacgnn train-policy --run-dir runs/gt --env obs_mode=groundtruth --ppo max_iterations=2000 [--resume]
    tacgnn evaluate runs/gt/model_002000.pt --task middle --episodes 500
    tacgnn robustness runs/gt/model_002000.pt   the policy on hands and skins as real ones differ
    tacgnn export-policy runs/blind/model_000400.pt --out blind.pt [--perception runs/p/best.pt | --ground-truth]
    tacgnn sysid recording.npz --out outputs/sysid_hand.yaml    per-joint stiffness/damping from steps
    tacgnn sysid --make-recording rec.npz --random-truth        a simulated recording to try it on
    tacgnn calibrate-skin rest.npz --out skin_calibration.npz   real skin: baseline, thresholds, gains
    tacgnn real-hand run --calibration skin_calibration.npz     the blind policy on a real hand (ROS)

Config keys are dotted and checked before anything runs (an unknown key or a bad value is
one line): demo, render, view, config and make-dataset take ``--config FILE.yaml`` and
``--set key=value`` (e.g. ``--set task=middle sim.timestep=0.004``); train-perception,
sysid, real-hand and evaluate take ``--set``; train-policy takes ``--env``, ``--ppo`` and
``--perception``; robustness takes none (its rows are the changes). A wrong file, key or value
is reported in one line (exit code 2); ``--debug`` shows the traceback. Every command's
``--help`` lists its options with their defaults.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tacgnn.cli import data, hardware, simulation
from tacgnn.cli.common import Parser
from tacgnn.user_errors import report_user_errors


def cmd_train_policy(args) -> int:
    from tacgnn.learning import train

    return train.main(args.rest, parser_class=Parser)


def cmd_evaluate(args) -> int:
    from tacgnn.learning import evaluate

    return evaluate.main(args.rest, parser_class=Parser)


def cmd_robustness(args) -> int:
    from tacgnn.learning import robustness

    return robustness.main(args.rest, parser_class=Parser)


def cmd_export_policy(args) -> int:
    """A small policy file for acting (the demo, the real hand), optionally with another perception."""
    from tacgnn.files import check_writable
    from tacgnn.learning.policy import export_policy

    check_writable(Path(args.out).parent, "policy folder")
    out = export_policy(args.checkpoint, args.out, perception_from=args.perception, ground_truth=args.ground_truth)
    print(f"policy written: {out} ({out.stat().st_size // 1024} kB)")
    return 0


#: Commands that parse their own flags (--help included).
PASSTHROUGH = {"train-policy": cmd_train_policy, "evaluate": cmd_evaluate, "robustness": cmd_robustness}


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="tacgnn", description=__doc__)
    parser.add_argument("--debug", action="store_true",
                        help="show the traceback of an error (taken anywhere in the arguments)")
    sub = parser.add_subparsers(dest="command", required=True)
    simulation.register(sub)
    data.register(sub)
    for name, fn, text in (("train-policy", cmd_train_policy, "train PPO on the Baoding env (see --help)"),
                           ("evaluate", cmd_evaluate, "success rate of a policy on simple/middle/hard"),
                           ("robustness", cmd_robustness, "a policy on hands and skins that differ as real ones do")):
        p = sub.add_parser(name, help=text, add_help=False)
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(fn=fn)
    p = sub.add_parser("export-policy", help="a small policy file for acting, optionally with another perception")
    p.add_argument("checkpoint", help="a PPO checkpoint (or an exported policy)")
    p.add_argument("--out", required=True, help="the policy file to write")
    p.add_argument("--perception", help="a blind policy acts with this perception checkpoint's weights (the same "
                   "network; e.g. `train-perception --init-from` on the policy's own frames)")
    p.add_argument("--ground-truth", action="store_true", help="a blind policy's actor reading the true ball "
                   "positions instead of its perception's: a ground-truth policy with the blind policy's grip")
    p.set_defaults(fn=cmd_export_policy)
    hardware.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one sub-command. User errors (wrong file, key or value) print one line on stderr and
    return 2; ``--debug`` (anywhere in the arguments) shows their traceback instead."""
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    command = argv[0] if argv else ""

    def run() -> int:
        if command in PASSTHROUGH:
            return PASSTHROUGH[command](argparse.Namespace(rest=argv[1:]))
        args = build_parser().parse_args(argv)
        for name in ("video", "out", "skin_picture"):
            value = getattr(args, name, None)
            if value:
                Path(value).parent.mkdir(parents=True, exist_ok=True)
        return args.fn(args)

    return report_user_errors(run, " ".join(["tacgnn", command][:1 + bool(command)]), debug)
