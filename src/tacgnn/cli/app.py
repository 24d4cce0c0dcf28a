"""The parser of every sub-command and `main`, which runs one and reports a user's mistake in one line."""

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


#: Commands that parse their own flags (--help included).
PASSTHROUGH = {"train-policy": cmd_train_policy, "evaluate": cmd_evaluate}


def build_parser() -> argparse.ArgumentParser:
    import tacgnn.cli

    parser = Parser(prog="tacgnn", description=tacgnn.cli.__doc__)
    parser.add_argument("--debug", action="store_true",
                        help="show the traceback of an error (taken anywhere in the arguments)")
    sub = parser.add_subparsers(dest="command", required=True)
    simulation.register(sub)
    data.register(sub)
    for name, fn, text in (("train-policy", cmd_train_policy, "train PPO on the Baoding env (see --help)"),
                           ("evaluate", cmd_evaluate, "success rate of a policy on simple/middle/hard")):
        p = sub.add_parser(name, help=text, add_help=False)
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(fn=fn)
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
