"""Sharded HDF5 datasets that survive a kill and refuse to load when corrupt.

A dataset is a folder:

    manifest.json        schema, metadata (skin layout, object, seed, code version) and,
                         per finished shard, its file name, sample count and SHA-256
    shard_00000.h5 ...   one HDF5 file per shard, every field a chunked array

Each shard is written to a temporary file and renamed into place, then recorded in the
manifest, which is itself replaced atomically; a killed writer leaves only finished
shards behind. Shard i is generated from seed (seed, i), so resuming regenerates only
the missing shards and the result equals an uninterrupted run. Reading checks each
shard's checksum and the fields against the schema, and raises `DatasetError` naming
the file and the problem.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import h5py
import numpy as np

FORMAT_VERSION = 1


class DatasetError(RuntimeError):
    """A dataset is missing, corrupt, or not what the caller expects."""


@dataclass(frozen=True)
class Field:
    """One per-sample array of the schema: its shape (without the sample axis) and dtype."""

    shape: tuple[int, ...]
    dtype: str = "float32"


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _differences(old, new, prefix: str = "") -> tuple[list[tuple[str, object, object]], list[str]]:
    """(changed, added): dotted keys whose values differ, and keys only `new` has."""
    if isinstance(old, dict) and isinstance(new, dict):
        changed: list = []
        added: list = []
        for key in new:
            path = f"{prefix}{key}"
            if key not in old:
                added.append(path)
                continue
            c, a = _differences(old[key], new[key], f"{path}.")
            changed += c
            added += a
        changed += [(f"{prefix}{key}", old[key], None) for key in old if key not in new]
        return changed, added
    return ([(prefix.rstrip("."), old, new)] if old != new else []), []


def _atomic_write_text(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


class ShardedWriter:
    """Writes a dataset shard by shard; `generate_missing` resumes an interrupted run.

    Args:
        root: the dataset folder (created).
        schema: field name -> Field.
        metadata: anything JSON-serialisable that identifies the data (skin, object, seed...).
            Resuming into a folder whose metadata differs raises `DatasetError`.
        num_shards, shard_size: the dataset holds num_shards * shard_size samples.
    """

    def __init__(self, root: str | Path, schema: dict[str, Field], metadata: dict,
                 num_shards: int, shard_size: int):
        self.root = Path(root)
        self.schema = schema
        self.root.mkdir(parents=True, exist_ok=True)
        for stale in self.root.glob(".shard_*"):  # temp files of a killed writer
            stale.unlink()
        self.manifest_path = self.root / "manifest.json"
        header = {"format_version": FORMAT_VERSION, "metadata": metadata, "num_shards": num_shards,
                  "shard_size": shard_size,
                  "schema": {k: {"shape": list(f.shape), "dtype": f.dtype} for k, f in schema.items()}}
        if self.manifest_path.exists():
            manifest = read_manifest(self.root)
            old = {k: manifest[k] for k in header}
            changed, added = _differences(old, json.loads(json.dumps(header)))
            if changed:
                shown = "; ".join(f"{key}: {a!r} there, {b!r} now" for key, a, b in changed[:5])
                raise DatasetError(f"{self.manifest_path}: the existing dataset was made with other settings "
                                   f"({shown}{'; ...' if len(changed) > 5 else ''}); use another folder or "
                                   "delete it")
            # config keys added to the code since (their defaults keep the old behaviour) do not
            # make the shards already written different
            self.manifest = manifest
        else:
            self.manifest = {**header, "shards": {}}
            _atomic_write_text(self.manifest_path, json.dumps(self.manifest, indent=1))

    def missing(self) -> list[int]:
        """Shard indices not yet written (or whose file is gone)."""
        done = {int(i) for i, s in self.manifest["shards"].items() if (self.root / s["file"]).exists()}
        return [i for i in range(self.manifest["num_shards"]) if i not in done]

    def write_shard(self, index: int, arrays: dict[str, np.ndarray]) -> None:
        """Write shard `index` atomically and record it in the manifest."""
        n = self.manifest["shard_size"]
        for name, spec in self.schema.items():
            if name not in arrays:
                raise DatasetError(f"shard {index}: field '{name}' missing")
            a = arrays[name]
            if a.shape != (n, *spec.shape):
                raise DatasetError(f"shard {index}: field '{name}' has shape {a.shape}, expected {(n, *spec.shape)}")
            if not np.isfinite(a).all():
                raise DatasetError(f"shard {index}: field '{name}' holds NaN or Inf")
        name = f"shard_{index:05d}.h5"
        fd, tmp = tempfile.mkstemp(dir=self.root, prefix=f".{name}.")
        os.close(fd)
        with h5py.File(tmp, "w") as h5:
            for key, spec in self.schema.items():
                chunk = (min(n, 1024), *spec.shape)
                h5.create_dataset(key, data=arrays[key].astype(spec.dtype), chunks=chunk)
        os.replace(tmp, self.root / name)
        self.manifest["shards"][str(index)] = {"file": name, "samples": n, "sha256": _sha256(self.root / name)}
        _atomic_write_text(self.manifest_path, json.dumps(self.manifest, indent=1))

    def generate_missing(self, make_shard: Callable[[int], dict[str, np.ndarray]],
                         progress: Callable[[Iterator[int]], Iterator[int]] | None = None) -> int:
        """Generate and write every missing shard; returns how many were written."""
        todo = self.missing()
        for index in (progress(todo) if progress else todo):
            self.write_shard(index, make_shard(index))
        return len(todo)


def read_manifest(root: str | Path) -> dict:
    path = Path(root) / "manifest.json"
    if not path.is_file():
        raise DatasetError(f"{path}: no dataset manifest (generate the dataset first)")
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise DatasetError(f"{path}: manifest is not valid JSON ({err})") from None
    if manifest.get("format_version") != FORMAT_VERSION:
        raise DatasetError(f"{path}: format version {manifest.get('format_version')}, "
                           f"this code reads {FORMAT_VERSION}")
    return manifest


def load(root: str | Path, fields: list[str] | None = None, expect: dict | None = None) -> dict[str, np.ndarray]:
    """Read a complete dataset into memory, verifying checksums and schema.

    Args:
        fields: which fields (default all).
        expect: metadata entries that must match (e.g. {"num_taxels": 653}); a mismatch
            raises `DatasetError` naming the key.
    """
    root = Path(root)
    manifest = read_manifest(root)
    for key, value in (expect or {}).items():
        have = manifest["metadata"].get(key)
        if have != value:
            raise DatasetError(f"{root}: metadata '{key}' is {have!r}, expected {value!r}")
    missing = [i for i in range(manifest["num_shards"]) if str(i) not in manifest["shards"]]
    if missing:
        raise DatasetError(f"{root}: incomplete, shards {missing[:10]} missing (resume the generation)")
    schema = manifest["schema"]
    fields = fields or list(schema)
    unknown = [f for f in fields if f not in schema]
    if unknown:
        raise DatasetError(f"{root}: no fields {unknown}; it has {list(schema)}")
    parts: dict[str, list[np.ndarray]] = {f: [] for f in fields}
    for i in range(manifest["num_shards"]):
        entry = manifest["shards"][str(i)]
        path = root / entry["file"]
        if not path.is_file():
            raise DatasetError(f"{path}: shard file missing")
        if _sha256(path) != entry["sha256"]:
            raise DatasetError(f"{path}: checksum mismatch, the file is corrupt")
        with h5py.File(path, "r") as h5:
            for f in fields:
                if f not in h5:
                    raise DatasetError(f"{path}: field '{f}' missing")
                a = h5[f][...]
                if a.shape != (entry["samples"], *schema[f]["shape"]):
                    raise DatasetError(f"{path}: field '{f}' has shape {a.shape}")
                parts[f].append(a)
    return {f: np.concatenate(v) for f, v in parts.items()}
