"""The ROS side of the real hand: topics, message layout and the control loop's timing rules.

Topics (the authors' setup, all configurable here):

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

A config of its own (not part of the env's) because it describes the hand's driver, which
the simulator never sees; `tacgnn real-hand --set KEY=VALUE` overrides it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from tacgnn.config import check
from tacgnn.hand.allegro import NUM_JOINTS

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
    malformed_limit: int = 25
    """Malformed joint states (or skin frames) in a row that stop the run. Fewer are dropped and
    counted, the last good message stays in use (and ages into stale data: the hand holds)."""
    malformed_timeout_s: float = 1.0
    """A topic that sends only malformed messages for this long (s) stops the run, however few came."""

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
        check(isinstance(self.malformed_limit, int) and not isinstance(self.malformed_limit, bool)
              and self.malformed_limit >= 1, "ros.malformed_limit",
              f"must be an integer >= 1, got {self.malformed_limit!r}")
        check(0 < self.malformed_timeout_s < float("inf"), "ros.malformed_timeout_s",
              f"must be positive and finite, got {self.malformed_timeout_s}")
        check(0 <= self.pair_window_s < 1 / self.rate_hz, "ros.pair_window_s",
              f"must be in [0, one period = 1 / rate_hz = {1 / self.rate_hz:g} s), got {self.pair_window_s}")

    @property
    def period(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def stale_after_s(self) -> float:
        return self.stale_periods / self.rate_hz

