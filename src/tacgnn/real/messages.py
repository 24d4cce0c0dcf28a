"""The hand's ROS messages without ROS: stamps, decoding, message classes, the newest message of a topic.

Decoding checks what the controller relies on (joint names, counts, finite values, skin
fields), so a message that breaks it fails here with a ValueError that names the problem.
`Latest` keeps the newest message of a topic that decodes: one that does not is dropped,
counted and logged (on the terminal, see `node.log_to_terminal`), and only a run of them
(`ros.malformed_limit` in a row, or nothing else for `ros.malformed_timeout_s`) stops the
run: any node can publish on a topic, and one stray message must not end a run on a hand.
"""

from __future__ import annotations

import importlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from tacgnn.hand.allegro import JOINT_NAMES, NUM_JOINTS
from tacgnn.real.bag import tactile_definition
from tacgnn.real.ros_config import ALLEGRO_JOINT_NAMES, RosConfig

log = logging.getLogger("tacgnn.real")


class MalformedInput(ValueError):
    """A topic sent only malformed messages for too long: the run stops; the message names topic and problem."""


def stamp_ns(msg: Any) -> int | None:
    """A message's header stamp in integer nanoseconds (ROS 1 or 2); None without a header or with stamp 0."""
    header = getattr(msg, "header", None)
    if header is None:
        return None
    stamp = header.stamp
    secs = stamp.secs if hasattr(stamp, "secs") else stamp.sec
    nsecs = stamp.nsecs if hasattr(stamp, "nsecs") else stamp.nanosec
    ns = int(secs) * 1_000_000_000 + int(nsecs)
    return ns or None


def decode_joint_state(msg: Any, names: tuple[str, ...] = ALLEGRO_JOINT_NAMES) -> tuple[np.ndarray, np.ndarray]:
    """(positions, velocities) (16,) each, in our joint order, from a JointState-like message."""
    pos = np.asarray(msg.position, dtype=np.float64)
    vel = np.asarray(msg.velocity, dtype=np.float64) if len(msg.velocity) else np.zeros_like(pos)
    if len(msg.name):
        index = {n: i for i, n in enumerate(msg.name)}
        missing = [n for n in names if n not in index]
        if missing:
            raise ValueError(f"joint state names do not match ros.joint_names: lacks {missing[:4]}"
                             f"{' ...' if len(missing) > 4 else ''} (the message has {list(msg.name)[:4]} ...)")
        if len(pos) != len(msg.name) or len(vel) != len(msg.name):
            raise ValueError(f"joint state has {len(msg.name)} names but {len(pos)} positions, {len(vel)} velocities")
        order = [index[n] for n in names]
        pos, vel = pos[order], vel[order]
    if pos.shape != (NUM_JOINTS,) or vel.shape != (NUM_JOINTS,):
        raise ValueError(f"joint state must hold {NUM_JOINTS} positions and velocities, got {pos.shape}, {vel.shape}")
    bad = ~(np.isfinite(pos) & np.isfinite(vel))
    if bad.any():
        raise ValueError(f"joint state has non-finite angles or velocities (NaN/Inf) at joint(s) "
                         f"{[JOINT_NAMES[i] for i in np.flatnonzero(bad)][:4]}")
    return pos, vel


def decode_tactile(msg: Any, fields: tuple[tuple[str, str], ...]) -> dict[str, np.ndarray]:
    """patch name -> raw array, from a skin message with one array field per patch."""
    out = {}
    for patch, attr in fields:
        if not hasattr(msg, attr):
            raise ValueError(f"skin message {type(msg).__name__} has no field '{attr}' (for patch '{patch}'); "
                             "set ros.tactile_fields to your message's fields")
        out[patch] = np.asarray(getattr(msg, attr), dtype=np.float64)
    return out


def import_message(type_name: str) -> type:
    """The Python class of message 'package/Type' (ROS 1 and ROS 2 both generate package.msg.Type)."""
    package, _, name = type_name.partition("/")
    try:
        return getattr(importlib.import_module(f"{package}.msg"), name)
    except (ImportError, AttributeError) as err:
        raise ImportError(f"cannot import message {type_name}: is its package built and sourced?") from err


def tactile_message_class(cfg: RosConfig) -> Any:
    """The skin message class: its package's, or (ROS 1, package not installed) one generated
    from `tactile_fields` as one float32[] per field, which is what the simulated hand sends."""
    try:
        return import_message(cfg.tactile_type)
    except ImportError:
        if cfg.ros_version != 1:
            raise
    import genpy.dynamic

    log.info("message package of %s not found: using float32[] fields %s", cfg.tactile_type,
             [a for _, a in cfg.tactile_fields][:3] + ["..."])
    return genpy.dynamic.generate_dynamic(cfg.tactile_type, tactile_definition(cfg.tactile_fields))[cfg.tactile_type]


class Latest:
    """The newest well-formed message of a topic, when it arrived, and how many came (callbacks
    write, the loop reads).

    `last` holds (message, arrival time) as one tuple, so a reader never pairs a message
    with another message's time. With `check` (a function that raises ValueError on a
    message the controller cannot use), a message that fails it is dropped and counted
    (`malformed`); the last good one stays. One warning line when dropping starts, one when
    a good message ends it. `failure()` says when the run must stop: `limit` malformed
    messages in a row, or `timeout_s` since the first of a run of them with no good one.
    """

    def __init__(self, check: Callable[[Any], object] | None = None, what: str = "message", limit: int = 1,
                 timeout_s: float = np.inf) -> None:
        self.last: tuple[Any, float] = (None, -np.inf)
        self.count = 0
        self.arrived = threading.Event()
        self.listener: Callable[[], None] | None = None
        """Called on the receiving thread after each kept message (the control loop ticks there)."""
        self.check, self.what, self.limit, self.timeout_s = check, what, limit, timeout_s
        self.malformed = 0
        """Messages dropped because `check` refused them, over the whole run."""
        self.in_row = 0
        self._since: float | None = None  # arrival of the first malformed message since the last good one
        self._problem = ""

    def __call__(self, msg: Any) -> None:
        if self.check is not None:
            try:
                self.check(msg)
            except ValueError as err:
                self._drop(err)
                return
            if self.in_row:
                log.warning("%s: well-formed again after %d malformed dropped", self.what, self.in_row)
                self.in_row, self._since = 0, None
        self.last = (msg, time.monotonic())
        self.count += 1
        self.arrived.set()
        if self.listener is not None:
            self.listener()

    def _drop(self, err: ValueError) -> None:
        if self.in_row == 0:
            self._since = time.monotonic()
            log.warning("malformed %s dropped: %s (the run stops after %d in a row or %.3g s of them)",
                        self.what, err, self.limit, self.timeout_s)
        self._problem = str(err)
        self.malformed += 1
        self.in_row += 1

    def failure(self) -> str | None:
        """Why the run must stop for this topic's malformed messages, or None."""
        since, in_row = self._since, self.in_row
        if not in_row or since is None:
            return None
        if in_row >= self.limit:
            return f"{self.what}: {in_row} malformed messages in a row, the last: {self._problem}"
        waited = time.monotonic() - since
        if waited >= self.timeout_s:
            return f"{self.what}: only malformed messages for {waited:.2f} s ({in_row}), the last: {self._problem}"
        return None

    @property
    def msg(self) -> Any:
        return self.last[0]

    @property
    def stamp(self) -> float:
        return self.last[1]

    @stamp.setter
    def stamp(self, value: float) -> None:
        self.last = (self.last[0], value)
