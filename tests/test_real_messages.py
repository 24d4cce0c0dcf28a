"""Messages the controller cannot use, without ROS: dropped where they arrive, counted, logged once on
the terminal, and only a run of them (a number in a row, or a time) stops the node."""

import logging
import sys
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from tacgnn.hand.skin_layout import default_skin
from tacgnn.real.messages import Latest, MalformedInput, decode_joint_state
from tacgnn.real.node import RosNode, log_to_terminal
from tacgnn.real.ros_config import ALLEGRO_JOINT_NAMES, RosConfig
from tacgnn.real.skin import SkinProcessor, calibrate
from tacgnn.real.tick import ArrivalTicker, ControlTick, LoopStats


class CountingController:
    def __init__(self):
        self.steps = 0

    def reset(self, _pos):
        pass

    def step(self, pos, _vel, _skin):
        self.steps += 1
        return np.asarray(pos)


def joint_state(**changes) -> SimpleNamespace:
    fields = {"name": list(ALLEGRO_JOINT_NAMES), "position": [0.1] * 16, "velocity": [0.0] * 16}
    return SimpleNamespace(**{**fields, **changes})


def skin_frame(cfg: RosConfig, **sizes) -> SimpleNamespace:
    """A skin message of the default layout at rest; `sizes`: patch -> another length (malformed)."""
    fields = dict(cfg.tactile_fields)
    return SimpleNamespace(**{fields[p.name]: [1.0] * sizes.get(p.name, p.size) for p in default_skin().patches})


def make_tick(cfg: RosConfig) -> ControlTick:
    layout = default_skin()
    processor = SkinProcessor(calibrate(np.ones((2, layout.num_taxels)), layout), layout)
    return ControlTick(cfg, CountingController(), processor)


MALFORMED_STATES = {
    "another hand's names": joint_state(name=[f"right_{n}" for n in ALLEGRO_JOINT_NAMES]),
    "15 joints": joint_state(name=list(ALLEGRO_JOINT_NAMES[:15]), position=[0.1] * 15, velocity=[0.0] * 15),
    "NaN": joint_state(position=[0.1] * 15 + [np.nan]),
}


@pytest.mark.parametrize("kind", MALFORMED_STATES)
def test_each_kind_of_malformed_joint_state_is_refused_by_decoding(kind):
    with pytest.raises(ValueError, match="names do not match|must hold 16|non-finite"):
        decode_joint_state(MALFORMED_STATES[kind])


def test_malformed_joint_states_are_dropped_counted_and_logged_once(caplog):
    cfg = RosConfig(malformed_limit=3)
    tick = make_tick(cfg)
    good = joint_state()
    tick.joints(good)
    tick.skin(skin_frame(cfg))
    assert tick() is not None
    with caplog.at_level(logging.WARNING, logger="tacgnn.real"):
        tick.joints(MALFORMED_STATES["another hand's names"])  # another node on the topic
        tick.joints(MALFORMED_STATES["NaN"])
        assert tick.joints.msg is good and tick.joints.malformed == 2
        assert tick() is None and tick.held == "answered"  # no new good state: nothing to answer, no stop
        tick.joints(joint_state(position=[0.2] * 16))
        tick.skin(skin_frame(cfg))
        assert tick() is not None and tick.controller.steps == 2
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2, lines
    assert lines[0].startswith("malformed joint state on /allegroHand_0/joint_states dropped: joint state names")
    assert "after 3 in a row or 1 s" in lines[0]
    assert lines[1] == "joint state on /allegroHand_0/joint_states: well-formed again after 2 malformed dropped"
    # the limit in a row stops the node, naming the topic and the last problem
    for _ in range(3):
        tick.joints(MALFORMED_STATES["15 joints"])
    assert tick.joints.malformed == 5
    with pytest.raises(MalformedInput, match=r"joint_states: 3 malformed messages in a row, the last: .*lacks"):
        tick()


def test_a_skin_frame_the_calibration_refuses_is_dropped_and_a_long_run_of_them_times_out():
    cfg = RosConfig(malformed_limit=1000, malformed_timeout_s=0.05)
    tick = make_tick(cfg)
    tick.joints(joint_state())
    tick.skin(skin_frame(cfg))
    tick.skin(skin_frame(cfg, palm=5))  # a wrongly sized patch
    tick.skin(SimpleNamespace())  # a message without the skin's fields
    assert tick.skin.malformed == 2 and tick() is not None  # the good frame is used
    time.sleep(0.06)
    with pytest.raises(MalformedInput, match=r"/allegro_tactile: only malformed messages for 0\.\d+ s.*palm_Value"):
        tick()


def test_the_loop_survives_a_stray_message_and_stops_on_a_run_of_them():
    """Through the receive-thread ticker, as in the node: one malformed state among good ones is
    dropped and the loop goes on; `malformed_limit` in a row end the loop with the error."""
    cfg = RosConfig(rate_hz=10.0, malformed_limit=4)
    tick = make_tick(cfg)
    running = threading.Event()
    running.set()
    commands = []

    def step(_arrived):
        target = tick()
        if target is not None:
            commands.append(target)
        return True

    ticker = ArrivalTicker(cfg, tick.joints, step, LoopStats(), tick.paired, tick.skin)

    def hand():
        for k in range(3):
            tick.skin(skin_frame(cfg))
            tick.joints(joint_state(position=[0.1 * (k + 1)] * 16))
            tick.joints(MALFORMED_STATES["NaN"])  # a stray node's message after each good one
            time.sleep(cfg.period)
        for _ in range(4):
            tick.joints(MALFORMED_STATES["another hand's names"])

    threading.Timer(0.01, hand).start()
    with pytest.raises(MalformedInput, match="5 malformed messages in a row.*names do not match"):  # NaN + 4
        ticker.run(running.is_set)
    assert len(commands) == 3 and tick.joints.malformed == 7


def test_the_node_stops_before_its_first_command_when_only_malformed_messages_come():
    cfg = RosConfig(malformed_limit=3)
    node = RosNode.__new__(RosNode)  # the node's waiting, without ROS behind it
    node.cfg, node.ok, node.spin_once = cfg, lambda: True, lambda: None
    latest = Latest(lambda m: decode_joint_state(m, cfg.joint_names), "joint state on /js", cfg.malformed_limit)
    threading.Timer(0.02, lambda: [latest(MALFORMED_STATES["15 joints"]) for _ in range(3)]).start()
    began = time.monotonic()
    with pytest.raises(MalformedInput, match="joint state on /js: 3 malformed messages in a row.*lacks"):
        node.wait_for("joint state on /js", latest, timeout=10.0)
    assert time.monotonic() - began < 5.0


@pytest.mark.parametrize("key, value", [("malformed_limit", 0), ("malformed_limit", 2.5),
                                        ("malformed_timeout_s", 0.0), ("malformed_timeout_s", float("inf"))])
def test_the_limits_are_checked_by_the_config(key, value):
    from tacgnn.config import ConfigError

    with pytest.raises(ConfigError, match=f"ros.{key}"):
        RosConfig(**{key: value})


@pytest.fixture
def ros_logging(tmp_path):
    """The logging rospy's init_node leaves: the root logger writes only to the ROS log file."""
    root, ours = logging.getLogger(), logging.getLogger("tacgnn.real")
    saved = root.handlers[:], ours.handlers[:], ours.level
    log_file = tmp_path / "rosout.log"
    root.handlers = [logging.FileHandler(log_file)]
    ours.handlers = []
    try:
        yield log_file
    finally:
        root.handlers[0].close()
        root.handlers, ours.handlers = saved[0], saved[1]
        ours.setLevel(saved[2])


def test_stale_data_warnings_reach_the_terminal_as_well_as_the_ros_log(ros_logging, capfd):
    log_to_terminal()
    log_to_terminal()  # a second node in the process adds no second handler
    cfg = RosConfig()
    tick = make_tick(cfg)
    tick.joints(joint_state())
    tick.skin(skin_frame(cfg))
    tick.skin.stamp -= 1.0  # a skin frame a second old
    assert tick() is None and tick.held == "stale"
    err = capfd.readouterr().err
    assert err.count("stale skin: no frame newer than 40 ms on /allegro_tactile") == 1, err
    assert "stale skin" in ros_logging.read_text()


def test_a_terminal_handler_already_there_is_not_doubled(ros_logging, capfd):
    logging.getLogger().addHandler(logging.StreamHandler(sys.stderr))  # logging.basicConfig, no ROS
    log_to_terminal()
    assert logging.getLogger("tacgnn.real").handlers == []
    logging.getLogger("tacgnn.real").warning("one line")
    assert capfd.readouterr().err.count("one line") == 1
