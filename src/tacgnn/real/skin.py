"""Raw skin arrays of a real hand -> the simulator's taxel readings.

The authors' tactile pipeline, per taxel: subtract the rest baseline, clip at 0, zero
what is below the taxel's threshold, multiply by the taxel's gain. The result is the
(653,) vector in the simulator's units (newtons per taxel) and taxel order, what the
perception model was trained on.

A calibration holds, per taxel and in the simulator's order:

* ``baseline`` (raw units): the mean reading at rest, with nothing touching the skin;
* ``threshold`` (raw units): readings less than this above the baseline are noise;
* ``gain`` (N per raw unit): 1 by default; `patch_gain_from_load` sets a patch's gain
  from frames under a known force (inside a patch the simulator's readings sum to the
  contact force, so the gain makes the real ones do the same);
* ``dead``: taxels that read exactly 0 in every rest frame (a broken line); they read 0;
* ``order``: wiring, ``skin[i] = raw[order[i]]`` where ``raw`` is the driver's patch
  arrays concatenated in the layout's patch order (identity when the driver already
  numbers taxels like `tacgnn.hand.skin_layout`).

Raw frames come in as one array per patch (the driver's message holds one per patch),
as a mapping patch name -> array or a sequence in the layout's patch order.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from tacgnn.files import atomic_write
from tacgnn.hand.skin_layout import SkinLayout, default_skin
from tacgnn.real.bag import BagError, read_bag
from tacgnn.real.messages import decode_tactile
from tacgnn.real.ros_config import RosConfig
from tacgnn.sim.skin_signal import calibrated, track_baseline


class CalibrationError(ValueError):
    """A skin calibration file or array is malformed; the message names the file and problem."""


@dataclass(frozen=True, eq=False)
class SkinCalibration:
    """Per-taxel calibration in the simulator's taxel order (see the module docstring)."""

    baseline: np.ndarray
    threshold: np.ndarray
    gain: np.ndarray
    dead: np.ndarray
    order: np.ndarray
    patch_names: tuple[str, ...]
    patch_sizes: tuple[int, ...]
    source: str = "<memory>"

    def __post_init__(self) -> None:
        def fail(problem: str) -> None:
            raise CalibrationError(f"skin calibration {self.source}: {problem}")

        n = int(sum(self.patch_sizes))
        if len(self.patch_names) != len(self.patch_sizes) or n <= 0:
            fail(f"{len(self.patch_names)} patch names for {len(self.patch_sizes)} patch sizes")
        for name in ("baseline", "threshold", "gain", "dead", "order"):
            value = getattr(self, name)
            if not isinstance(value, np.ndarray) or value.shape != (n,):
                fail(f"'{name}' must have shape ({n},) (one value per taxel), got {np.shape(value)}")
        for name in ("baseline", "threshold", "gain"):
            value = getattr(self, name)
            if not np.isfinite(value).all():
                fail(f"'{name}' has non-finite values at taxels {np.flatnonzero(~np.isfinite(value))[:5].tolist()}")
        for name in ("threshold", "gain"):
            if (getattr(self, name) < 0).any():
                fail(f"'{name}' must be >= 0 (taxels {np.flatnonzero(getattr(self, name) < 0)[:5].tolist()})")
        if self.dead.dtype != bool:
            fail(f"'dead' must be boolean, got {self.dead.dtype}")
        if not np.issubdtype(self.order.dtype, np.integer) or not np.array_equal(np.sort(self.order), np.arange(n)):
            fail(f"'order' must be a permutation of 0..{n - 1}")

    @property
    def num_taxels(self) -> int:
        return len(self.baseline)

    def check_layout(self, layout: SkinLayout) -> None:
        """Raise CalibrationError unless this calibration is for `layout`'s patches."""
        names = tuple(p.name for p in layout.patches)
        sizes = tuple(p.size for p in layout.patches)
        if (names, sizes) != (tuple(self.patch_names), tuple(self.patch_sizes)):
            raise CalibrationError(f"skin calibration {self.source}: made for patches "
                                   f"{dict(zip(self.patch_names, self.patch_sizes))}, "
                                   f"the skin has {dict(zip(names, sizes))}")

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, lambda fh: np.savez(
            fh, baseline=self.baseline, threshold=self.threshold, gain=self.gain, dead=self.dead, order=self.order,
            patch_names=np.array(self.patch_names, dtype=str), patch_sizes=np.array(self.patch_sizes, dtype=np.int64)))
        return path

    @classmethod
    def load(cls, path: str | Path) -> SkinCalibration:
        path = Path(path)
        if not path.is_file():
            raise CalibrationError(f"skin calibration {path}: file not found")
        keys = ("baseline", "threshold", "gain", "dead", "order", "patch_names", "patch_sizes")
        try:
            with np.load(path, allow_pickle=False) as data:
                missing = [k for k in keys if k not in data.files]
                if missing:
                    raise CalibrationError(f"skin calibration {path}: missing array(s) {missing}; "
                                           f"the file holds {sorted(data.files)}")
                arrays = {k: data[k] for k in keys}
        except CalibrationError:
            raise
        except Exception as err:
            raise CalibrationError(f"skin calibration {path}: not a readable .npz file ({err})") from err
        return cls(baseline=arrays["baseline"].astype(np.float64), threshold=arrays["threshold"].astype(np.float64),
                   gain=arrays["gain"].astype(np.float64), dead=arrays["dead"], order=arrays["order"],
                   patch_names=tuple(str(s) for s in arrays["patch_names"]),
                   patch_sizes=tuple(int(s) for s in arrays["patch_sizes"]), source=str(path))


def calibrate(rest_frames: np.ndarray, layout: SkinLayout | None = None, sigmas: float = 4.0,
              min_threshold: float = 0.0, gain: float | np.ndarray = 1.0,
              order: np.ndarray | None = None) -> SkinCalibration:
    """A calibration from (N, T) raw frames at rest (driver order, patches concatenated).

    threshold = max(sigmas x the taxel's rest std, min_threshold): noise at rest stays 0.
    """
    layout = layout or default_skin()
    n = layout.num_taxels
    frames = np.asarray(rest_frames, dtype=np.float64)
    if frames.ndim != 2 or frames.shape[1] != n or len(frames) < 2:
        raise CalibrationError(f"rest frames must have shape (N >= 2, {n}), got {frames.shape}")
    if not np.isfinite(frames).all():
        raise CalibrationError(f"rest frames hold non-finite values (frame, taxel) "
                               f"{np.argwhere(~np.isfinite(frames))[0].tolist()}")
    if sigmas < 0 or min_threshold < 0:
        raise CalibrationError(f"sigmas and min_threshold must be >= 0, got {sigmas}, {min_threshold}")
    order = np.arange(n) if order is None else np.asarray(order)
    if order.shape != (n,) or not np.issubdtype(order.dtype, np.integer) or \
            not np.array_equal(np.sort(order), np.arange(n)):
        raise CalibrationError(f"order must be a permutation of 0..{n - 1}, got shape {order.shape}")
    frames = frames[:, order]
    gains = np.broadcast_to(np.asarray(gain, np.float64), (n,)).copy()
    return SkinCalibration(
        baseline=frames.mean(axis=0), threshold=np.maximum(sigmas * frames.std(axis=0), min_threshold),
        gain=gains, dead=(frames == 0).all(axis=0), order=order,
        patch_names=tuple(p.name for p in layout.patches), patch_sizes=tuple(p.size for p in layout.patches))


class SkinProcessor:
    """Applies a calibration to raw per-patch arrays, one frame or many.

    With `tracking_rate` > 0 (a controller's stream of frames, one at a time) the baseline follows
    every taxel that reads no touch by that share per frame (`track_baseline`, as the simulated
    skin does), so drift over a session is not read as touches; 0 keeps the calibration's baseline.
    """

    def __init__(self, calibration: SkinCalibration, layout: SkinLayout | None = None, tracking_rate: float = 0.0):
        self.layout = layout or default_skin()
        calibration.check_layout(self.layout)
        if not 0 <= tracking_rate <= 1:
            raise CalibrationError(f"tracking_rate must be in [0, 1], got {tracking_rate}")
        self.calibration = calibration
        self.tracking_rate = tracking_rate
        self.baseline = calibration.baseline.copy()  # tracked; the calibration's own while tracking_rate is 0
        self._offsets = self.layout.offsets()
        self._names = [p.name for p in self.layout.patches]

    @classmethod
    def for_env(cls, calibration: SkinCalibration, env_config: Any) -> SkinProcessor:
        """The processor a policy trained on `env_config` (a BaodingConfig) expects: its skin layout,
        and its skin's baseline tracking at its control rate."""
        signal = env_config.skin_signal
        rate = 0.0 if signal.is_ideal else signal.tracking_rate(env_config.control_dt)
        return cls(calibration, env_config.skin, tracking_rate=rate)

    def assemble(self, patches: Mapping[str, np.ndarray] | Sequence[np.ndarray]) -> np.ndarray:
        """The raw (T,) vector in driver order from one frame's per-patch arrays (validated)."""
        if isinstance(patches, Mapping):
            unknown = sorted(set(patches) - set(self._names))
            missing = [n for n in self._names if n not in patches]
            if unknown or missing:
                raise ValueError(f"skin frame: missing patches {missing}, unknown patches {unknown}")
            arrays = [patches[n] for n in self._names]
        else:
            if len(patches) != len(self._names):
                raise ValueError(f"skin frame: {len(patches)} patch arrays, the skin has {len(self._names)} "
                                 f"({', '.join(self._names)})")
            arrays = list(patches)
        out = np.empty(self.layout.num_taxels)
        for i, (name, arr) in enumerate(zip(self._names, arrays)):
            arr = np.asarray(arr, dtype=np.float64).ravel()
            size = self._offsets[i + 1] - self._offsets[i]
            if arr.shape != (size,):
                raise ValueError(f"skin frame: patch '{name}' has {arr.size} values, expected {size}")
            if not np.isfinite(arr).all():
                raise ValueError(f"skin frame: patch '{name}' holds non-finite values (NaN/Inf)")
            out[self._offsets[i]:self._offsets[i + 1]] = arr
        return out

    def process_raw(self, raw: np.ndarray, track: bool = True) -> np.ndarray:
        """(..., T) raw vectors in driver order -> (..., T) float32 readings in simulator order;
        `track` advances the tracking baseline by this frame (False: a look that changes nothing,
        e.g. checking a message, so that the frames the policy acts on alone move the baseline)."""
        raw = np.asarray(raw, dtype=np.float64)
        if raw.shape[-1:] != (self.layout.num_taxels,):
            raise ValueError(f"raw skin must end in ({self.layout.num_taxels},), got {raw.shape}")
        c = self.calibration
        raw = raw[..., c.order]
        out = calibrated(raw, self.baseline, c.threshold, c.gain, c.dead)  # the simulated skin's too
        if self.tracking_rate > 0 and track:
            if raw.ndim != 1:
                raise ValueError("a tracking baseline follows a stream: give one frame at a time")
            track_baseline(raw, self.baseline, c.threshold, self.tracking_rate)
        return out

    def __call__(self, patches: Mapping[str, np.ndarray] | Sequence[np.ndarray], track: bool = True) -> np.ndarray:
        """(T,) float32 readings of one frame given as per-patch arrays (`track`: see `process_raw`)."""
        return self.process_raw(self.assemble(patches), track)

    def never_active(self, raw_frames: np.ndarray) -> np.ndarray:
        """Indices (simulator order) of live taxels that read 0 in every frame of a session.

        Run it on frames in which every patch was pressed: those taxels are likely dead
        too (or their threshold is too high).
        """
        readings = self.process_raw(raw_frames)
        return np.flatnonzero(~(readings > 0).any(axis=tuple(range(readings.ndim - 1))) & ~self.calibration.dead)

    def describe(self, taxels: np.ndarray) -> list[str]:
        """'patch[index in patch]' for taxel indices, for reports."""
        patch = np.searchsorted(self._offsets, taxels, side="right") - 1
        return [f"{self._names[p]}[{t - self._offsets[p]}]" for t, p in zip(np.asarray(taxels), patch)]


def patch_gain_from_load(calibration: SkinCalibration, raw_frames: np.ndarray, patch: str,
                         force_newtons: float, layout: SkinLayout | None = None) -> SkinCalibration:
    """`calibration` with patch `patch`'s gain set so its readings sum to a known force.

    raw_frames: (N, T) raw frames (driver order) with a known normal force `force_newtons`
    resting on that patch only.
    """
    layout = layout or default_skin()
    names = [p.name for p in layout.patches]
    if patch not in names:
        raise ValueError(f"unknown patch '{patch}'; patches: {', '.join(names)}")
    if force_newtons <= 0:
        raise ValueError(f"force_newtons must be positive, got {force_newtons}")
    offsets = layout.offsets()
    i = names.index(patch)
    unit = replace(calibration, gain=np.ones_like(calibration.gain))
    counts = SkinProcessor(unit, layout).process_raw(raw_frames)[..., offsets[i]:offsets[i + 1]]
    total = float(counts.sum(axis=-1).mean())
    if total <= 0:
        raise ValueError(f"patch '{patch}' reads nothing above its thresholds in these frames: is the load on it?")
    gain = calibration.gain.copy()
    gain[offsets[i]:offsets[i + 1]] = force_newtons / total
    return replace(calibration, gain=gain)


def load_raw_frames(path: str | Path, layout: SkinLayout | None = None) -> np.ndarray:
    """(N, T) raw frames in driver order from a ROS 1 bag or an .npz of per-patch arrays.

    A .bag holds the skin messages (``tacgnn real-hand record-skin``, default topic and
    fields of `tacgnn.real.ros_config.RosConfig`); an .npz one (N, patch size) array per patch,
    named by patch, or a single (N, T) array named ``raw``.
    """
    layout = layout or default_skin()
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"skin frames {path}: file not found")
    if path.suffix == ".bag":
        return _frames_from_bag(path, layout)
    try:
        with np.load(path, allow_pickle=False) as data:
            contents = {k: data[k] for k in data.files}
    except Exception as err:
        raise CalibrationError(f"skin frames {path}: not a readable .npz file ({err})") from err
    if "raw" in contents:
        frames = np.asarray(contents["raw"], dtype=np.float64)
    else:
        missing = [p.name for p in layout.patches if p.name not in contents]
        if missing:
            raise CalibrationError(f"skin frames {path}: missing patch array(s) {missing}; the file holds "
                                   f"{sorted(contents)} (one (N, size) array per patch, or 'raw' (N, T))")
        parts = []
        for p in layout.patches:
            arr = np.asarray(contents[p.name], dtype=np.float64)
            if arr.ndim != 2 or arr.shape[1] != p.size:
                raise CalibrationError(f"skin frames {path}: patch '{p.name}' must have shape (N, {p.size}), "
                                       f"got {arr.shape}")
            parts.append(arr)
        if len({len(a) for a in parts}) != 1:
            raise CalibrationError(f"skin frames {path}: patches hold different numbers of frames")
        frames = np.concatenate(parts, axis=1)
    if frames.ndim != 2 or frames.shape[1] != layout.num_taxels:
        raise CalibrationError(f"skin frames {path}: expected (N, {layout.num_taxels}) frames, got {frames.shape}")
    if not np.isfinite(frames).all():
        raise CalibrationError(f"skin frames {path}: non-finite values at (frame, taxel) "
                               f"{np.argwhere(~np.isfinite(frames))[0].tolist()}")
    return frames


def _frames_from_bag(path: Path, layout: SkinLayout) -> np.ndarray:
    """A bag of skin messages on the Allegro skin's default topic and fields (`RosConfig`)."""
    ros = RosConfig()
    try:
        return skin_frames_from_bag(path, ros.tactile_topic, ros.tactile_fields, layout)
    except BagError as err:
        raise CalibrationError(str(err)) from err


def skin_frames_from_bag(path: str | Path, tactile_topic: str, fields: tuple[tuple[str, str], ...],
                         layout: SkinLayout) -> np.ndarray:
    """(N, T) raw frames (driver order) from the skin messages of a bag, validated per patch."""
    msgs = read_bag(path, {"skin": tactile_topic})[tactile_topic]
    if not msgs:
        raise CalibrationError(f"skin frames {path}: no messages on {tactile_topic}")
    sizes = {p.name: p.size for p in layout.patches}
    frames = []
    for k, m in enumerate(msgs):
        try:
            patches = decode_tactile(m.msg, fields)
        except ValueError as err:
            raise CalibrationError(f"skin frames {path}: message {k}: {err}") from err
        for name, arr in patches.items():
            if arr.size != sizes[name]:
                raise CalibrationError(f"skin frames {path}: message {k}: patch '{name}' has {arr.size} values, "
                                       f"the skin layout has {sizes[name]}")
        frames.append(np.concatenate([patches[p.name] for p in layout.patches]))
    return np.asarray(frames, dtype=np.float64)
