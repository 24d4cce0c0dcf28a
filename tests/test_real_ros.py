"""The real-hand path through a real ROS 1 master on loopback, with the simulator as the hand.

`tacgnn real-hand sim-hand` plays the Allegro driver; `tacgnn real-hand run` controls it
as it would a real hand. Needs ROS 1 (roscore, rospy): `make test-ros` installs it where
apt-get is available; elsewhere these tests skip and say so.
"""

import importlib.util
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tacgnn.real.loopback_master import free_port, loopback_env, start_roscore, stop_roscore

HAVE_ROS = shutil.which("roscore") is not None and importlib.util.find_spec("rospy") is not None
pytestmark = pytest.mark.skipif(not HAVE_ROS, reason="ROS 1 is not installed (roscore and rospy): "
                                                     "`make test-ros` installs it where apt-get is available")
TIMEOUT = 240


@pytest.fixture(scope="module")
def ros_env(tmp_path_factory):
    """A roscore on a free loopback port, and the environment that points nodes at it."""
    home = tmp_path_factory.mktemp("ros")
    port = free_port()
    env = loopback_env(port, home)
    try:
        core = start_roscore(env, port)
    except RuntimeError as e:
        pytest.fail(str(e))
    yield env
    stop_roscore(core)


@pytest.fixture(scope="module")
def policy(tmp_path_factory):
    from real_policy import blind_policy

    return blind_policy(tmp_path_factory.mktemp("policy"))


def tacgnn(env, action, *args, policy=None) -> subprocess.Popen:
    extra = ("--policy", str(policy)) if policy else ()
    return subprocess.Popen([sys.executable, "-m", "tacgnn.cli", "real-hand", action, *extra, *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def finish(proc: subprocess.Popen) -> str:
    out, _ = proc.communicate(timeout=TIMEOUT)
    return out


@pytest.fixture(scope="module")
def calibration(ros_env, policy, tmp_path_factory):
    """record-skin of the simulated hand at rest (a bag), then calibrate-skin on that bag."""
    d = tmp_path_factory.mktemp("calib")
    recorder = tacgnn(ros_env, "record-skin", "--out", str(d / "rest.bag"), "--frames", "40",
                      "--set", "startup_timeout_s=60")  # the hand may take long to start on a loaded machine
    time.sleep(1.0)
    hand = tacgnn(ros_env, "sim-hand", "--rest-steps", "150", policy=policy)  # the real skin, at rest
    out = finish(recorder)
    finish(hand)
    assert recorder.returncode == 0, out
    from tacgnn.cli import main

    assert main(["calibrate-skin", str(d / "rest.bag"), "--out", str(d / "calib.npz")]) == 0
    from tacgnn.real.skin import SkinCalibration
    from tacgnn.sim.skin_signal import SkinSignalConfig

    calib = SkinCalibration.load(d / "calib.npz")
    skin = SkinSignalConfig()  # the real skin's dead taxels (up to 5 % of 653) are found, its offsets measured
    assert calib.dead.sum() <= skin.dead_fraction[1] * 653 + 10
    live = calib.baseline[~calib.dead]
    # within the offsets but for the drift since the skin's own calibration and the stuck taxels
    inside = (live >= skin.offset[0] - 0.1) & (live <= skin.offset[1] + 0.1)
    assert inside.mean() >= 0.95, inside.mean()
    return d / "calib.npz"


def run_pair(env, tmp: Path, calibration: Path, policy: Path, episodes: int = 2, hand_args=(),
             run_args=()) -> tuple[dict, dict, str]:
    hand = tacgnn(env, "sim-hand", "--episodes", str(episodes), "--summary", str(tmp / "hand.json"), *hand_args,
                  policy=policy)
    time.sleep(0.5)
    ctrl = tacgnn(env, "run", "--calibration", str(calibration), "--stats", str(tmp / "stats.json"), *run_args,
                  policy=policy)
    ctrl_out = finish(ctrl)
    hand_out = finish(hand)
    assert ctrl.returncode == 0, ctrl_out
    assert hand.returncode == 0, hand_out
    return json.loads((tmp / "hand.json").read_text()), json.loads((tmp / "stats.json").read_text()), ctrl_out


def test_blind_controller_runs_the_simulated_hand_and_replays_offline(ros_env, calibration, policy, tmp_path):
    hand, stats, out = run_pair(ros_env, tmp_path, calibration, policy,
                                run_args=("--record", str(tmp_path / "run.bag")))
    assert hand["episodes"] == 2 and 0.0 <= hand["success_rate"] <= 1.0
    # the node's log lines reach the terminal after rospy.init_node sent the root logger to its file
    assert "joint states and skin frames check out" in out, out
    assert stats["malformed_dropped"] == {"joint_states": 0, "skin": 0}, stats
    steps = sum(r["steps"] for r in hand["results"])
    # about one command per step of the hand (a loaded machine misses some ticks: the hand then holds)
    assert stats["episodes"] == 2 and stats["commands"] >= 0.8 * steps, stats
    assert hand["commands_received"] == stats["commands"]
    # every step of the hand applied a command that answers a state it sent (lag in steps, by the
    # command's stamp) or held; skin and joint angles of one instant
    lags = hand["command_lag_steps"]
    assert sum(lags.values()) == steps and set(lags) <= {"none", "0", "1", "2", "3+"}, lags
    assert stats["unpaired_skin"] <= 0.2 * stats["commands"], stats

    from tacgnn.real.controller import BlindController, BlindControllerConfig
    from tacgnn.real.ros_config import RosConfig
    from tacgnn.real.run_bag import replay_run
    from tacgnn.real.skin import SkinCalibration, SkinProcessor

    controller = BlindController(BlindControllerConfig(policy=str(policy)))
    processor = SkinProcessor.for_env(SkinCalibration.load(calibration), controller.env_config)
    recorded, replayed = replay_run(tmp_path / "run.bag", RosConfig(), controller, processor)
    assert len(recorded) == stats["commands"]
    np.testing.assert_array_equal(replayed, recorded)


def test_latency_dropped_skin_messages_and_malformed_joint_states_are_survived(ros_env, calibration, policy,
                                                                               tmp_path):
    hand, stats, out = run_pair(ros_env, tmp_path, calibration, policy, episodes=1,
                                hand_args=("--latency-ms", "20", "--drop-tactile", "0.05",
                                           "--stray-joint-states", "0.1"))
    assert hand["episodes"] == 1 and "success_rate" in hand
    assert stats["commands"] > 0
    # the stray states are dropped and counted, never in a row long enough to stop the run
    assert stats["malformed_dropped"]["joint_states"] > 0, stats
    assert "malformed joint state on /allegroHand_0/joint_states dropped" in out, out


def test_bad_input_stops_before_any_command(ros_env, calibration, policy, tmp_path):
    hand = tacgnn(ros_env, "sim-hand", "--episodes", "50", "--summary", str(tmp_path / "hand.json"), policy=policy)
    time.sleep(0.5)
    names = "joint_names=[" + ",".join(f"j{i}" for i in range(16)) + "]"
    wrong_names = finish(tacgnn(ros_env, "run", "--calibration", str(calibration), "--set", names, policy=policy))
    from tacgnn.real.ros_config import RosConfig

    swapped = "tactile_fields=[[palm,index_tip_Value],[index_tip,palm_Value]" + "".join(
        f",[{p},{f}]" for p, f in RosConfig().tactile_fields[2:]) + "]"
    wrong_length = finish(tacgnn(ros_env, "run", "--calibration", str(calibration), "--set", swapped, policy=policy))
    hand.terminate()
    finish(hand)
    assert "joint state names do not match ros.joint_names" in wrong_names
    assert "patch 'palm' has 72 values, expected 113" in wrong_length
    assert json.loads((tmp_path / "hand.json").read_text())["commands_received"] == 0
