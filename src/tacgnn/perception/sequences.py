"""Sequence data: a dataset's frames in episode order, split by episode, and windows of consecutive frames.

A temporal model learns from windows of consecutive frames of one episode. Neighbouring
frames of an episode are nearly the same, so a split by frame would put near copies of the
test frames into training; the split here is by episode. Datasets made with
``keep_every=1`` (``tacgnn make-dataset baoding --keep-every 1``) store each frame's
``episode`` and ``step`` and hold every step of an episode after its first
``settle_steps``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from tacgnn.config import ConfigError
from tacgnn.datasets.store import DatasetError, load, read_manifest
from tacgnn.perception.data import TactileData
from tacgnn.perception.objectives import CM, targets

SEQUENCE_FIELDS = ("episode", "step", "action")


@dataclass
class SequenceData:
    """Frames sorted by (episode, step), with what a temporal model reads beside the skin.

    ``frames``: readings (N, T) in N, positions (N, T, 3) in cm, targets (N, 6) in cm,
    joints (N, 16) in rad; ``actions`` (N, 16) the command of each frame's step in [-1, 1];
    ``episode`` (N,) and ``step`` (N,) int64.
    """

    frames: TactileData
    actions: torch.Tensor
    episode: torch.Tensor
    step: torch.Tensor

    def __post_init__(self) -> None:
        n = len(self.frames)
        if not (len(self.actions) == len(self.episode) == len(self.step) == n):
            raise ValueError(f"sequence fields of different lengths: {n} frames, {len(self.actions)} actions, "
                             f"{len(self.episode)} episode ids, {len(self.step)} steps")

    def __len__(self) -> int:
        return len(self.frames)

    def subset(self, idx: torch.Tensor) -> SequenceData:
        """Rows `idx` (kept in the given order)."""
        return SequenceData(self.frames.subset(idx), self.actions[idx], self.episode[idx], self.step[idx])

    def with_frames(self, frames: TactileData) -> SequenceData:
        """The same rows with other frames (e.g. other readings)."""
        return SequenceData(frames, self.actions, self.episode, self.step)

    def run_starts(self) -> torch.Tensor:
        """(N,) bool: frames that start a run of consecutive steps of one episode (an episode's
        first frame, or the frame after a gap in its steps)."""
        first = torch.ones(len(self), dtype=torch.bool)
        if len(self) > 1:
            first[1:] = (self.episode[1:] != self.episode[:-1]) | (self.step[1:] != self.step[:-1] + 1)
        return first

    def run_index(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Per frame: the row where its run starts, and the run's length."""
        first = self.run_starts()
        run = torch.cumsum(first.long(), 0) - 1
        starts = first.nonzero().squeeze(1)
        lengths = torch.bincount(run, minlength=len(starts))
        return starts[run], lengths[run]

    def episodes(self) -> torch.Tensor:
        """The episode ids, in order."""
        return torch.unique_consecutive(self.episode)


def as_sequence(frames: TactileData) -> SequenceData:
    """Frames without episodes (a dataset recorded for single frames) as sequence data: each frame an
    episode of its own, at step 0, with no actions; a single-frame model reads them in windows of one."""
    n = len(frames)
    return SequenceData(frames, torch.zeros(n, 0), torch.arange(n), torch.zeros(n, dtype=torch.long))


def load_sequences(root: str | Path, max_frames: int = 0) -> SequenceData:
    """A Baoding dataset with episode and step indices, sorted by (episode, step).

    `max_frames` keeps the frames of the first episodes (in id order) up to that many frames
    (0: all). Raises DatasetError naming the folder when the dataset lacks the indices.
    """
    manifest = read_manifest(root)
    meta, schema = manifest["metadata"], manifest["schema"]
    if meta.get("kind") != "baoding":
        raise DatasetError(f"{root}: a {meta.get('kind')!r} dataset; sequences are read from Baoding datasets")
    missing = [f for f in SEQUENCE_FIELDS if f not in schema]
    if missing:
        raise DatasetError(f"{root}: no {', '.join(missing)} per frame (made before sequence datasets); "
                           "make it again with `tacgnn make-dataset baoding --keep-every 1`")
    data = load(root, ["tactile", "taxel_pos", "ball_pos", "joint_pos", *SEQUENCE_FIELDS])
    order = np.lexsort((data["step"], data["episode"]))
    if max_frames:
        episode = data["episode"][order]
        cut = min(max_frames, len(order))
        # whole episodes only: stop at the first episode boundary at or after max_frames
        while 0 < cut < len(order) and episode[cut] == episode[cut - 1]:
            cut += 1
        order = order[:cut]
    frames = TactileData(torch.from_numpy(data["tactile"][order]),
                         torch.from_numpy(data["taxel_pos"][order] * CM),
                         torch.from_numpy(targets({"ball_pos": data["ball_pos"][order]}, "baoding")),
                         torch.from_numpy(data["joint_pos"][order]).float())
    return SequenceData(frames, torch.from_numpy(data["action"][order]).float(),
                        torch.from_numpy(data["episode"][order]), torch.from_numpy(data["step"][order]))


def split_by_episode(data: SequenceData, train_fraction: float, seed: int) -> tuple[SequenceData, SequenceData]:
    """Seeded random split into (train, test) by episode: no episode has frames on both sides."""
    episodes = data.episodes()
    if len(episodes) < 2:
        raise DatasetError(f"the data holds {len(episodes)} episode(s); a split by episode needs at least 2")
    order = torch.randperm(len(episodes), generator=torch.Generator().manual_seed(seed))
    cut = min(max(1, int(round(train_fraction * len(episodes)))), len(episodes) - 1)
    train_ids = episodes[order[:cut]]
    in_train = torch.isin(data.episode, train_ids)
    return data.subset(in_train.nonzero().squeeze(1)), data.subset((~in_train).nonzero().squeeze(1))


def join_episodes(parts: list[SequenceData]) -> SequenceData:
    """The frames of several datasets' episodes in one; the first part keeps its episode ids, each
    later part's are shifted past those before it (keeping their order), so no two share an id.

    Training adds the episodes of other datasets this way (``extra_train``) after the split,
    so the test episodes stay those of the main dataset alone.
    """
    if not parts:
        raise ValueError("join_episodes needs at least one part")
    joints = [p.frames.joints for p in parts]
    if any(j is None for j in joints) and not all(j is None for j in joints):
        raise ValueError("parts with and without joint angles cannot be joined")
    widths = {p.frames.readings.shape[1] for p in parts}
    if len(widths) > 1:
        raise ValueError(f"parts with different numbers of taxels cannot be joined: {sorted(widths)}")
    episodes: list[torch.Tensor] = []
    offset = None  # the first part keeps its ids
    for p in parts:
        shifted = p.episode if offset is None or not len(p) else p.episode - int(p.episode.min()) + offset
        episodes.append(shifted)
        if len(p):
            offset = max(offset or 0, int(shifted.max()) + 1)
    frames = TactileData(torch.cat([p.frames.readings for p in parts]), torch.cat([p.frames.positions for p in parts]),
                         torch.cat([p.frames.targets for p in parts]),
                         None if joints[0] is None else torch.cat([j for j in joints if j is not None]))
    return SequenceData(frames, torch.cat([p.actions for p in parts]), torch.cat(episodes),
                        torch.cat([p.step for p in parts]))


def window_starts(data: SequenceData, length: int) -> torch.Tensor:
    """Rows where a window of `length` consecutive frames of one episode can start.

    Raises ConfigError (key ``window``) when the window is longer than every run of
    consecutive frames in the data (e.g. a dataset made with keep_every > 1).
    """
    if length < 1:
        raise ConfigError(f"config key 'window': must be >= 1, got {length}", key="window")
    start, run_length = data.run_index()
    if len(data) == 0 or int(run_length.max()) < length:
        longest = int(run_length.max()) if len(data) else 0
        raise ConfigError(f"config key 'window': a window of {length} frames is longer than every episode of "
                          f"the data (longest run of consecutive steps: {longest} frames)", key="window")
    position = torch.arange(len(data)) - start
    return (position + length <= run_length).nonzero().squeeze(1)


def check_windows(data: SequenceData, rows: torch.Tensor) -> None:
    """Raise ValueError unless every row of `rows` (B, L) lists consecutive steps of one episode."""
    if rows.dim() != 2:
        raise ValueError(f"windows must be (B, L) rows, got shape {tuple(rows.shape)}")
    if rows.numel() == 0:
        return
    if int(rows.min()) < 0 or int(rows.max()) >= len(data):
        raise ValueError(f"window rows outside the data's {len(data)} frames")
    episode, step = data.episode[rows], data.step[rows]
    mixed = (episode != episode[:, :1]).any(1)
    if mixed.any():
        b = int(mixed.nonzero()[0])
        raise ValueError(f"window {b} holds frames of two episodes ({sorted(set(episode[b].tolist()))[:2]}): "
                         "a window must stay inside one episode")
    gap = (step[:, 1:] != step[:, :-1] + 1).any(1)
    if gap.any():
        b = int(gap.nonzero()[0])
        raise ValueError(f"window {b} of episode {int(episode[b, 0])} skips steps ({step[b].tolist()[:8]}...): "
                         "a window must hold consecutive steps")


def burn_in_rows(data: SequenceData, starts: torch.Tensor, burn_in: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The `burn_in` rows before each window start, and which of them lie in the same run.

    Returns ``rows (B, burn_in)`` (clamped to valid rows) and ``valid (B, burn_in)``: a frame
    before its run's first frame is padding, and the state stays fresh through it, as it is
    at the start of an episode.
    """
    run_start, _ = data.run_index()
    offsets = torch.arange(-burn_in, 0)
    rows = starts.unsqueeze(1) + offsets
    valid = rows >= run_start[starts].unsqueeze(1)
    return rows.clamp_min(0), valid


def touched(data: TactileData, within_cm: float = 3.0) -> torch.Tensor:
    """(N, 2) bool: an activated taxel lies within `within_cm` of the ball's centre (`touched_balls`)."""
    return touched_balls(data.readings, data.positions, data.targets, within_cm)


def touched_balls(readings: torch.Tensor, positions: torch.Tensor, balls: torch.Tensor,
                  within_cm: float = 3.0) -> torch.Tensor:
    """(N, 2) bool: an activated taxel lies within `within_cm` of the ball's centre.

    The balls' radius is 2.625 cm: 3 cm counts taxels pressed by the ball (their positions
    are on the skin's surface, up to a few mm inside the ball's surface under load) and
    none pressed by the other ball (centres >= 5.25 cm apart).

    Shapes: readings (N, T), positions (N, T, 3) cm, balls (N, 6) cm -> (N, 2).
    """
    active = readings > 0
    out = []
    for b in range(2):
        centre = balls[:, None, 3 * b:3 * b + 3]
        dist = (positions - centre).norm(dim=-1).masked_fill(~active, float("inf"))
        out.append(dist.amin(1) < within_cm)
    return torch.stack(out, 1)


def steps_since_touch(data: SequenceData, touch: torch.Tensor) -> torch.Tensor:
    """(N, 2) int64: steps since each ball last touched the skin (0 while touched).

    Counted within the frame's episode; a ball not yet touched in its episode counts from
    the episode's first frame plus one (as if touched just before it).
    """
    first = data.run_starts().numpy()
    hit = touch.numpy()
    out = np.zeros(hit.shape, np.int64)
    count = np.zeros(2, np.int64)
    for i in range(len(data)):  # a plain scan: datasets hold tens of thousands of frames
        count = np.where(hit[i], 0, 1 if first[i] else count + 1)
        out[i] = count
    return torch.from_numpy(out)
