"""What every sub-command shares: the parser with one-line errors and defaults in its help,
argument types, and configs built from --config, --set and a command's own flags."""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from tacgnn.config import ConfigError, check_seed, load_yaml, override, parse_overrides, yaml_load


class HelpWithDefaults(argparse.RawDescriptionHelpFormatter):
    """Every option's help ends with its default, unless the help already states it."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        flag = isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction,
                                   argparse._HelpAction, argparse._StoreConstAction))
        if flag or not action.option_strings or "default" in text or action.default is argparse.SUPPRESS:
            return text
        default = action.default
        if default is None:
            shown = "none"
        elif isinstance(default, (list, tuple)):
            shown = " ".join(str(v) for v in default) or "none"
        else:
            shown = repr(default) if default == "" else str(default)
        return f"{text} (default: {shown.replace('%', '%%')})".strip()


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (the wrong argument and where to look, not the whole usage)
    and every option's default in the help."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", HelpWithDefaults)
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def fraction(text: str) -> float:
    """argparse type: a number in [0, 1]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1], got {text!r}") from None
    if not 0.0 <= value <= 1.0:  # NaN fails too
        raise argparse.ArgumentTypeError(f"must be a fraction in [0, 1], got {text}")
    return value


def count(minimum: int, maximum: int | None = None):
    """argparse type: an integer in minimum..maximum."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum or (maximum is not None and value > maximum):
            bound = f"in {minimum}..{maximum}" if maximum is not None else f">= {minimum}"
            raise argparse.ArgumentTypeError(f"must be {bound}, got {value}")
        return value

    parse.__name__ = f"integer >= {minimum}"
    return parse


def seed(text: str) -> int:
    """argparse type: a seed every config takes (`tacgnn.config.check_seed`)."""
    value = count(0)(text)
    try:
        check_seed(value)
    except ConfigError as err:
        raise argparse.ArgumentTypeError(err.detail or str(err)) from None
    return value


def add_config_options(p: argparse.ArgumentParser, what: str = "BaodingConfig", note: str = "") -> None:
    """--config and --set for `what`'s keys; `note` says how they combine with the command's own."""
    p.add_argument("--config", metavar="FILE.yaml", help=f"YAML file of {what} keys{note} (default: the defaults)")
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                   help=f"change {what} keys, dotted (e.g. task=middle sim.timestep=0.004); an unknown key or a "
                        "bad value stops the command before it runs (default: none)")


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Dotted keys of the leaves of a nested mapping: {'hand': {'stiffness': 2}} -> {'hand.stiffness': 2}."""
    out: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, Mapping) and value:
            out.update(flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def config_updates(cls, args: argparse.Namespace) -> dict[str, Any]:
    """The dotted keys --config sets (the file checked as a whole `cls` first), then --set's."""
    updates: dict[str, Any] = {}
    if getattr(args, "config", None):
        load_yaml(cls, args.config)  # names a missing file, bad YAML, an unknown key or a bad value
        updates.update(flatten(yaml_load(Path(args.config).read_text()) or {}))
    updates.update(parse_overrides(getattr(args, "set", None) or []))
    return updates


def build_config(cls, args: argparse.Namespace, **given):
    """`cls` from --config (YAML) or its defaults, then --set, then the keys of the command's
    own flags `given` (None = flag not given), which win."""
    cfg = load_yaml(cls, args.config) if getattr(args, "config", None) else cls()
    updates = {**parse_overrides(getattr(args, "set", None) or []),
               **{k: v for k, v in given.items() if v is not None}}
    return override(cfg, updates) if updates else cfg


def baoding_config(args: argparse.Namespace):
    from tacgnn.envs.baoding import BaodingConfig

    return build_config(BaodingConfig, args, num_envs=getattr(args, "envs", None) or None,
                        seed=getattr(args, "seed", None))
