"""Sharded HDF5 datasets that survive a kill and refuse to load when corrupt.

A dataset is a folder:

    manifest.json        schema, metadata (skin layout, object, seed, code version) and,
                         per finished shard, its file name, sample count and SHA-256
    shard_00000.h5 ...   one HDF5 file per shard, every field a chunked array

Each shard is written through `tacgnn.files.atomic_write` (a temp file renamed into
place), then recorded in the manifest, which is replaced the same way; a killed writer
leaves only finished shards behind, and the next writer removes its temp files. Shard i
is generated from seed (seed, i), so a rerun regenerates only the shards that are missing
or fail verification (checksum, HDF5 structure, schema) and the result equals an
uninterrupted run. Reading runs the same checks, refuses NaN and Inf values, and raises
`DatasetError` naming the file and the problem.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from tacgnn.files import atomic_write, atomic_write_text, remove_stale_temp_files

FORMAT_VERSION = 1
log = logging.getLogger(__name__)
# temp files of the writer before `atomic_write` (tempfile.mkstemp names), left by killed runs
_OLD_TEMP = re.compile(r"^\.(manifest\.json|shard_\d{5}\.h5)\.[A-Za-z0-9_]{8}$")


class DatasetError(RuntimeError):
    """A dataset is missing, corrupt, or not what the caller expects."""


class DamagedManifest(DatasetError):
    """The manifest cannot be read: not JSON, or lacking the keys of one (a rerun rebuilds it)."""


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


def _read_shard(path: Path, entry: dict, schema: dict, fields: list[str]) -> dict[str, np.ndarray]:
    """The `fields` of one shard, checked: checksum, HDF5 structure, shapes, finite values.

    Raises `DatasetError` naming the file and what is wrong with it.
    """
    if not path.is_file():
        raise DatasetError(f"{path}: shard file missing")
    if _sha256(path) != entry["sha256"]:
        raise DatasetError(f"{path}: checksum mismatch, the file is corrupt")
    out = {}
    try:
        with h5py.File(path, "r") as h5:
            for f in fields:
                if f not in h5:
                    raise DatasetError(f"{path}: field '{f}' missing")
                a = h5[f][...]
                if a.shape != (entry["samples"], *schema[f]["shape"]):
                    raise DatasetError(f"{path}: field '{f}' has shape {a.shape}, expected "
                                       f"{(entry['samples'], *schema[f]['shape'])}")
                if a.dtype.kind == "f" and not np.isfinite(a).all():
                    bad = np.unique(np.argwhere(~np.isfinite(a))[:, 0])
                    raise DatasetError(f"{path}: field '{f}' holds NaN or Inf (samples {bad[:5].tolist()}"
                                       f"{' ...' if len(bad) > 5 else ''})")
                out[f] = a
    except (OSError, KeyError, ValueError, RuntimeError) as err:  # h5py: broken header, truncated data
        if isinstance(err, DatasetError):
            raise
        first = (str(err).strip().splitlines() or [type(err).__name__])[0]
        raise DatasetError(f"{path}: not a readable HDF5 shard ({first})") from err
    return out


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
        remove_stale_temp_files(self.root)  # temp files of a killed writer
        for stale in self.root.iterdir():
            if _OLD_TEMP.match(stale.name):
                stale.unlink(missing_ok=True)
        self.manifest_path = self.root / "manifest.json"
        header = {"format_version": FORMAT_VERSION, "metadata": metadata, "num_shards": num_shards,
                  "shard_size": shard_size,
                  "schema": {k: {"shape": list(f.shape), "dtype": f.dtype} for k, f in schema.items()}}
        manifest = self._readable_manifest()
        if manifest is not None:
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
            atomic_write_text(self.manifest_path, json.dumps(self.manifest, indent=1))

    def _readable_manifest(self) -> dict | None:
        """The folder's manifest; None when there is none or it is damaged (cut off by a full
        disk, edited by hand): that one is started afresh and every shard made again, which
        gives the same data (shard i comes from seed (seed, i)) without trusting unrecorded files."""
        if not self.manifest_path.exists():
            return None
        try:
            return read_manifest(self.root)
        except DamagedManifest as err:
            log.warning("%s; starting the manifest afresh, every shard is made again", err)
            return None

    def missing(self) -> list[int]:
        """Shard indices not yet written (or whose file is gone)."""
        done = {int(i) for i, s in self.manifest["shards"].items() if (self.root / s["file"]).exists()}
        return [i for i in range(self.manifest["num_shards"]) if i not in done]

    def bad(self) -> dict[int, str]:
        """Recorded shards that fail verification (checksum, HDF5 structure, schema, values): index -> why."""
        problems = {}
        schema = self.manifest["schema"]
        for i in range(self.manifest["num_shards"]):
            entry = self.manifest["shards"].get(str(i))
            if entry is None or not (self.root / entry["file"]).exists():
                continue
            try:
                _read_shard(self.root / entry["file"], entry, schema, list(schema))
            except DatasetError as err:
                problems[i] = str(err)
        return problems

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
        buffer = io.BytesIO()  # HDF5 built in memory, then written and renamed in one go
        with h5py.File(buffer, "w") as h5:
            for key, spec in self.schema.items():
                chunk = (min(n, 1024), *spec.shape)
                h5.create_dataset(key, data=arrays[key].astype(spec.dtype), chunks=chunk)
        atomic_write(self.root / name, lambda fh: fh.write(buffer.getbuffer()))
        self.manifest["shards"][str(index)] = {"file": name, "samples": n, "sha256": _sha256(self.root / name)}
        atomic_write_text(self.manifest_path, json.dumps(self.manifest, indent=1))

    def generate_missing(self, make_shard: Callable[[int], dict[str, np.ndarray]],
                         progress: Callable[[Iterable[int]], Iterable[int]] | None = None) -> int:
        """Generate and write every missing shard and regenerate every bad one (see `bad`);
        returns how many were written."""
        bad = self.bad()
        for problem in bad.values():
            log.warning("%s; regenerating it", problem)
        todo = sorted(set(self.missing()) | set(bad))
        for index in (progress(todo) if progress else todo):
            self.write_shard(index, make_shard(index))
        return len(todo)


def read_manifest(root: str | Path) -> dict:
    path = Path(root) / "manifest.json"
    if not path.is_file():
        raise DatasetError(f"{path}: no dataset manifest (generate the dataset first)")
    try:
        manifest = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise DamagedManifest(f"{path}: manifest is not valid JSON ({err})") from None
    if not isinstance(manifest, dict):
        raise DamagedManifest(f"{path}: manifest is not a JSON object")
    if manifest.get("format_version") != FORMAT_VERSION:
        raise DatasetError(f"{path}: format version {manifest.get('format_version')}, "
                           f"this code reads {FORMAT_VERSION}")
    _check_manifest(manifest, path)
    return manifest


def _check_manifest(manifest: dict, path: Path) -> None:
    """The manifest's structure, so that a damaged one is named instead of failing with a KeyError."""

    def need(ok: bool, what: str) -> None:
        if not ok:
            raise DamagedManifest(f"{path}: damaged manifest, {what}")

    for key, kind in (("metadata", dict), ("num_shards", int), ("shard_size", int), ("schema", dict),
                      ("shards", dict)):
        need(isinstance(manifest.get(key), kind), f"'{key}' missing or not a {kind.__name__}")
    need(manifest["num_shards"] >= 0 and manifest["shard_size"] >= 1, "bad num_shards or shard_size")
    for name, spec in manifest["schema"].items():
        need(isinstance(spec, dict) and isinstance(spec.get("shape"), list) and isinstance(spec.get("dtype"), str),
             f"schema field '{name}' needs a shape list and a dtype")
    for index, entry in manifest["shards"].items():
        need(isinstance(entry, dict) and isinstance(entry.get("file"), str) and isinstance(entry.get("sha256"), str)
             and isinstance(entry.get("samples"), int), f"shard entry '{index}' needs file, samples and sha256")
        need(Path(entry["file"]).name == entry["file"] and entry["file"] not in ("", ".", ".."),
             f"shard entry '{index}' names a file outside the dataset folder")


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
        arrays = _read_shard(root / entry["file"], entry, schema, fields)
        for f in fields:
            parts[f].append(arrays[f])
    return {f: np.concatenate(v) for f, v in parts.items()}
