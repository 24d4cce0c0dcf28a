"""Where a result file comes from: the checkpoint's hash, the code's commit, the seed, the config.

Every result file tacgnn writes carries `provenance(...)`, so a number in the report can be
traced to the exact weights and code that produced it and rerun.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import subprocess
import sys
from pathlib import Path
from typing import Any

#: The checkout this package runs from (an editable install): its files are recorded relative to it.
CHECKOUT = Path(__file__).resolve().parents[2]


def recorded_path(path: str | Path) -> str:
    """`path` as a result file records it: relative to the checkout when the file lies in it (the same
    in every clone and worktree), else as given."""
    try:
        return str(Path(path).resolve().relative_to(CHECKOUT))
    except ValueError:
        return str(path)


def file_sha256(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def code_commit() -> str:
    """The git commit of the checkout this package runs from ('+dirty' with local changes), or
    'unknown' outside a git checkout."""
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=CHECKOUT, capture_output=True, text=True,
                                timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "src"], cwd=CHECKOUT,
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return commit + ("+dirty" if dirty else "")


def provenance(checkpoints: dict[str, str | Path], seed: int | None, config: dict[str, Any] | None) -> dict[str, Any]:
    """The provenance block of a result file: named checkpoints (`recorded_path`) with their SHA-256,
    the commit, the seed, the config, the command line and the UTC date."""
    return {
        "checkpoints": {name: {"path": recorded_path(path), "sha256": file_sha256(path)}
                        for name, path in checkpoints.items() if path is not None and Path(path).is_file()},
        "commit": code_commit(),
        "seed": seed,
        "config": config,
        "command": " ".join(["tacgnn", *sys.argv[1:]]) if Path(sys.argv[0]).name == "tacgnn" else " ".join(sys.argv),
        "date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
    }
