"""The blind controller as a ROS node: `tacgnn real-hand run`.

It subscribes to the joint states, the skin and the episode numbers, checks that the
first of them decode and fit the calibration before any command, warms the networks up,
then ticks (`tick.ControlTick`, on the thread that completes a state) until the hand sends
a negative episode number, `duration_s` runs out, ROS shuts down, or a topic sends only
malformed messages for too long (`MalformedInput`, one line naming topic and problem).
`--record` keeps every commanding tick in a bag (`run_bag`), `--stats` the loop's figures.
"""

from __future__ import annotations

import gc
import json
import logging
import time
from pathlib import Path

import numpy as np

from tacgnn.files import atomic_write_text
from tacgnn.real.messages import decode_joint_state, decode_tactile, stamp_ns, tactile_message_class
from tacgnn.real.node import RosNode
from tacgnn.real.ros_config import RosConfig
from tacgnn.real.run_bag import RunRecorder
from tacgnn.real.tick import ControlTick, LoopStats

log = logging.getLogger("tacgnn.real")


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
    node = RosNode(cfg)
    tick = ControlTick(cfg, controller, processor)
    tactile_cls = tactile_message_class(cfg)
    node.subscribe(cfg.joint_state_topic, node.JointState, tick.joints)
    node.subscribe(cfg.tactile_topic, tactile_cls, tick.skin)
    if cfg.episode_topic:
        node.subscribe(cfg.episode_topic, node.Int32, tick.episodes)
    publish = node.publisher(cfg.joint_cmd_topic, node.JointState)
    # wrong names, patch sizes, calibration: the messages are dropped, and a run of them stops
    # the node here, before any command
    node.wait_for(f"joint state on {cfg.joint_state_topic}", tick.joints, cfg.startup_timeout_s)
    node.wait_for(f"skin frame on {cfg.tactile_topic}", tick.skin, cfg.startup_timeout_s)
    node.wait_for_subscriber(publish, cfg.joint_cmd_topic, cfg.startup_timeout_s)
    pos, vel = decode_joint_state(tick.joints.msg, cfg.joint_names)
    controller.warm_up(pos, vel, processor(decode_tactile(tick.skin.msg, cfg.tactile_fields), track=False))
    log.info("joint states and skin frames check out; controlling at %.0f Hz", cfg.rate_hz)
    collector = IdleCollector()
    bag = RunRecorder(record, cfg, tactile_cls) if record else None
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
        stats.malformed_joint_states, stats.malformed_skin = tick.joints.malformed, tick.skin.malformed
        if bag is not None:
            bag.close()
        if stats_path:
            Path(stats_path).parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(stats_path, json.dumps(stats.summary(), indent=1))
    node.shutdown("control loop ended")
    return stats
