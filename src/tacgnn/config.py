"""Typed, validated configuration.

Every config in tacgnn is a frozen dataclass. `from_dict` builds one from a plain
mapping (e.g. parsed YAML) and rejects unknown keys and wrongly typed values with
an error that names the key, so that a typo fails at load time, never mid-run.
Dataclasses validate their own value ranges in ``__post_init__`` via `check`.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import types
import typing
from pathlib import Path
from typing import Any, Mapping, TypeVar

import yaml

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration key or value is wrong; the message names it."""


def check(condition: bool, key: str, message: str) -> None:
    """Raise `ConfigError` for `key` unless `condition` holds."""
    if not condition:
        raise ConfigError(f"config key '{key}': {message}")


def _coerce(value: Any, annotation: Any, key: str) -> Any:
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if annotation is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, key)
            except ConfigError as err:
                errors.append(str(err))
        raise ConfigError(errors[0] if errors else f"config key '{key}': bad value {value!r}")
    if origin is typing.Literal:
        check(value in args, key, f"must be one of {list(args)}, got {value!r}")
        return value
    if dataclasses.is_dataclass(annotation):
        if isinstance(value, annotation):
            return value
        check(isinstance(value, Mapping), key, f"expected a mapping, got {type(value).__name__}")
        return from_dict(annotation, value, prefix=f"{key}.")
    if origin is tuple:
        check(isinstance(value, (list, tuple)), key, f"expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{key}[{i}]") for i, v in enumerate(value))
        check(len(value) == len(args), key, f"expected {len(args)} values, got {len(value)}")
        return tuple(_coerce(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if annotation is float:
        check(isinstance(value, (int, float)) and not isinstance(value, bool), key,
              f"expected a number, got {value!r}")
        check(math.isfinite(value), key, f"must be finite, got {value!r}")
        return float(value)
    if annotation is int:
        check(isinstance(value, int) and not isinstance(value, bool), key,
              f"expected an integer, got {value!r}")
        return value
    if annotation is bool:
        check(isinstance(value, bool), key, f"expected true/false, got {value!r}")
        return value
    if annotation is str:
        check(isinstance(value, str), key, f"expected a string, got {value!r}")
        return value
    return value


def from_dict(cls: type[T], data: Mapping[str, Any], prefix: str = "") -> T:
    """Build dataclass `cls` from `data`, naming any unknown or mistyped key."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"config '{prefix or cls.__name__}': expected a mapping")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    kwargs = {}
    for key, value in data.items():
        if key not in fields:
            close = difflib.get_close_matches(str(key), list(fields), n=1)
            hint = f" (did you mean '{prefix}{close[0]}'?)" if close else ""
            raise ConfigError(f"unknown config key '{prefix}{key}' for {cls.__name__}{hint}")
        kwargs[key] = _coerce(value, hints[key], f"{prefix}{key}")
    return cls(**kwargs)


def to_dict(config: Any) -> dict:
    """A plain, YAML-friendly dict of a config dataclass (tuples become lists)."""

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (tuple, list)):
            return [plain(x) for x in v]
        return v

    return plain(config)


def load_yaml(cls: type[T], path: str | Path) -> T:
    """Read a YAML file into config class `cls`."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    with path.open() as fh:
        data = yaml.safe_load(fh) or {}
    return from_dict(cls, data)


def override(config: T, updates: Mapping[str, Any]) -> T:
    """A copy of `config` with dotted-key `updates` applied (e.g. {'sim.timestep': 0.004})."""
    tree = to_dict(config)
    for dotted, value in updates.items():
        node = tree
        parts = dotted.split(".")
        for i, part in enumerate(parts):
            if part not in node or (i < len(parts) - 1 and not isinstance(node[part], dict)):
                close = difflib.get_close_matches(part, list(node), n=1)
                hint = f" (did you mean '{'.'.join(parts[:i] + close[:1])}'?)" if close else ""
                raise ConfigError(f"unknown config key '{dotted}'{hint}")
            if i < len(parts) - 1:
                node = node[part]
        node[parts[-1]] = value
    return from_dict(type(config), tree)


def parse_overrides(items: list[str]) -> dict[str, Any]:
    """Parse command-line 'key=value' strings, values as YAML scalars."""
    out = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"override '{item}' must look like key=value")
        key, raw = item.split("=", 1)
        out[key.strip()] = yaml.safe_load(raw)
    return out
