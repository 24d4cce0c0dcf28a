"""System identification: simulated recordings with known gains are identified; bad files are named."""

import numpy as np
import pytest

from tacgnn.cli import main as cli_main
from tacgnn.config import ConfigError, load_yaml
from tacgnn.envs.baoding import BAODING_RANGES, BaodingConfig
from tacgnn.hand.allegro import JOINT_NAMES, HandConfig
from tacgnn.real.joint_recording import JointRecording, RecordingError, csv_columns, load_recording, save_recording
from tacgnn.real.sysid import StepProtocol, StepReplay, SysIdConfig, SysIdGrid, identify, make_recording, write_outputs

GRID = SysIdGrid()  # the authors' {1, 3, 5} x {0, 0.1, 0.5}
CONTACT_FREE = StepProtocol(levels_deg=(0.0, 5.0, 10.0, 20.0, 30.0))
"""Smaller steps than the authors' (0 to 60 deg): no finger touches another or the palm (a
blocked joint's angle says nothing about its gains), and the 0.5 N m motors saturate less."""


def random_truth(seed: int) -> tuple[np.ndarray, np.ndarray]:
    pairs = GRID.candidates()[np.random.default_rng(seed).integers(len(GRID.candidates()), size=16)]
    return pairs[:, 0], pairs[:, 1]


@pytest.fixture(scope="module")
def truth():
    return random_truth(1)


def test_per_joint_truth_from_the_grid_is_identified_exactly(truth):
    k, d = truth
    rec = make_recording(k, d, CONTACT_FREE)
    result = identify(rec)
    np.testing.assert_array_equal(result.stiffness, k)
    np.testing.assert_array_equal(result.damping, d)
    # the replay with every joint at its identified pair reproduces the recording
    replay = StepReplay(HandConfig(), SysIdConfig().sim, rec.period)
    sim = replay.run(rec.target, rec.measured[0], result.stiffness[None], result.damping[None])[0]
    assert np.abs(sim - rec.measured).max() < 1e-9
    assert result.errors.shape == (9, 16) and np.all(np.sort(result.errors, 0)[1] > np.deg2rad(0.1))


def test_identified_despite_measurement_noise(truth):
    k, d = truth
    rec = make_recording(k, d, CONTACT_FREE, noise_deg=0.5, seed=7)
    result = identify(rec)
    np.testing.assert_array_equal(result.stiffness, k)
    np.testing.assert_array_equal(result.damping, d)
    assert np.all(np.abs(np.rad2deg(result.best_errors) - 0.5) < 0.1)  # what is left is the noise


def test_finer_grid_and_sequential_protocol():
    grid = SysIdGrid(stiffness=(2.0, 2.5, 3.0, 3.5), damping=(0.05, 0.1, 0.2))
    k = np.full(16, 2.5)
    d = np.full(16, 0.2)
    rec = make_recording(k, d, StepProtocol(levels_deg=(20.0, 40.0), hold_steps=15, sequential=True))
    assert rec.num_samples == 16 * 2 * 15
    result = identify(rec, SysIdConfig(grid=grid))
    np.testing.assert_array_equal(result.stiffness, k)
    np.testing.assert_array_equal(result.damping, d)


def test_grid_is_validated():
    with pytest.raises(ConfigError, match="grid.stiffness"):
        SysIdGrid(stiffness=(0.0, 1.0))
    with pytest.raises(ConfigError, match="grid.damping.*repeat"):
        SysIdGrid(damping=(0.1, 0.1))


def test_output_is_a_hand_config_that_loads_back(tmp_path, truth):
    k, d = truth
    rec = make_recording(k, d)
    result = identify(rec)
    base = HandConfig(joint_ranges=BAODING_RANGES)
    hand_path, report_path = write_outputs(result, rec, tmp_path / "hand.yaml", base)
    cfg = load_yaml(BaodingConfig, hand_path)
    assert cfg.hand.joint_stiffness() == tuple(k) and cfg.hand.joint_damping() == tuple(d)
    assert cfg.hand.joint_ranges == BAODING_RANGES  # the task's ranges survive loading
    import yaml

    report = yaml.safe_load(report_path.read_text())
    assert list(report["joints"]) == list(JOINT_NAMES)
    assert np.shape(report["joints"]["index_j0"]["errors_deg"]) == (3, 3)


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_recording_round_trip(tmp_path, suffix):
    rec = make_recording(3.0, 0.1, StepProtocol(hold_steps=5), noise_deg=0.2)
    back = load_recording(save_recording(rec, tmp_path / f"rec{suffix}"))
    for name in ("time", "target", "measured"):
        np.testing.assert_array_equal(getattr(back, name), getattr(rec, name))


def _npz(tmp_path, **arrays):
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    return path


def _good(t=20):
    time = np.arange(t) * 0.02
    target = np.zeros((t, 16))
    return {"time": time, "target": target, "measured": target.copy()}


@pytest.mark.parametrize("change,problem", [
    (lambda a: a.pop("measured"), r"missing array\(s\) \['measured'\]"),
    (lambda a: a.update(target=np.zeros((20, 15))), r"'target' must have shape \(20, 16\).*got \(20, 15\)"),
    (lambda a: a.update(time=np.arange(19) * 0.02), r"'target' must have shape \(19, 16\)"),
    (lambda a: a["measured"].__setitem__((4, 1), np.nan), r"'measured' has 1 non-finite.*sample 4, joint index_j1"),
    (lambda a: a["time"].__setitem__(5, 0.0), r"'time' must increase strictly"),
    (lambda a: a.update(time=np.r_[np.arange(10) * 0.02, 0.3 + np.arange(10) * 0.02]), "not evenly spaced"),
])
def test_malformed_recording_names_file_and_problem(tmp_path, change, problem):
    arrays = _good()
    change(arrays)
    path = _npz(tmp_path, **arrays)
    with pytest.raises(RecordingError, match=problem) as err:
        load_recording(path)
    assert str(path) in str(err.value)


def test_malformed_files_of_other_kinds(tmp_path):
    with pytest.raises(RecordingError, match="file not found"):
        load_recording(tmp_path / "none.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(RecordingError, match=f"{junk}.*not a readable .npz"):
        load_recording(junk)
    with pytest.raises(RecordingError, match="unknown format '.txt'"):
        (tmp_path / "r.txt").write_text("x")
        load_recording(tmp_path / "r.txt")
    csv = tmp_path / "r.csv"
    csv.write_text(",".join(c for c in csv_columns() if c != "measured_thumb_j3") + "\n")
    with pytest.raises(RecordingError, match=f"{csv}.*missing column.*measured_thumb_j3"):
        load_recording(csv)
    with pytest.raises(RecordingError, match="'time' must have shape"):
        JointRecording(np.zeros((3, 1)), np.zeros((3, 16)), np.zeros((3, 16)))


def test_cli_makes_a_recording_and_identifies_it(tmp_path, capsys):
    rec = tmp_path / "rec.csv"
    assert cli_main(["sysid", "--make-recording", str(rec), "--true-stiffness", "5", "--true-damping", "0.5",
                     "--hold-steps", "20", "--noise-deg", "0.2"]) == 0
    out = tmp_path / "hand.yaml"
    assert cli_main(["sysid", str(rec), "--out", str(out), "--refine-passes", "1"]) == 0
    hand = load_yaml(BaodingConfig, out).hand
    assert hand.stiffness == 5.0 and hand.damping == 0.5  # one value: all joints agree
    assert "hand.stiffness=5.0" in capsys.readouterr().out
    bad = tmp_path / "bad.npz"
    np.savez(bad, time=np.arange(3.0))
    assert cli_main(["sysid", str(bad)]) == 2
    assert "missing array" in capsys.readouterr().err


# --- beyond the grid: least squares with mujoco.sysid, confidence intervals -----------------
def test_refined_gains_off_the_grid_lie_inside_their_intervals():
    pytest.importorskip("mujoco.sysid", reason="needs the 'sysid' extra (mujoco[sysid])")
    from tacgnn.real.sysid_refine import RefineConfig, refine

    rng = np.random.default_rng(3)
    k, d = rng.uniform(1.5, 4.5, 16).round(3), rng.uniform(0.05, 0.4, 16).round(3)  # off the grid
    rec = make_recording(k, d, CONTACT_FREE, noise_deg=0.5, seed=11)
    grid = identify(rec)
    result = refine(rec, grid.stiffness, grid.damping, refine_cfg=RefineConfig(max_iters=40))
    inside = result.covers(k, d)
    assert inside.sum() >= 15, (inside, result.stiffness, result.damping)
    # the fit is better than the grid's and explains the recording down to its noise
    assert np.all(result.rms <= grid.best_errors + 1e-9)
    np.testing.assert_allclose(np.rad2deg(result.rms), 0.5, atol=0.06)
    assert np.all(np.isfinite(result.stiffness_half_width)) and np.all(result.stiffness_half_width > 0)


def test_step_recording_round_trips_through_a_ros_bag(tmp_path):
    from tacgnn.real.bag import BagWriter
    from tacgnn.real.ros_config import ALLEGRO_JOINT_NAMES, RosConfig

    rec = make_recording(3.0, 0.1, StepProtocol(levels_deg=(0.0, 20.0), hold_steps=10))
    ros = RosConfig()
    path = tmp_path / "steps.bag"
    with BagWriter(path) as bag:
        for t in range(rec.num_samples):  # the hand's state, then (2 ms later) the command after it
            state = bag.message("sensor_msgs/JointState", name=list(ALLEGRO_JOINT_NAMES), position=rec.measured[t],
                                velocity=np.zeros(16), effort=np.zeros(0))
            bag.write(ros.joint_state_topic, "sensor_msgs/JointState", state, 1.0 + rec.time[t])
            cmd = bag.message("sensor_msgs/JointState", name=list(ALLEGRO_JOINT_NAMES), position=rec.target[t],
                              velocity=np.zeros(0), effort=np.zeros(0))
            bag.write(ros.joint_cmd_topic, "sensor_msgs/JointState", cmd, 1.002 + rec.time[t])
    back = load_recording(path)
    np.testing.assert_array_equal(back.measured, rec.measured)
    np.testing.assert_array_equal(back.target, rec.target)
    np.testing.assert_allclose(back.time, rec.time, atol=1e-9)
    # a bag without the command topic is named as such
    with BagWriter(tmp_path / "states_only.bag") as bag:
        bag.write(ros.joint_state_topic, "sensor_msgs/JointState", state, 1.0)
    with pytest.raises(RecordingError, match=r"no messages on /allegroHand_0/joint_cmd \(joint commands\)"):
        load_recording(tmp_path / "states_only.bag")
