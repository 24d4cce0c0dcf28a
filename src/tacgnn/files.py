"""Writing and reading the files tacgnn produces: one place for atomic writes and checkpoints.

Every file a long job writes (checkpoints, dataset shards, manifests, result files) goes
through `atomic_write`: a temp file in the same folder, fsync, then `os.replace`, so a
killed job leaves either the old file or the new one, never half of one. Temp files are
named `.<name>.<pid>.tmp`; `remove_stale_temp_files` clears those of killed writers.
Checkpoints are read only through `read_weights` (``torch.load(weights_only=True)``: no
code runs from a file).
"""

from __future__ import annotations

import errno
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

TEMP_SUFFIX = ".tmp"


class FileProblem(OSError):
    """A file could not be written or read; the message names the file and the reason."""


def temp_path(path: Path) -> Path:
    """The temp file `atomic_write` uses for `path` in this process."""
    return path.with_name(f".{path.name}.{os.getpid()}{TEMP_SUFFIX}")


def atomic_write(path: str | Path, write: Callable[[IO[bytes]], Any]) -> None:
    """Write `path` through a temp file in the same directory, fsync it, then rename over.

    Disk full and unwritable folders raise `FileProblem` naming the file.
    """
    path = Path(path)
    tmp = temp_path(path)
    try:
        with open(tmp, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as err:
        raise FileProblem(f"cannot write {path}: {_reason(err)}") from err
    except RuntimeError as err:  # torch.save reports a full disk as RuntimeError
        if "enforce fail" in str(err) or "No space" in str(err) or "file write failed" in str(err):
            raise FileProblem(f"cannot write {path}: disk full or write failed") from err
        raise
    finally:
        tmp.unlink(missing_ok=True)


def atomic_write_text(path: str | Path, text: str) -> None:
    """`atomic_write` of a UTF-8 text."""
    atomic_write(path, lambda fh: fh.write(text.encode()))


def check_writable(folder: str | Path, what: str = "folder") -> Path:
    """Create `folder` if needed and prove a file can be written in it, before a job runs.

    A job that finds out at its end (or in a logging thread) that its output folder is read
    only has wasted its run; raises `FileProblem` naming the folder instead.
    """
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = temp_path(folder / ".write-probe")
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        raise FileProblem(f"cannot write in the {what} {folder}: {_reason(err)}") from err
    return folder


def remove_stale_temp_files(folder: str | Path) -> list[Path]:
    """Delete temp files of writers that no longer run (killed mid-write); return them."""
    removed = []
    for tmp in Path(folder).glob(f".*{TEMP_SUFFIX}"):
        parts = tmp.name[1:-len(TEMP_SUFFIX)].rsplit(".", 1)
        if len(parts) != 2 or not parts[1].isdigit():
            continue
        pid = int(parts[1])
        if pid != os.getpid() and _alive(pid):
            continue
        tmp.unlink(missing_ok=True)
        removed.append(tmp)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _foreign_kind(path: Path) -> str:
    """What `path` is when it cannot be a torch file ('' when it may be one).

    torch.save writes a zip archive (or, long ago, a pickle); anything else fails inside
    torch.load with messages such as '101' or 'pop from empty list'.
    """
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if head.startswith(b"PK\x03\x04") or head[:1] == b"\x80":
        return ""
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        return "not a torch file"
    if path.suffix.lower() in (".yaml", ".yml") or re.match(r"\s*[\w.-]+\s*:", text):
        return "a YAML or text file"
    return "a text file"


def _reason(err: OSError) -> str:
    if err.errno == errno.ENOSPC:
        return "disk full"
    if err.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return "folder not writable"
    return err.strerror or type(err).__name__


def read_weights(path: str | Path, what: str) -> Any:
    """``torch.load(path, weights_only=True)`` on the CPU, with one-line errors naming the file.

    Raises FileNotFoundError for a missing file and `FileProblem` for an empty, truncated
    or foreign one.
    """
    import torch

    path = Path(path)
    if path.is_dir():
        raise FileProblem(f"{path} is a folder, not a {what} (give the .pt file in it)")
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    if path.stat().st_size == 0:
        raise FileProblem(f"cannot read {what} {path}: the file is empty")
    kind = _foreign_kind(path)
    if kind:
        raise FileProblem(f"{path} is {kind}, not a {what} (a .pt file written by tacgnn)")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # truncated zip, bad pickle, foreign objects...
        text = str(err).strip()
        first_line = text.splitlines()[0] if text else type(err).__name__
        raise FileProblem(f"cannot read {what} {path} (truncated or corrupt?): {first_line}") from err
