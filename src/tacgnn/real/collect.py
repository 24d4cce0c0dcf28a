"""Recordings from the hand over ROS for the first steps of the real path: joint steps for
system identification (`tacgnn sysid`), skin frames at rest for calibration
(`tacgnn calibrate-skin`); `tacgnn real-hand record-steps` and `record-skin`.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from tacgnn.files import atomic_write
from tacgnn.hand.skin_layout import default_skin
from tacgnn.real.bag import BagWriter
from tacgnn.real.joint_recording import JointRecording, save_recording
from tacgnn.real.messages import Latest, MalformedInput, decode_joint_state, decode_tactile, tactile_message_class
from tacgnn.real.node import RosNode
from tacgnn.real.ros_config import RosConfig


def record_steps(cfg: RosConfig, targets: np.ndarray, out: str | Path) -> Path:
    """Command `targets` (T, 16) at rate_hz and save a bag for `tacgnn sysid` (or .npz/.csv).

    The bag holds every joint state as received and every command as sent; sample t of
    the recording is the newest joint state read just before targets[t] is published.
    """
    out = Path(out)
    node = RosNode(cfg, "tacgnn_record_steps")
    joints = Latest(lambda m: decode_joint_state(m, cfg.joint_names), f"joint state on {cfg.joint_state_topic}",
                    cfg.malformed_limit, cfg.malformed_timeout_s)
    bag = BagWriter(out) if out.suffix == ".bag" else None
    t0 = time.monotonic()

    def on_joint_state(msg):
        kept = joints.count
        joints(msg)
        if bag is not None and joints.count > kept:  # a malformed state is dropped, not recorded
            bag.write_msg(cfg.joint_state_topic, msg, joints.stamp - t0 + 1.0)

    node.subscribe(cfg.joint_state_topic, node.JointState, on_joint_state)
    publish = node.publisher(cfg.joint_cmd_topic, node.JointState)
    # joint states that do not decode (other joint names, NaN) are dropped: a run of them stops
    # the recording here, before the first command
    node.wait_for(f"joint state on {cfg.joint_state_topic}", joints, cfg.startup_timeout_s)
    times: list[float] = []
    measured: list[np.ndarray] = []

    def step(_scheduled: float) -> bool:
        t = len(measured)
        if t == len(targets):
            return False
        problem = joints.failure()
        if problem is not None:
            raise MalformedInput(problem)
        now = time.monotonic()
        times.append(now - t0)
        measured.append(decode_joint_state(joints.msg, cfg.joint_names)[0])
        msg = node.joint_state(targets[t])
        publish(msg)
        if bag is not None:
            bag.write_msg(cfg.joint_cmd_topic, msg, now - t0 + 1.0)
        return True

    try:
        node.loop(step)
    finally:
        if bag is not None:
            bag.close()
    node.shutdown("recording done")
    if bag is not None:
        return out
    rec = JointRecording(np.asarray(times), np.asarray(targets[:len(measured)], np.float64), np.asarray(measured),
                         source=str(out))
    return save_recording(rec, out)


def record_skin(cfg: RosConfig, frames: int, out: str | Path, layout=None) -> Path:
    """Save `frames` skin messages: as received in a .bag, or one (frames, size) array per patch in a .npz."""
    layout = layout or default_skin()
    out = Path(out)
    node = RosNode(cfg, "tacgnn_record_skin")
    tactile_cls = tactile_message_class(cfg)
    received: list[Any] = []
    done = threading.Event()

    def on_skin(msg):
        if len(received) < frames:
            received.append((time.monotonic(), msg))
        if len(received) >= frames:
            done.set()

    node.subscribe(cfg.tactile_topic, tactile_cls, on_skin)
    deadline = time.monotonic() + cfg.startup_timeout_s + 2 * frames / cfg.rate_hz
    while not done.wait(0.05):
        node.spin_once()
        if time.monotonic() > deadline or not node.ok():
            raise TimeoutError(f"only {len(received)} of {frames} skin frames on {cfg.tactile_topic} in time")
    node.shutdown("recording done")
    if out.suffix == ".bag":
        t0 = received[0][0]
        with BagWriter(out, {tactile_cls._type: tactile_cls._full_text}) as bag:
            for t, msg in received:
                bag.write_msg(cfg.tactile_topic, msg, t - t0 + 1.0)
        return out
    rows = [decode_tactile(msg, cfg.tactile_fields) for _, msg in received]
    arrays = {p.name: np.stack([r[p.name] for r in rows]) for p in layout.patches}
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(out, lambda fh: np.savez(fh, **arrays))  # type: ignore[arg-type]  # numpy's stub: **arrays
    return out
