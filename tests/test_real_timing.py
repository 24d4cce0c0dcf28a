"""The control loop's timing rules without ROS: stamps, joint state and skin of one instant,
one command per state of the hand, no state dropped for transport jitter."""

import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from tacgnn.real.controller_node import IdleCollector
from tacgnn.real.messages import Latest, stamp_ns
from tacgnn.real.node import RosNode
from tacgnn.real.ros_config import ALLEGRO_JOINT_NAMES, RosConfig
from tacgnn.real.tick import ArrivalTicker, ControlTick, LoopStats

PERIOD_NS = 20_000_000


def stamped(ns: int | None, **fields) -> SimpleNamespace:
    """A message with a ROS 1 header stamped `ns` (None: a message without a header)."""
    if ns is None:
        return SimpleNamespace(**fields)
    secs, nsecs = divmod(ns, 1_000_000_000)
    return SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(secs=secs, nsecs=nsecs)), **fields)


class CountingController:
    """A controller stand-in that counts its steps (the env steps once per state)."""

    def __init__(self):
        self.steps, self.resets = 0, 0

    def reset(self, _pos):
        self.resets += 1

    def step(self, pos, _vel, _skin):
        self.steps += 1
        return np.asarray(pos)


def make_tick(cfg: RosConfig) -> ControlTick:
    return ControlTick(cfg, CountingController(), lambda patches, track=True: np.zeros(1, np.float32))


def joint_state(ns: int | None) -> SimpleNamespace:
    return stamped(ns, name=list(ALLEGRO_JOINT_NAMES), position=[0.1] * 16, velocity=[0.0] * 16)


def skin(ns: int | None, cfg: RosConfig) -> SimpleNamespace:
    return stamped(ns, **{attr: [0.0] for _, attr in cfg.tactile_fields})


def test_stamps_in_nanoseconds_ros1_and_ros2():
    assert stamp_ns(stamped(3_000_000_007)) == 3_000_000_007
    ros2 = SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=2, nanosec=5)))
    assert stamp_ns(ros2) == 2_000_000_005
    assert stamp_ns(stamped(None)) is None
    assert stamp_ns(stamped(0)) is None  # a driver that does not stamp


def test_the_tick_waits_for_the_skin_of_its_joint_states_instant():
    """The joint state arrives before its skin frame: the tick runs when the frame comes, on the
    thread that delivers it; a frame that never comes: the tick runs after the pair window.
    (At 10 Hz with a wide window, so that a loaded test machine's scheduling stays inside it.)"""
    cfg = RosConfig(rate_hz=10.0, pair_window_s=0.08)
    period_ns = int(1e9 / cfg.rate_hz)
    tick = make_tick(cfg)
    running = threading.Event()
    running.set()
    threads: list[str] = []

    def step(_arrived):
        if tick() is not None:  # (ticks on timeouts hold: nothing new)
            threads.append(threading.current_thread().name)
        return True

    ticker = ArrivalTicker(cfg, tick.joints, step, LoopStats(), tick.paired, tick.skin)
    loop = threading.Thread(target=ticker.run, args=(running.is_set,), name="loop", daemon=True)
    loop.start()
    t = 10 * period_ns
    tick.skin(skin(t - period_ns, cfg))  # the frame of the step before
    tick.joints(joint_state(t))
    assert not tick.paired() and threads == []
    sender = threading.Thread(target=tick.skin, args=(skin(t, cfg),), name="skin")
    sender.start()
    sender.join()
    assert threads == ["skin"] and tick.unpaired == 0
    began = time.monotonic()
    tick.joints(joint_state(t + period_ns))  # its frame does not come: after the window, the newest one
    while len(threads) < 2 and time.monotonic() - began < 2.0:
        time.sleep(0.001)
    assert threads == ["skin", "loop"] and time.monotonic() - began >= cfg.pair_window_s
    assert tick.unpaired == 1 and tick.controller.steps == 2
    running.clear()
    loop.join()


def test_an_error_in_a_tick_ends_the_loop_on_its_thread():
    cfg = RosConfig()
    latest = Latest()
    running = threading.Event()
    running.set()

    def tick(_arrived):
        raise FloatingPointError("the policy returned non-finite actions")

    ticker = ArrivalTicker(cfg, latest, tick)
    threading.Timer(0.01, latest, (joint_state(PERIOD_NS),)).start()
    with pytest.raises(FloatingPointError, match="non-finite"):
        ticker.run(running.is_set)


def test_without_stamps_a_frame_newer_than_the_last_tick_pairs():
    cfg = RosConfig()
    tick = make_tick(cfg)
    tick.joints(joint_state(None))
    tick.skin(skin(None, cfg))
    assert tick.paired() and tick() is not None
    tick.joints(joint_state(None))
    assert not tick.paired()  # the skin frame was used by the last tick
    tick.skin(skin(None, cfg))
    assert tick.paired()


def test_a_state_is_answered_once():
    cfg = RosConfig()
    tick = make_tick(cfg)
    tick.joints(joint_state(PERIOD_NS))
    tick.skin(skin(PERIOD_NS, cfg))
    assert tick() is not None
    assert tick() is None and tick.held == "answered"  # a timeout tick on the same state
    assert tick.controller.steps == 1


def fake_node(cfg: RosConfig, running: threading.Event) -> RosNode:
    """The loop of `RosNode` without ROS behind it."""
    node = RosNode.__new__(RosNode)
    node.cfg = cfg
    node.ok = running.is_set
    node.spin_once = lambda: None
    return node


def test_every_stamped_state_is_ticked_despite_arrival_jitter():
    """States one period apart by their stamps but arriving 0.3 periods late or early (a loaded hand
    or network): none is skipped as 'faster than the control rate'; a state the hand never sent is
    an overrun. (At 10 Hz, so that a loaded test machine's scheduling does not add jitter of its own.)"""
    cfg = RosConfig(rate_hz=10.0)
    period_ns = int(1e9 / cfg.rate_hz)
    latest = Latest()
    running = threading.Event()
    running.set()
    ticked: list[int] = []
    stats = LoopStats(commands=1)
    sent = [k for k in range(12) if k != 7]  # state 7 is lost
    jitter = cfg.period * np.array([0.0, 0.3, -0.3, 0.3, 0.0, -0.3, 0.3, 0.0, -0.3, 0.0, 0.3, 0.0])

    def hand():
        start = time.monotonic() + 0.05
        for k in sent:
            time.sleep(max(0.0, start + cfg.period * k + jitter[k] - time.monotonic()))
            latest(joint_state(period_ns * (k + 1)))
        time.sleep(0.05)
        running.clear()

    def tick(_arrived):
        if latest.count and (not ticked or ticked[-1] != latest.count):
            ticked.append(latest.count)
        return True

    thread = threading.Thread(target=hand)
    thread.start()
    fake_node(cfg, running).loop_on(latest, tick, stats)
    thread.join()
    assert ticked == list(range(1, len(sent) + 1))  # every state, once
    assert stats.overruns == 1


def test_garbage_is_collected_between_ticks_only():
    """Between `start` and `stop` nothing is collected automatically; `collect` (after a command)
    runs the collections the thresholds ask for, and reference cycles are freed there."""
    import gc
    import weakref

    class Node:
        pass

    collector = IdleCollector()
    seen: list[int] = []

    def record(phase, info):
        if phase == "start":
            seen.append(info["generation"])

    collector.start()
    gc.callbacks.append(record)
    try:
        assert not gc.isenabled()
        cycles = []
        for _ in range(3 * gc.get_threshold()[0]):
            a, b = Node(), Node()
            a.other, b.other = b, a
            cycles.append(weakref.ref(a))
        del a, b
        assert seen == [] and all(ref() is not None for ref in cycles)  # left for the idle time
        for _ in range(20):
            collector.collect()
        assert seen and all(ref() is None for ref in cycles)
    finally:
        gc.callbacks.remove(record)
        collector.stop()
        gc.unfreeze()
    assert gc.isenabled()
