"""A run of the controller node as a bag, and its replay offline.

Per tick that commanded, the bag holds the joint state and skin message the tick used and
the command it sent, all stamped with the tick's time, and the episode starts: what
`replay_run` needs to feed a fresh controller exactly what the live one saw, so a run on
the hand can be replayed and its commands compared bit for bit.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from tacgnn.real.bag import BagWriter, read_bag
from tacgnn.real.messages import decode_joint_state, decode_tactile
from tacgnn.real.ros_config import RosConfig
from tacgnn.real.tick import ControlTick


class RunRecorder:
    """Writes, per commanding tick, the joint state and skin message it used and its command."""

    def __init__(self, path: str | Path, cfg: RosConfig, tactile_cls: Any):  # a generated ROS message class
        self.cfg = cfg
        self.writer = BagWriter(path, {tactile_cls._type: tactile_cls._full_text})
        self.t0 = time.monotonic()

    def tick(self, t: float, tick: ControlTick, command: Any) -> None:
        time_s = t - self.t0 + 1.0  # bag times must be positive
        assert tick.used is not None  # the tick commanded, so it kept its messages
        joint_msg, skin_msg = tick.used
        if tick.reset_now:
            self.writer.write(self.cfg.episode_topic or "/tacgnn/episode", "std_msgs/Int32",
                              self.writer.message("std_msgs/Int32", data=tick.episode), time_s)
        self.writer.write_msg(self.cfg.joint_state_topic, joint_msg, time_s)
        self.writer.write_msg(self.cfg.tactile_topic, skin_msg, time_s)
        self.writer.write_msg(self.cfg.joint_cmd_topic, command, time_s)

    def close(self) -> None:
        self.writer.close()


def replay_run(path: str | Path, cfg: RosConfig, controller, processor) -> tuple[np.ndarray, np.ndarray]:
    """(recorded, replayed) (K, 16) targets: a run bag's ticks fed through `controller` offline."""
    topics = {"joint states": cfg.joint_state_topic, "skin": cfg.tactile_topic, "commands": cfg.joint_cmd_topic}
    msgs = read_bag(path, topics)
    episode_topic = cfg.episode_topic or "/tacgnn/episode"
    try:
        resets = {round(m.time, 9) for m in read_bag(path, {"episodes": episode_topic})[episode_topic]}
    except ValueError:
        resets = set()
    joints, skins, cmds = (msgs[t] for t in (cfg.joint_state_topic, cfg.tactile_topic, cfg.joint_cmd_topic))
    if not (len(joints) == len(skins) == len(cmds)):
        raise ValueError(f"bag {path}: not a run recording (per tick one joint state, skin frame and command)")
    recorded, replayed = [], []
    for j, s, c in zip(joints, skins, cmds):
        pos, vel = decode_joint_state(j.msg, cfg.joint_names)
        if round(j.time, 9) in resets:
            controller.reset(pos)
        replayed.append(controller.step(pos, vel, processor(decode_tactile(s.msg, cfg.tactile_fields))))
        recorded.append(decode_joint_state(c.msg, cfg.joint_names)[0])
    return np.asarray(recorded), np.asarray(replayed)
