"""The skin frames a late skin delivers: the last frames of every env, read some frames behind.

A real skin's frames reach the policy a few control steps after the instant they describe (its
bus and driver). `SkinRing` keeps the newest `slots` frames (readings and taxel positions) of all
envs and hands back, for each env, the one `delay` frames old. The frames are stored by age, one
(N, ...) block per slot, so a step writes one contiguous block and reads whole blocks (envs of
the most common delay) with a few rows patched: plain copies, a third of the time of row-indexed
ones at 256 envs.
"""

from __future__ import annotations

from typing import Any

import numpy as np


class SkinRing:
    """The last `slots` skin frames of `num_envs` envs: slot (head + k) % slots holds the frame k
    steps old.

    Args:
        num_envs: N.
        slots: frames kept (the largest delay + 1).
        num_taxels: T.

    Shapes: ``push(tactile (N, T), taxel_pos (N, T, 3), delay (N,)) -> (N, T), (N, T, 3)``.
    """

    STATE = ("frames", "positions", "head")

    def __init__(self, num_envs: int, slots: int, num_taxels: int):
        self.frames = np.zeros((slots, num_envs, num_taxels), np.float32)
        self.positions = np.zeros((slots, num_envs, num_taxels, 3), np.float32)
        self.head = np.zeros((), np.int64)

    def fill(self, ids: np.ndarray | slice, tactile: np.ndarray, taxel_pos: np.ndarray) -> None:
        """Envs `ids` start over (a reset): every slot holds this frame."""
        self.frames[:, ids], self.positions[:, ids] = tactile[None], taxel_pos[None]

    def push(self, tactile: np.ndarray, taxel_pos: np.ndarray, delay: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Store every env's new frame; return, as new arrays, each env's frame `delay[env]` steps old."""
        slots = len(self.frames)
        self.head[...] = newest = (int(self.head) - 1) % slots  # the oldest slot takes the new frame
        self.frames[newest], self.positions[newest] = tactile, taxel_pos
        late = (newest + delay) % slots
        common = int(np.bincount(late, minlength=slots).argmax())
        frames, positions = self.frames[common].copy(), self.positions[common].copy()
        others = np.flatnonzero(late != common)
        frames[others], positions[others] = self.frames[late[others], others], self.positions[late[others], others]
        return frames, positions

    def state_dict(self) -> dict[str, Any]:
        return {name: getattr(self, name).copy() for name in self.STATE}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if "head" in state and np.ndim(state["head"]) == 0:
            for name in self.STATE:
                getattr(self, name)[...] = state[name]
            return
        # a state saved env by env ((N, slots, ...) and a head per env; states older still have no
        # head: newest first from slot 0): slot k takes each env's frame k steps old, head 0
        frames, positions = np.asarray(state["frames"]), np.asarray(state["positions"])
        envs, slots = np.arange(frames.shape[0]), frames.shape[1]
        head = np.asarray(state.get("head", np.zeros(len(envs), np.int64)))
        for k in range(slots):
            self.frames[k], self.positions[k] = frames[envs, (head + k) % slots], positions[envs, (head + k) % slots]
        self.head[...] = 0
