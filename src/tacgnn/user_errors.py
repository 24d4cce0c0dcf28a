"""What counts as the user's mistake, and how every command reports it: one line, exit code 2.

The `tacgnn` command line and the scripts under ``experiments/`` and ``bench/`` share this, so
that a wrong file, key or value never shows a traceback, wherever it is given.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

from tacgnn.config import ConfigError

# Matched by class name so that a command need not import the modules that define them (they
# load torch and MuJoCo); OSError covers missing, unreadable and unwritable files.
USER_ERRORS = ("ConfigError", "DatasetError", "CheckpointError", "CalibrationError", "RecordingError",
               "RenderingUnavailable", "FileProblem", "SimulationDiverged")


def is_user_error(err: BaseException) -> bool:
    # FloatingPointError: the training guards' stop on a NaN or Inf loss or gradient (weights left
    # as they were, the last checkpoint the one to resume); with the shipped settings it does not
    # happen, so a value given (a learning rate, a loss weight) is the cause.
    return (isinstance(err, (ConfigError, OSError, FloatingPointError))
            or any(c.__name__ in USER_ERRORS for c in type(err).__mro__))


def error_line(err: BaseException) -> str:
    """One line for a user error, naming the file when the exception knows it."""
    text = "; ".join(line.strip() for line in str(err).splitlines() if line.strip()) or type(err).__name__
    filename = getattr(err, "filename", None)
    if isinstance(err, OSError) and filename and (err.strerror or str(filename) not in text):
        text = f"{filename}: {err.strerror or text}"
    return text


def report_user_errors(run: Callable[[], int | None], name: str, debug: bool) -> int:
    """`run()`'s exit code; a user error prints one line on stderr, `name` first, and returns 2
    (with `debug`, its traceback instead); Ctrl-C returns 130."""
    try:
        return run() or 0
    except KeyboardInterrupt:
        if debug:
            raise
        print(f"{name}: interrupted", file=sys.stderr)
        return 130
    except Exception as err:
        if debug or not is_user_error(err):
            raise
        print(f"{name}: {error_line(err)}", file=sys.stderr)
        return 2


def run_script(main: Callable[[], int | None]) -> int:
    """Run a script's `main` as the command line runs a sub-command: a user error prints one
    line on stderr (the script's name first) and returns 2; ``--debug`` among the arguments
    shows the traceback instead. Use: ``raise SystemExit(run_script(main))``."""
    debug = "--debug" in sys.argv
    sys.argv = [a for a in sys.argv if a != "--debug"]
    return report_user_errors(main, Path(sys.argv[0]).name, debug)


def labelled_paths(items: list[str], what: str = "policy") -> list[tuple[str, str]]:
    """``LABEL=PATH`` arguments as (label, path) pairs; the path must exist."""
    pairs = []
    for item in items:
        label, sep, path = item.rpartition("=")
        if not sep or not label or not path:
            raise ConfigError(f"'{item}': a {what} is given as LABEL=PATH")
        if not Path(path).exists():
            raise FileNotFoundError(2, "No such file or directory", path)
        pairs.append((label, path))
    return pairs
