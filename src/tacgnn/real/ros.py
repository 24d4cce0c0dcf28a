"""Optional ROS adapter: the blind controller, step recordings and skin recordings on a real hand.

Nothing here imports ROS at module import: ``rospy`` (ROS 1) or ``rclpy`` (ROS 2) is
imported when a node starts, so this module loads (and its ROS-free parts are tested)
on machines without ROS.

Topics (the authors' setup, all configurable in `RosConfig`):

* joint states, ``sensor_msgs/JointState`` from the Allegro driver on
  ``/allegroHand_0/joint_states`` (names ``joint_0.0`` .. ``joint_15.0``: index j0-j3,
  middle, ring, thumb, the order of `tacgnn.hand.allegro.JOINT_NAMES`);
* joint commands, ``sensor_msgs/JointState`` (positions, rad) to ``/allegroHand_0/joint_cmd``,
  published at 50 Hz by our loop;
* the skin: one message type holding one numeric array per patch, on ``/allegro_tactile``.
  Its type (``package/Type``) and which field holds which patch are set by
  ``tactile_type`` and ``tactile_fields``; the defaults follow a public Allegro skin
  message (``<finger>_tip_Value``, ``<finger>_mid_Value``, ``<finger>_end_Value``,
  ``palm_Value``): check them against your driver's .msg file.

Control runs on a fixed 50 Hz rate: each tick takes the newest joint state and skin
frame, and commands nothing (holding the last command) when either is older than
``stale_after_s``; the Allegro driver keeps the last command.
"""

from __future__ import annotations

import importlib
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from tacgnn.config import check
from tacgnn.hand.allegro import JOINT_NAMES

NUM_JOINTS = len(JOINT_NAMES)
ALLEGRO_JOINT_NAMES = tuple(f"joint_{i}.0" for i in range(NUM_JOINTS))


def _default_tactile_fields() -> tuple[tuple[str, str], ...]:
    fields = [("palm", "palm_Value")]
    for finger in ("index", "middle", "ring"):
        fields += [(f"{finger}_tip", f"{finger}_tip_Value"), (f"{finger}_medial", f"{finger}_mid_Value"),
                   (f"{finger}_proximal", f"{finger}_end_Value")]
    return tuple(fields + [("thumb_tip", "thumb_tip_Value"), ("thumb_medial", "thumb_mid_Value")])


@dataclass(frozen=True)
class RosConfig:
    ros_version: int = 1
    """1: rospy (the Allegro driver allegro_hand_ros is ROS 1); 2: rclpy."""
    node_name: str = "tacgnn_blind_baoding"
    joint_state_topic: str = "/allegroHand_0/joint_states"
    joint_cmd_topic: str = "/allegroHand_0/joint_cmd"
    joint_names: tuple[str, ...] = ALLEGRO_JOINT_NAMES
    """The driver's names of our 16 joints, in `JOINT_NAMES` order (used to reorder its messages)."""
    tactile_topic: str = "/allegro_tactile"
    tactile_type: str = "allegro_tactile_sensor/tactile_msgs"
    """'package/Type' of the skin message."""
    tactile_fields: tuple[tuple[str, str], ...] = field(default_factory=_default_tactile_fields)
    """(skin patch name, message field) for every patch of the skin."""
    rate_hz: float = 50.0
    stale_after_s: float = 0.1
    """A joint state or skin frame older than this stops the commands."""

    def __post_init__(self) -> None:
        check(self.ros_version in (1, 2), "ros.ros_version", f"must be 1 or 2, got {self.ros_version}")
        check(len(self.joint_names) == NUM_JOINTS, "ros.joint_names", f"needs {NUM_JOINTS} names")
        check("/" in self.tactile_type, "ros.tactile_type", f"must look like 'package/Type', got {self.tactile_type!r}")
        check(self.rate_hz > 0 and self.stale_after_s > 0, "ros.rate_hz", "rate and staleness must be positive")


# --- messages (no ROS needed) ------------------------------------------------------------
def decode_joint_state(msg: Any, names: tuple[str, ...] = ALLEGRO_JOINT_NAMES) -> tuple[np.ndarray, np.ndarray]:
    """(positions, velocities) (16,) each, in our joint order, from a JointState-like message."""
    pos = np.asarray(msg.position, dtype=np.float64)
    vel = np.asarray(msg.velocity, dtype=np.float64) if len(msg.velocity) else np.zeros_like(pos)
    if len(msg.name):
        index = {n: i for i, n in enumerate(msg.name)}
        missing = [n for n in names if n not in index]
        if missing:
            raise ValueError(f"joint state lacks joints {missing[:4]} (has {list(msg.name)[:4]}...)")
        order = [index[n] for n in names]
        pos, vel = pos[order], vel[order]
    if pos.shape != (NUM_JOINTS,) or vel.shape != (NUM_JOINTS,):
        raise ValueError(f"joint state must hold {NUM_JOINTS} positions and velocities, got {pos.shape}, {vel.shape}")
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


class Latest:
    """The newest message of a topic and when it arrived (callbacks write, the loop reads)."""

    def __init__(self) -> None:
        self.msg: Any = None
        self.stamp = -np.inf

    def __call__(self, msg: Any) -> None:
        self.msg, self.stamp = msg, time.monotonic()

    def fresh(self, max_age: float) -> bool:
        return self.msg is not None and time.monotonic() - self.stamp <= max_age


class ControlTick:
    """The ROS-free body of one tick: latest joint state + skin -> targets, or None when stale."""

    def __init__(self, cfg: RosConfig, controller, processor):
        self.cfg, self.controller, self.processor = cfg, controller, processor
        self.joints, self.skin = Latest(), Latest()

    def __call__(self) -> np.ndarray | None:
        if not (self.joints.fresh(self.cfg.stale_after_s) and self.skin.fresh(self.cfg.stale_after_s)):
            return None
        pos, vel = decode_joint_state(self.joints.msg, self.cfg.joint_names)
        readings = self.processor(decode_tactile(self.skin.msg, self.cfg.tactile_fields))
        return self.controller.step(pos, vel, readings)


# --- ROS I/O ------------------------------------------------------------------------------
class _Node:
    """Subscribe, publish, clock and rate over rospy or rclpy, imported only here."""

    def __init__(self, cfg: RosConfig):
        self.cfg = cfg
        try:
            if cfg.ros_version == 1:
                import rospy

                rospy.init_node(cfg.node_name)
                self._ros = rospy
            else:
                import rclpy

                rclpy.init()
                self._ros, self._node = rclpy, rclpy.create_node(cfg.node_name)
        except ImportError as err:
            name = "rospy" if cfg.ros_version == 1 else "rclpy"
            raise ImportError(f"{name} is not importable: source your ROS {cfg.ros_version} setup "
                              f"(e.g. /opt/ros/<distro>/setup.bash) in this shell first") from err
        from sensor_msgs.msg import JointState

        self.JointState = JointState

    def subscribe(self, topic: str, msg_type: type, callback: Callable[[Any], None]) -> None:
        if self.cfg.ros_version == 1:
            self._ros.Subscriber(topic, msg_type, callback, queue_size=1)
        else:
            self._node.create_subscription(msg_type, topic, callback, 1)

    def joint_command_publisher(self) -> Callable[[np.ndarray], None]:
        topic = self.cfg.joint_cmd_topic
        pub = self._ros.Publisher(topic, self.JointState, queue_size=1) if self.cfg.ros_version == 1 \
            else self._node.create_publisher(self.JointState, topic, 1)

        def publish(targets: np.ndarray) -> None:
            msg = self.JointState()
            msg.name = list(self.cfg.joint_names)
            msg.position = [float(x) for x in targets]
            if self.cfg.ros_version == 1:
                msg.header.stamp = self._ros.Time.now()
            else:
                msg.header.stamp = self._node.get_clock().now().to_msg()
            pub.publish(msg)

        return publish

    def ok(self) -> bool:
        return not self._ros.is_shutdown() if self.cfg.ros_version == 1 else self._ros.ok()

    def loop(self, tick: Callable[[], bool]) -> None:
        """Call tick() at rate_hz until it returns False or ROS shuts down."""
        period = 1.0 / self.cfg.rate_hz
        next_time = time.monotonic()
        try:
            while self.ok():
                if self.cfg.ros_version == 2:
                    self._ros.spin_once(self._node, timeout_sec=0.0)
                if tick() is False:
                    break
                next_time += period
                time.sleep(max(0.0, next_time - time.monotonic()))
        finally:
            if self.cfg.ros_version == 2:
                self._node.destroy_node()
                self._ros.shutdown()


def run_controller(cfg: RosConfig, controller, processor, log_every: int = 250) -> None:
    """Drive the hand with `controller` (a BlindController) at rate_hz until shutdown."""
    node = _Node(cfg)
    tick = ControlTick(cfg, controller, processor)
    node.subscribe(cfg.joint_state_topic, node.JointState, tick.joints)
    node.subscribe(cfg.tactile_topic, import_message(cfg.tactile_type), tick.skin)
    publish = node.joint_command_publisher()
    count = {"ticks": 0, "stale": 0}

    def step() -> bool:
        targets = tick()
        count["ticks"] += 1
        if targets is None:
            count["stale"] += 1
        else:
            publish(targets)
        if count["ticks"] % log_every == 0:
            print(f"[tacgnn] {count['ticks']} ticks, {count['stale']} without fresh joint/skin data", flush=True)
        return True

    node.loop(step)


def record_steps(cfg: RosConfig, targets: np.ndarray, out: str | Path) -> Path:
    """Command `targets` (T, 16) at rate_hz and save the joint recording for `tacgnn sysid`.

    Sample t is the newest joint state read just before targets[t] is published.
    """
    from tacgnn.tools.joint_recording import JointRecording, save_recording

    node = _Node(cfg)
    joints = Latest()
    node.subscribe(cfg.joint_state_topic, node.JointState, joints)
    publish = node.joint_command_publisher()
    deadline = time.monotonic() + 5.0
    while not joints.fresh(cfg.stale_after_s):
        if time.monotonic() > deadline:
            raise TimeoutError(f"no joint states on {cfg.joint_state_topic} within 5 s")
        time.sleep(0.01)
    times, measured = [], []
    start = time.monotonic()

    def step() -> bool:
        t = len(measured)
        if t == len(targets):
            return False
        times.append(time.monotonic() - start)
        measured.append(decode_joint_state(joints.msg, cfg.joint_names)[0])
        publish(targets[t])
        return True

    node.loop(step)
    rec = JointRecording(np.asarray(times), np.asarray(targets[:len(measured)], np.float64), np.asarray(measured),
                         source=str(out))
    return save_recording(rec, out)


def record_skin(cfg: RosConfig, frames: int, out: str | Path, layout=None) -> Path:
    """Save `frames` raw skin frames as .npz, one (frames, patch size) array per patch name."""
    from tacgnn.hand.skin_layout import default_skin

    layout = layout or default_skin()
    node = _Node(cfg)
    skin = Latest()
    node.subscribe(cfg.tactile_topic, import_message(cfg.tactile_type), skin)
    rows: list[dict[str, np.ndarray]] = []
    last = [skin.stamp]

    def step() -> bool:
        if skin.fresh(cfg.stale_after_s) and skin.stamp != last[0]:  # each driver frame once
            rows.append(decode_tactile(skin.msg, cfg.tactile_fields))
            last[0] = skin.stamp
        return len(rows) < frames

    node.loop(step)
    arrays = {p.name: np.stack([r[p.name] for r in rows]) for p in layout.patches}
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(out, **arrays)
    return out
