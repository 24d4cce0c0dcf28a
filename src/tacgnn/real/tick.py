"""The control loop without ROS: what one tick does, when ticks happen, and what the loop counts.

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
command, and one log line says so (one more when data is fresh again). A joint state or
skin frame that does not decode (wrong names or sizes, NaN, a field missing) is dropped
where it arrives (`messages.Latest`); a run of them stops the loop with `MalformedInput`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tacgnn.real.messages import Latest, MalformedInput, decode_joint_state, decode_tactile, stamp_ns
from tacgnn.real.ros_config import RosConfig
from tacgnn.real.safety_log import SafetyLog


class ControlTick:
    """The ROS-free body of one tick: latest joint state + skin -> targets, or None (hold).

    Holds (returns None) when the joint state or the skin frame is older than
    `cfg.stale_after_s`, with one log line when that starts and one when it ends. Joint
    states and skin frames that do not decode (or that the calibration refuses) are dropped
    as they arrive; `MalformedInput` when a run of them reaches the config's limits. A new
    value on the episode topic resets the controller at the pose of the first joint state
    received after it (the tick holds until one came); a negative value sets `stop`.
    """

    def __init__(self, cfg: RosConfig, controller, processor):
        self.cfg, self.controller, self.processor = cfg, controller, processor
        limit, timeout_s = cfg.malformed_limit, cfg.malformed_timeout_s
        self.joints = Latest(lambda m: decode_joint_state(m, cfg.joint_names),
                             f"joint state on {cfg.joint_state_topic}", limit, timeout_s)
        self.skin = Latest(lambda m: processor(decode_tactile(m, cfg.tactile_fields), track=False),  # a check
                           f"skin frame on {cfg.tactile_topic}", limit, timeout_s)
        self.episodes = Latest()
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

    def __call__(self) -> np.ndarray | None:
        for latest in (self.joints, self.skin):
            problem = latest.failure()
            if problem is not None:
                raise MalformedInput(problem)
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
    malformed_joint_states: int = 0
    """Joint states dropped because they did not decode (wrong names or sizes, NaN)."""
    malformed_skin: int = 0
    """Skin frames dropped because they did not decode or the calibration refused them."""

    @property
    def missed(self) -> int:
        return self.held + self.overruns

    def summary(self) -> dict:
        def pct(values, q):
            return round(1e3 * float(np.percentile(values, q)), 3) if values else None
        return {"ticks": self.ticks, "commands": self.commands, "missed_ticks": self.missed, "held_stale": self.held,
                "overruns": self.overruns, "episodes": self.episodes, "unpaired_skin": self.unpaired,
                "malformed_dropped": {"joint_states": self.malformed_joint_states, "skin": self.malformed_skin},
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

