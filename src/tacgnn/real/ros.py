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
  ``palm_Value``): check them against your driver's .msg file. Without the message's
  package, its definition is taken as one ``float32[]`` per field (`bag.tactile_definition`);
* episodes, ``std_msgs/Int32`` on ``/tacgnn/episode`` (optional): a new value starts an
  episode (the controller resets, as the env does), a negative value ends the run.

Control ticks follow the joint states, at most 50 Hz (`clock`: with a hand that
publishes at the control rate each tick reads the state it just measured), or run on a
fixed 50 Hz clock for faster drivers. Each tick takes the newest joint state and the skin
frame of the same instant: the tick waits up to ``pair_window_s`` for it (same header
stamp where both messages carry one, else a frame newer than the last tick), so joint
angles and skin are never taken from two different steps of the hand when both arrive.
The tick runs on the thread that receives whichever of the two comes last
(`ArrivalTicker`), with no hand-over to another thread.
The command's header stamp is the stamp of the joint state it answers (a driver can
tell how late it is). When the joint state or the skin frame is older
than ``stale_periods`` control periods the tick commands nothing, so the hand holds its last
command, and one log line says so (one more when data is fresh again). Before the first
command, the first joint state and skin frame are checked (joint names, patch sizes,
calibration layout): a mismatch stops with an error that names it.
"""

from __future__ import annotations

import gc
import importlib
import json
import logging
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tacgnn.config import check
from tacgnn.hand.allegro import JOINT_NAMES

NUM_JOINTS = len(JOINT_NAMES)
ALLEGRO_JOINT_NAMES = tuple(f"joint_{i}.0" for i in range(NUM_JOINTS))
log = logging.getLogger("tacgnn.real")


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
    episode_topic: str = "/tacgnn/episode"
    """std_msgs/Int32: a new value starts an episode, a negative one ends the run ('' : not used)."""
    rate_hz: float = 50.0
    stale_periods: float = 2.0
    """A joint state or skin frame older than this many control periods stops the commands."""
    clock: str = "joint_states"
    """'joint_states': a tick follows each new joint state, at most rate_hz (for a hand that
    publishes at the control rate, like the simulated one: each tick reads the state just
    measured); 'timer': a fixed rate_hz clock, started `align_delay_s` after a joint state
    (for a driver that publishes faster than the control rate)."""
    align_delay_s: float = 0.001
    pair_window_s: float = 0.005
    """After a new joint state, wait up to this long for the skin frame of the same instant
    (clock 'joint_states'); then tick with the newest frame there is."""
    startup_timeout_s: float = 10.0
    """How long to wait for the first joint state and skin frame."""

    def __post_init__(self) -> None:
        check(self.ros_version in (1, 2), "ros.ros_version", f"must be 1 or 2, got {self.ros_version}")
        check(len(self.joint_names) == NUM_JOINTS, "ros.joint_names", f"needs {NUM_JOINTS} names")
        check("/" in self.tactile_type, "ros.tactile_type", f"must look like 'package/Type', got {self.tactile_type!r}")
        check(self.rate_hz > 0, "ros.rate_hz", f"must be positive, got {self.rate_hz}")
        check(self.stale_periods > 0, "ros.stale_periods", f"must be positive, got {self.stale_periods}")
        check(0 <= self.align_delay_s < 1 / self.rate_hz, "ros.align_delay_s",
              f"must be in [0, one period = 1 / rate_hz = {1 / self.rate_hz:g} s), got {self.align_delay_s}")
        check(self.clock in ("joint_states", "timer"), "ros.clock",
              f"must be joint_states or timer, got {self.clock!r}")
        check(self.startup_timeout_s > 0, "ros.startup_timeout_s", "must be positive")
        check(0 <= self.pair_window_s < 1 / self.rate_hz, "ros.pair_window_s",
              f"must be in [0, one period = 1 / rate_hz = {1 / self.rate_hz:g} s), got {self.pair_window_s}")

    @property
    def period(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def stale_after_s(self) -> float:
        return self.stale_periods / self.rate_hz


# --- messages (no ROS needed) ------------------------------------------------------------
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

    from tacgnn.real.bag import tactile_definition

    log.info("message package of %s not found: using float32[] fields %s", cfg.tactile_type,
             [a for _, a in cfg.tactile_fields][:3] + ["..."])
    return genpy.dynamic.generate_dynamic(cfg.tactile_type, tactile_definition(cfg.tactile_fields))[cfg.tactile_type]


class Latest:
    """The newest message of a topic, when it arrived, and how many came (callbacks write, the loop reads).

    `last` holds (message, arrival time) as one tuple, so a reader never pairs a message
    with another message's time.
    """

    def __init__(self) -> None:
        self.last: tuple[Any, float] = (None, -np.inf)
        self.count = 0
        self.arrived = threading.Event()
        self.listener: Callable[[], None] | None = None
        """Called on the receiving thread after each message (the control loop ticks there)."""

    def __call__(self, msg: Any) -> None:
        self.last = (msg, time.monotonic())
        self.count += 1
        self.arrived.set()
        if self.listener is not None:
            self.listener()

    @property
    def msg(self) -> Any:
        return self.last[0]

    @property
    def stamp(self) -> float:
        return self.last[1]

    @stamp.setter
    def stamp(self, value: float) -> None:
        self.last = (self.last[0], value)

    def fresh(self, max_age: float) -> bool:
        msg, stamp = self.last
        return msg is not None and time.monotonic() - stamp <= max_age


class ControlTick:
    """The ROS-free body of one tick: latest joint state + skin -> targets, or None (hold).

    Holds (returns None) when the joint state or the skin frame is older than
    `cfg.stale_after_s`, with one log line when that starts and one when it ends. A new
    value on the episode topic resets the controller at the pose of the first joint state
    received after it (the tick holds until one came); a negative value sets `stop`.
    """

    def __init__(self, cfg: RosConfig, controller, processor):
        from tacgnn.real.controller import SafetyLog

        self.cfg, self.controller, self.processor = cfg, controller, processor
        self.joints, self.skin, self.episodes = Latest(), Latest(), Latest()
        self.safety = SafetyLog()
        self.episode: int | None = None
        self.stop = False
        self.used: tuple[Any, Any] | None = None
        """The (joint state, skin) messages of the last tick that commanded."""
        self.reset_now = False
        """Whether the last tick started an episode."""
        self.unpaired = 0
        """Commanding ticks whose skin frame was stamped with another instant than their joint state."""
        self.held = ""
        """Why the last tick did not command: 'stale' (old data), 'episode' (waiting for the new
        episode's first state), 'answered' (no joint state since the last command), '' (it commanded)."""
        self._skin_seen = 0

    def paired(self) -> bool:
        """Whether the newest skin frame is of the newest joint state's instant: the same header
        stamp where both have one, else a frame that arrived since the last tick."""
        joint_stamp, skin_stamp = stamp_ns(self.joints.msg), stamp_ns(self.skin.msg)
        if joint_stamp is not None and skin_stamp is not None:
            return skin_stamp >= joint_stamp
        return self.skin.count > self._skin_seen

    def check_inputs(self) -> None:
        """Decode the newest joint state and skin frame and run them through the calibration:
        a ValueError naming the problem if they do not fit (called before any command)."""
        decode_joint_state(self.joints.msg, self.cfg.joint_names)
        self.processor(decode_tactile(self.skin.msg, self.cfg.tactile_fields))

    def __call__(self) -> np.ndarray | None:
        (joint_msg, joint_t), (skin_msg, skin_t), (episode_msg, episode_t) = \
            self.joints.last, self.skin.last, self.episodes.last
        now, max_age = time.monotonic(), self.cfg.stale_after_s
        joints_ok, skin_ok = now - joint_t <= max_age, now - skin_t <= max_age
        self.safety.note("stale joint state", not joints_ok,
                         f"stale joint state: none newer than {1e3 * max_age:.0f} ms on "
                         f"{self.cfg.joint_state_topic}; holding position (no commands)")
        self.safety.note("stale skin", not skin_ok,
                         f"stale skin: no frame newer than {1e3 * max_age:.0f} ms on "
                         f"{self.cfg.tactile_topic}; holding position (no commands)")
        self.reset_now = False
        self.held = ""
        new_episode = episode_msg is not None and int(episode_msg.data) != self.episode
        if new_episode and int(episode_msg.data) < 0:
            self.stop = True
            return None
        if not (joints_ok and skin_ok):
            self.held = "stale"
            return None
        if new_episode and joint_t < episode_t:  # the episode's first joint state is still to come
            self.held = "episode"
            return None
        if self.used is not None and joint_msg is self.used[0]:  # each state is answered once, as in the env
            self.held = "answered"
            return None
        if new_episode:
            self.episode = int(episode_msg.data)
            self.reset_now = True
        pos, vel = decode_joint_state(joint_msg, self.cfg.joint_names)
        if self.reset_now:
            self.controller.reset(pos)
        readings = self.processor(decode_tactile(skin_msg, self.cfg.tactile_fields))
        self.used = (joint_msg, skin_msg)
        self._skin_seen = self.skin.count
        joint_stamp, skin_stamp = stamp_ns(joint_msg), stamp_ns(skin_msg)
        self.unpaired += joint_stamp is not None and skin_stamp is not None and joint_stamp != skin_stamp
        return self.controller.step(pos, vel, readings)


@dataclass
class LoopStats:
    """What the control loop did: ticks, commands, holds and how long each tick took."""

    ticks: int = 0
    commands: int = 0
    held: int = 0
    """Ticks without a command because of stale data (after the first command)."""
    overruns: int = 0
    """Periods skipped because a tick started more than one period late."""
    episodes: int = 0
    latency_s: list[float] = field(default_factory=list)
    """Per command: from the tick's scheduled time (clock 'joint_states': the joint state's arrival) to the
    command's publication."""
    compute_s: list[float] = field(default_factory=list)
    """Per command: from the tick's start to the command's publication."""
    slow_ticks: list[tuple[int, float, float]] = field(default_factory=list)
    """(tick, ms late to start, ms computing) of ticks whose command came more than a period late."""
    unpaired: int = 0
    """Commands computed from a joint state and a skin frame stamped with different instants."""

    @property
    def missed(self) -> int:
        return self.held + self.overruns

    def summary(self) -> dict:
        def pct(values, q):
            return round(1e3 * float(np.percentile(values, q)), 3) if values else None
        return {"ticks": self.ticks, "commands": self.commands, "missed_ticks": self.missed, "held_stale": self.held,
                "overruns": self.overruns, "episodes": self.episodes, "unpaired_skin": self.unpaired,
                "tick_to_command_ms": {"p50": pct(self.latency_s, 50), "p99": pct(self.latency_s, 99),
                                       "max": pct(self.latency_s, 100)},
                "compute_ms": {"p50": pct(self.compute_s, 50), "p99": pct(self.compute_s, 99),
                               "max": pct(self.compute_s, 100)},
                "slow_ticks": self.slow_ticks[:50]}


class ArrivalTicker:
    """Ticks on the thread that receives the message completing a state, not on a waiting loop.

    Why: handing each message to a main loop costs a thread wake-up per tick, which on
    loaded cores is the scheduler's to grant; ticking in the receive callback (ROS 1:
    rospy's thread of that topic) starts the tick as soon as the state is complete.

    A new message of `latest` ticks at once if `paired()` (its partner, e.g. the skin frame
    of the same instant, is there), else when `partner`'s next message makes it paired,
    else `pair_window_s` after its arrival with what there is. Messages closer than 0.75
    periods to the last one ticked on are skipped (a driver that publishes faster than the
    control rate), judged by their header stamps where they have them (the hand's clock,
    free of transport jitter), else by arrival; periods between two ticked messages
    without a message count as overruns in stats. When no message comes for 1.5 periods,
    the loop ticks anyway (the tick sees stale data and holds). Ticks never overlap (one
    lock); an exception in a tick ends the loop and is raised by `run`.
    """

    def __init__(self, cfg: RosConfig, latest: Latest, tick: Callable[[float], bool], stats: LoopStats | None = None,
                 paired: Callable[[], bool] | None = None, partner: Latest | None = None):
        self.cfg, self.latest, self.tick, self.stats, self.paired = cfg, latest, tick, stats, paired
        self.lock = threading.Lock()
        self.wake = threading.Event()  # the waiting loop has a new deadline or should stop
        self.seen = latest.count
        self.last = time.monotonic()  # the last tick: for the timeout
        self.last_fresh: float | None = None  # arrival of the last message ticked on
        self.last_stamp: int | None = None
        self.pending: float | None = None  # arrival of a message waiting for its partner
        self.stopped = False
        self.error: BaseException | None = None
        latest.listener = self.on_message
        if partner is not None:
            partner.listener = self.on_partner

    def on_message(self) -> None:
        with self.lock:
            if self.stopped or self.latest.count == self.seen:
                return
            self.seen = self.latest.count
            msg, arrived = self.latest.last
            period, stamp = self.cfg.period, stamp_ns(msg)
            if stamp is not None and self.last_stamp is not None:
                gap = (stamp - self.last_stamp) * 1e-9
            else:
                gap = np.inf if self.last_fresh is None else arrived - self.last_fresh
            if gap < 0.75 * period:
                return  # faster than the control rate: wait for the next one
            if np.isfinite(gap) and gap > 1.5 * period and self.stats is not None and self.stats.commands:
                self.stats.overruns += int(round(gap / period)) - 1
            self.last_stamp, self.last_fresh, self.pending = stamp, arrived, arrived
            if self.paired is None or self.paired():
                self._fire()
            else:
                self.wake.set()  # the loop waits for the pair window now

    def on_partner(self) -> None:
        with self.lock:
            if self.pending is not None and not self.stopped and self.paired is not None and self.paired():
                self._fire()

    def _fire(self, now: float | None = None) -> None:
        """Tick (lock held): on the pending message, or on none at `now` (a timeout)."""
        arrived = self.pending if now is None else now
        assert arrived is not None
        self.pending = None
        self.last = time.monotonic()
        try:
            go_on = self.tick(arrived)
        except BaseException as err:  # raised again by run(), on the loop's thread
            self.error, go_on = err, False
        if go_on is False:
            self.stopped = True
            self.wake.set()

    def run(self, ok: Callable[[], bool], spin: Callable[[float], None] | None = None) -> None:
        """Wait here for the pair windows and timeouts until a tick returns False or `ok()` fails;
        `spin(timeout)`: deliver messages on this thread (ROS 2) instead of sleeping."""
        period = self.cfg.period
        while ok() and not self.stopped:
            self.wake.clear()
            with self.lock:
                now = time.monotonic()
                if self.pending is not None:
                    deadline = self.pending + self.cfg.pair_window_s
                    if now >= deadline:
                        self._fire()  # the partner did not come: the newest there is
                        continue
                else:
                    deadline = self.last + 1.5 * period
                    if now >= deadline:
                        self._fire(now)
                        continue
            left = min(deadline - now, 0.1)
            if spin is not None:
                spin(min(left, 0.005))
            else:
                self.wake.wait(left)
        with self.lock:
            self.stopped = True
        if self.error is not None:
            raise self.error


# --- ROS I/O ------------------------------------------------------------------------------
class _Node:
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
        deadline = time.monotonic() + timeout
        while latest.msg is None:
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


class IdleCollector:
    """Python's garbage collection between ticks, not inside them.

    Why: measured in the controller node, automatic collections of generation 1 took 1-5 ms
    (about 30 a minute) and fell on ticks, where they made the latency's p99. `start`
    freezes what is loaded (it stays out of every later scan) and turns automatic
    collection off; `collect`, called right after a command is published, runs the
    collection the interpreter's thresholds ask for, if any; `stop` turns it back on.
    """

    def start(self) -> None:
        gc.collect()
        gc.freeze()
        gc.disable()

    def collect(self) -> None:
        counts, thresholds = gc.get_count(), gc.get_threshold()
        if counts[0] < thresholds[0]:
            return
        generation = 0
        while generation < 2 and counts[generation + 1] + 1 >= thresholds[generation + 1]:
            generation += 1
        gc.collect(generation)

    def stop(self) -> None:
        gc.enable()


def run_controller(cfg: RosConfig, controller, processor, duration_s: float = 0.0, record: str | Path | None = None,
                   stats_path: str | Path | None = None, log_every: int = 3000) -> LoopStats:
    """Drive the hand with `controller` (a BlindController) at rate_hz until shutdown, the end
    of `duration_s` (0: no end) or a negative episode number; optionally record the run as a bag."""
    node = _Node(cfg)
    tick = ControlTick(cfg, controller, processor)
    tactile_cls = tactile_message_class(cfg)
    node.subscribe(cfg.joint_state_topic, node.JointState, tick.joints)
    node.subscribe(cfg.tactile_topic, tactile_cls, tick.skin)
    if cfg.episode_topic:
        node.subscribe(cfg.episode_topic, node.Int32, tick.episodes)
    publish = node.publisher(cfg.joint_cmd_topic, node.JointState)
    node.wait_for(f"joint state on {cfg.joint_state_topic}", tick.joints, cfg.startup_timeout_s)
    node.wait_for(f"skin frame on {cfg.tactile_topic}", tick.skin, cfg.startup_timeout_s)
    tick.check_inputs()  # wrong names, patch sizes, calibration: fail before any command
    node.wait_for_subscriber(publish, cfg.joint_cmd_topic, cfg.startup_timeout_s)
    pos, vel = decode_joint_state(tick.joints.msg, cfg.joint_names)
    controller.warm_up(pos, vel, processor(decode_tactile(tick.skin.msg, cfg.tactile_fields)))
    log.info("joint states and skin frames check out; controlling at %.0f Hz", cfg.rate_hz)
    collector = IdleCollector()
    bag = _RunRecorder(record, cfg, tactile_cls) if record else None
    stats = LoopStats()
    start = None
    if cfg.clock == "timer":
        tick.joints.arrived.clear()
        if tick.joints.arrived.wait(cfg.startup_timeout_s):
            start = tick.joints.stamp + cfg.align_delay_s
    end = time.monotonic() + duration_s if duration_s > 0 else np.inf

    def step(scheduled: float) -> bool:
        began = time.monotonic()
        targets = tick()
        stats.ticks += 1
        if tick.stop or began > end:
            return False
        if targets is None:
            stats.held += stats.commands > 0 and tick.held == "stale"
        else:
            assert tick.used is not None
            msg = node.joint_state(targets, stamp=stamp_ns(tick.used[0]))  # the state it answers
            publish(msg)
            done = time.monotonic()
            stats.commands += 1
            stats.episodes += tick.reset_now
            stats.latency_s.append(done - scheduled)
            stats.compute_s.append(done - began)
            if done - scheduled > cfg.period:
                stats.slow_ticks.append((stats.ticks, round(1e3 * (began - scheduled), 2),
                                         round(1e3 * (done - began), 2)))
            if bag is not None:
                bag.tick(began, tick, msg)
            collector.collect()  # the command is out: the time until the next state is idle
        if stats.ticks % log_every == 0:
            print(f"[tacgnn] {stats.ticks} ticks, {stats.commands} commands, {stats.missed} missed", flush=True)
        return True

    try:
        collector.start()
        if cfg.clock == "timer":
            node.loop(step, start, stats)
        else:
            node.loop_on(tick.joints, step, stats, paired=tick.paired, partner=tick.skin)
    finally:
        collector.stop()
        stats.unpaired = tick.unpaired
        if bag is not None:
            bag.close()
        if stats_path:
            Path(stats_path).parent.mkdir(parents=True, exist_ok=True)
            Path(stats_path).write_text(json.dumps(stats.summary(), indent=1))
    node.shutdown("control loop ended")
    return stats


class _RunRecorder:
    """Writes, per commanding tick, the joint state and skin message it used and its command."""

    def __init__(self, path: str | Path, cfg: RosConfig, tactile_cls: Any):  # a generated ROS message class
        from tacgnn.real.bag import BagWriter

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
    from tacgnn.real.bag import read_bag

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


def record_steps(cfg: RosConfig, targets: np.ndarray, out: str | Path) -> Path:
    """Command `targets` (T, 16) at rate_hz and save a bag for `tacgnn sysid` (or .npz/.csv).

    The bag holds every joint state as received and every command as sent; sample t of
    the recording is the newest joint state read just before targets[t] is published.
    """
    from tacgnn.real.bag import BagWriter
    from tacgnn.tools.joint_recording import JointRecording, save_recording

    out = Path(out)
    node = _Node(cfg, "tacgnn_record_steps")
    joints = Latest()
    bag = BagWriter(out) if out.suffix == ".bag" else None
    t0 = time.monotonic()

    def on_joint_state(msg):
        joints(msg)
        if bag is not None:
            bag.write_msg(cfg.joint_state_topic, msg, joints.stamp - t0 + 1.0)

    node.subscribe(cfg.joint_state_topic, node.JointState, on_joint_state)
    publish = node.publisher(cfg.joint_cmd_topic, node.JointState)
    node.wait_for(f"joint state on {cfg.joint_state_topic}", joints, cfg.startup_timeout_s)
    decode_joint_state(joints.msg, cfg.joint_names)  # names checked before the first command
    times: list[float] = []
    measured: list[np.ndarray] = []

    def step(_scheduled: float) -> bool:
        t = len(measured)
        if t == len(targets):
            return False
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
    from tacgnn.hand.skin_layout import default_skin
    from tacgnn.real.bag import BagWriter

    layout = layout or default_skin()
    out = Path(out)
    node = _Node(cfg, "tacgnn_record_skin")
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
    np.savez(out, **arrays)  # type: ignore[arg-type]  # numpy's stub matches **arrays against allow_pickle
    return out
