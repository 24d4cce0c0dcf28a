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
import re
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import yaml

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

T = TypeVar("T", bound="DataclassInstance")  # a config dataclass


class ConfigError(ValueError):
    """A configuration key or value is wrong; the message names it.

    `key` (dotted) and `detail` are kept when known, so that a config nested in another
    can report the full key (``env.num_envs``, not ``num_envs``).
    """

    def __init__(self, message: str, key: str | None = None, detail: str | None = None):
        super().__init__(message)
        self.key, self.detail = key, detail


def _key_error(key: str, detail: str) -> ConfigError:
    return ConfigError(f"config key '{key}': {detail}", key=key, detail=detail)


def check(condition: bool, key: str, message: str) -> None:
    """Raise `ConfigError` for `key` unless `condition` holds."""
    if not condition:
        raise _key_error(key, message)


#: The largest seed a config takes: numpy's legacy seeding stops at 2**32 - 1, and a
#: data-parallel run adds its rank's offset, so the range leaves it room.
MAX_SEED = 2**31 - 1


def check_seed(seed: int, key: str = "seed") -> None:
    """Raise `ConfigError` for `key` unless `seed` is an int in 0..MAX_SEED."""
    check(isinstance(seed, int) and not isinstance(seed, bool) and 0 <= seed <= MAX_SEED, key,
          f"must be an int in 0..{MAX_SEED}, got {seed!r}")


# PyYAML follows YAML 1.1, where a float needs a dot: '1e-4' would load as a string. YAML 1.2
# (and every user) reads it as a number.
class _Loader(yaml.SafeLoader):
    pass


_Loader.add_implicit_resolver("tag:yaml.org,2002:float",
                              re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
                              list("-+0123456789"))


def yaml_load(text: str) -> Any:
    """Parse YAML as the configs expect it (``1e-4`` is a float); raises `yaml.YAMLError`."""
    return yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass


def _yaml_problem(err: yaml.YAMLError) -> str:
    """The first line of a YAML error, without PyYAML's multi-line context."""
    problem = getattr(err, "problem", None) or str(err).strip().splitlines()[0]
    mark = getattr(err, "problem_mark", None)
    return f"{problem} (column {mark.column + 1})" if mark is not None else problem


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
    if isinstance(annotation, type) and dataclasses.is_dataclass(annotation):
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
        try:
            number = float(value)
        except OverflowError:
            number = math.inf
        check(math.isfinite(number), key, f"must be finite, got {value!r}")
        return number
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
    missing = [name for name, f in fields.items() if name not in kwargs
               and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    if missing:
        raise _key_error(prefix.rstrip(".") or cls.__name__, f"missing keys {missing}")
    try:
        return cls(**kwargs)
    except ConfigError as err:
        if err.key is None or not prefix:
            raise
        raise _key_error(_nested_key(prefix, err.key), err.detail or str(err)) from None
    except (ValueError, TypeError, ArithmeticError) as err:
        # configs that validate with plain exceptions (e.g. "channels must be a positive int")
        word, _, rest = str(err).partition(" ")
        field = re.split(r"[^A-Za-z0-9_]", word)[0]
        if field in fields and rest:
            raise _key_error(f"{prefix}{field}", rest if word == field else str(err)) from err
        raise _key_error(prefix.rstrip(".") or cls.__name__, str(err)) from err


def _nested_key(prefix: str, key: str) -> str:
    """The full key of a nested config's `key`: 'env.' + 'num_envs' -> 'env.num_envs'.

    Configs name some keys from their usual parent ('hand.stiffness'); those are joined
    where the parent already appears ('grasp.hand.' + 'hand.stiffness' -> 'grasp.hand.stiffness').
    """
    parts, first = prefix.rstrip(".").split("."), key.split(".")[0]
    for i in range(len(parts) - 1, -1, -1):
        if parts[i] == first:
            return ".".join(parts[:i] + [key])
    return ".".join(parts + [key])


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
    try:
        data = yaml_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ConfigError(f"config file {path}: not valid YAML: {_yaml_problem(err)}") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"config file {path}: cannot read it ({err})") from None
    if not isinstance(data, Mapping):
        raise ConfigError(f"config file {path}: expected a mapping of config keys, got {type(data).__name__}")
    try:
        return from_dict(cls, data)
    except ConfigError as err:
        raise ConfigError(f"config file {path}: {err}", key=err.key, detail=err.detail) from None


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
    try:
        return from_dict(type(config), tree)
    except ConfigError as err:
        raise _named_by_updates(err, type(config).__name__, list(updates)) from None


def _named_by_updates(err: ConfigError, root: str, keys: list[str]) -> ConfigError:
    """`err` naming the given keys when it names only the config they sit in.

    A check that fails with an arithmetic error (e.g. ``round(inf)``) cannot say which field
    it read; the keys the user changed under that config are the ones to look at.
    """
    if err.key is None or err.key in keys:
        return err
    under = [k for k in keys if err.key == root or k.startswith(err.key + ".")]
    if not under:
        return err
    named = ", ".join(f"'{k}'" for k in under)
    return ConfigError(f"config key {named}: {err.detail or err}", key=under[0], detail=err.detail)


def parse_overrides(items: list[str]) -> dict[str, Any]:
    """Parse command-line 'key=value' strings, values as YAML (``1e-4`` a float, ``[1, 2]`` a list)."""
    out = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"override '{item}' must look like key=value")
        key, raw = item.split("=", 1)
        key = key.strip()
        if not key:
            raise ConfigError(f"override '{item}' has no key before '='")
        try:
            out[key] = yaml_load(raw)
        except yaml.YAMLError as err:
            raise _key_error(key, f"cannot parse the value {raw!r}: {_yaml_problem(err)}") from None
    return out
