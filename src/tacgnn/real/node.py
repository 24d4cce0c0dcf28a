"""The ROS side of a node over rospy (ROS 1) or rclpy (ROS 2), imported only when a node starts.

Nothing imports ROS at module import, so every node's ROS-free parts load (and are
tested) on machines without ROS. `log_to_terminal` runs when a node starts: rospy
reconfigures Python's logging at `init_node` so that the root logger writes only to the
ROS log file, which would leave the controller's warnings (stale data, malformed
messages, safety limits) where an operator watching the terminal never sees them.
"""

from __future__ import annotations

import logging
import sys
import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from tacgnn.real.messages import Latest, MalformedInput
from tacgnn.real.ros_config import RosConfig
from tacgnn.real.tick import ArrivalTicker, LoopStats

log = logging.getLogger("tacgnn.real")


def log_to_terminal(logger: logging.Logger = log) -> None:
    """Make `logger`'s records reach the terminal (stderr) once: unless a handler on its way up to
    the root already writes to stdout or stderr, add one that does. Records still go on to the
    root logger's handlers (the ROS log file)."""
    current: logging.Logger | None = logger
    while current is not None:
        for handler in current.handlers:
            if (isinstance(handler, logging.StreamHandler) and not isinstance(handler, logging.FileHandler)
                    and getattr(handler, "stream", None) in (sys.stderr, sys.stdout)):
                return
        current = current.parent if current.propagate else None
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("[tacgnn] %(message)s"))
    logger.addHandler(handler)
    if logger.getEffectiveLevel() > logging.INFO:
        logger.setLevel(logging.INFO)


class RosNode:
    """Subscribe, publish, clock and rate over rospy or rclpy, imported only here."""

    def __init__(self, cfg: RosConfig, name: str | None = None):
        self.cfg = cfg
        try:
            if cfg.ros_version == 1:
                import rospy

                rospy.init_node(name or cfg.node_name, disable_signals=False)
                self._ros = rospy
            else:
                import rclpy

                rclpy.init()
                self._ros, self._node = rclpy, rclpy.create_node(name or cfg.node_name)
        except ImportError as err:
            lib = "rospy" if cfg.ros_version == 1 else "rclpy"
            raise ImportError(f"{lib} is not importable: source your ROS {cfg.ros_version} setup "
                              f"(e.g. /opt/ros/<distro>/setup.bash) in this shell first") from err
        log_to_terminal()
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Int32

        self.JointState, self.Int32 = JointState, Int32

    def subscribe(self, topic: str, msg_type: type, callback: Callable[[Any], None], queue_size: int = 1) -> None:
        """queue_size 1: only the newest message matters (messages that come in a burst are dropped
        but the last); more: the callback sees every message of a burst (to count them)."""
        if self.cfg.ros_version == 1:
            self._ros.Subscriber(topic, msg_type, callback, queue_size=queue_size, tcp_nodelay=True)
        else:
            self._node.create_subscription(msg_type, topic, callback, queue_size)

    def publisher(self, topic: str, msg_type: type, latch: bool = False) -> Callable[[Any], None]:
        """ROS 1: synchronous unless latched (queue_size None: the message is on the socket when
        publish returns, with no hand-over to rospy's queue thread and the scheduling delay it costs)."""
        if self.cfg.ros_version == 1:
            with warnings.catch_warnings():  # rospy warns about queue_size None, which is meant here
                warnings.simplefilter("ignore", SyntaxWarning)
                return self._ros.Publisher(topic, msg_type, queue_size=1 if latch else None, latch=latch,
                                           tcp_nodelay=True).publish
        return self._node.create_publisher(msg_type, topic, 1).publish

    def stamp(self, msg: Any) -> Any:
        if self.cfg.ros_version == 1:
            msg.header.stamp = self._ros.Time.now()
        else:
            msg.header.stamp = self._node.get_clock().now().to_msg()
        return msg

    def set_stamp(self, msg: Any, ns: int) -> Any:
        """Set a message's header stamp to `ns` nanoseconds (ROS time)."""
        secs, nsecs = divmod(int(ns), 1_000_000_000)
        if self.cfg.ros_version == 1:
            msg.header.stamp = self._ros.Time(secs, nsecs)
        else:
            msg.header.stamp.sec, msg.header.stamp.nanosec = secs, nsecs
        return msg

    def joint_state(self, position: np.ndarray, velocity: np.ndarray | None = None, stamp: int | None = None) -> Any:
        """A JointState of our joints; stamped `stamp` (ns) if given, else now."""
        msg = self.JointState()
        msg.name = list(self.cfg.joint_names)
        msg.position = position.tolist() if isinstance(position, np.ndarray) else [float(x) for x in position]
        if velocity is not None:
            msg.velocity = velocity.tolist() if isinstance(velocity, np.ndarray) else [float(x) for x in velocity]
        return self.stamp(msg) if stamp is None else self.set_stamp(msg, stamp)

    def ok(self) -> bool:
        return not self._ros.is_shutdown() if self.cfg.ros_version == 1 else self._ros.ok()

    def wait_for_subscriber(self, publish: Callable[[Any], None], topic: str, timeout: float) -> None:
        """Wait until someone listens to `publish`'s topic (ROS 1), so the first command is not lost."""
        if self.cfg.ros_version != 1:
            return
        publisher = getattr(publish, "__self__", None)
        deadline = time.monotonic() + timeout
        while publisher is not None and publisher.get_num_connections() == 0:
            if time.monotonic() > deadline or not self.ok():
                raise TimeoutError(f"nobody subscribes to {topic} within {timeout:.0f} s: "
                                   "is the hand's driver running?")
            time.sleep(0.01)

    def spin_once(self, timeout: float = 0.0) -> None:
        if self.cfg.ros_version == 2:
            self._ros.spin_once(self._node, timeout_sec=timeout)

    def wait_for(self, what: str, latest: Latest, timeout: float) -> None:
        """Wait for `latest`'s first (well-formed) message; `MalformedInput` if only malformed ones come."""
        deadline = time.monotonic() + timeout
        while latest.msg is None:
            problem = latest.failure()
            if problem is not None:
                raise MalformedInput(problem)
            if time.monotonic() > deadline or not self.ok():
                raise TimeoutError(f"no {what} within {timeout:.0f} s: is the hand's driver running?")
            self.spin_once()
            latest.arrived.wait(0.01)

    def loop(self, tick: Callable[[float], bool], start: float | None = None, stats: LoopStats | None = None) -> None:
        """Call tick(scheduled_time) at rate_hz from `start` until it returns False or ROS shuts down;
        a tick that starts more than a period late skips the periods it missed (counted in stats)."""
        period = self.cfg.period
        next_time = time.monotonic() if start is None else start
        try:
            while self.ok():
                delay = next_time - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                self.spin_once()
                if tick(next_time) is False:
                    break
                next_time += period
                behind = int((time.monotonic() - next_time) // period)
                if behind > 0:
                    next_time += behind * period
                    if stats is not None:
                        stats.overruns += behind
                    log.warning("control loop %d period(s) behind; skipped them", behind)
        finally:
            if self.cfg.ros_version == 2:
                self._node.destroy_node()
                self._ros.shutdown()

    def loop_on(self, latest: Latest, tick: Callable[[float], bool], stats: LoopStats | None = None,
                paired: Callable[[], bool] | None = None, partner: Latest | None = None) -> None:
        """Call tick(arrival time) for each new message of `latest`, at most rate_hz, until it returns
        False or ROS shuts down (see `ArrivalTicker`); returns when the loop ends."""
        ticker = ArrivalTicker(self.cfg, latest, tick, stats, paired, partner)
        try:
            ticker.run(self.ok, self.spin_once if self.cfg.ros_version == 2 else None)
        finally:
            latest.listener = None
            if partner is not None:
                partner.listener = None

    def shutdown(self, reason: str) -> None:
        if self.cfg.ros_version == 1:
            self._ros.signal_shutdown(reason)
