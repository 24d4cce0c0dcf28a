"""Real-hand control: taxel kinematics and the blind controller agree with the simulator; bad input is refused."""

import importlib.util
import sys
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from real_policy import blind_policy

from tacgnn.envs.baoding import BaodingEnv
from tacgnn.envs.randomization import RandomizationConfig
from tacgnn.learning.policy import load_perception
from tacgnn.real import BlindController, BlindControllerConfig, TaxelKinematics
from tacgnn.real.messages import decode_joint_state, decode_tactile
from tacgnn.real.node import RosNode
from tacgnn.real.ros_config import ALLEGRO_JOINT_NAMES, RosConfig
from tacgnn.real.tick import ControlTick
from tests.test_temporal_loop import _run as temporal_blind_run

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def policy_file(tmp_path_factory):
    return blind_policy(tmp_path_factory.mktemp("policy"))


@pytest.fixture(scope="module")
def controller(policy_file):
    return BlindController(BlindControllerConfig(policy=str(policy_file)))


@pytest.fixture(scope="module")
def env_after_steps(controller, policy_file):
    """Envs of the policy's config, driven by the policy until the balls touch the skin (with a
    perception of their own: one with memory keeps a state per env)."""
    # the nominal hand: the controller is given the true joints, as the env's encoders read them only there
    env = BaodingEnv(replace(controller.env_config, num_envs=3, seed=0, randomization=RandomizationConfig()),
                     perception=load_perception(policy_file))
    obs, _ = env.reset(seed=0)
    for _ in range(15):
        obs, *_ = env.step(controller.policy(obs))
    env.sim.forward()  # poses, contacts and skin of the current state (the env keeps the last substep's)
    return env


def test_taxel_kinematics_equal_the_simulators_positions(controller):
    env = BaodingEnv(replace(controller.env_config, num_envs=4, obs_mode="groundtruth", tactile=False))
    kin = TaxelKinematics(env.config.hand, env.config.skin)
    rng = np.random.default_rng(0)
    qpos = env.sim.qpos.copy()
    qpos[:, env.joint_qpos_adr] = rng.uniform(env.joint_low, env.joint_high, (4, 16))
    env.sim.qpos[:] = qpos
    env.sim.forward()
    expected = env.taxel_positions()
    for i in range(4):
        # the same kinematics and maths; BLAS picks its float32 product's kernel by the batch's shape and
        # the CPU, so one env and four may round the last bit apart (1.5e-8 m seen): 0.1 um allowed
        np.testing.assert_allclose(kin.positions(env.joint_pos[i]), expected[i], rtol=0, atol=1e-7)


def test_targets_equal_the_env_driven_policys(controller, env_after_steps):
    env = env_after_steps
    ids = np.arange(env.num_envs)
    skin = env.tactile_readings(noisy=False)
    assert (skin > 0).sum(1).min() > 0  # the balls press the skin
    memory = getattr(env.perception, "state", None)  # a perception's memory of each env, if it keeps one
    memory = None if memory is None else memory.clone()
    obs = env._observe(ids, skin, env.taxel_positions())  # what the env shows the policy in this state
    expected = env.action_to_ctrl(np.clip(controller.policy(obs), -1, 1))
    for i in ids:
        controller.last_action = env.last_action[i].copy()
        if memory is not None:  # the controller takes over hand i where the env's perception left it
            controller.perception.state = memory[i:i + 1].clone()
            controller.hand.episode_steps[0] = env.episode_steps[i]
        obs_i = controller.observation(env.joint_pos[i], env.joint_vel[i], skin[i])
        np.testing.assert_allclose(obs_i, obs[i], atol=1e-6)
        target = controller.limit(controller.action_to_target(controller.act(obs_i)), env.joint_pos[i])
        np.testing.assert_allclose(target, expected[i], atol=1e-5)


def test_reset_starts_like_the_env(controller):
    env = BaodingEnv(replace(controller.env_config, num_envs=1, obs_mode="groundtruth", tactile=False))
    env.reset(seed=3)
    controller.reset(env.joint_pos[0])
    np.testing.assert_allclose(controller.last_action, env.last_action[0], atol=1e-12)


def test_bad_input_is_refused_with_clear_errors(controller):
    q, qd, skin = np.full(16, 0.5), np.zeros(16), np.zeros(controller.num_taxels)
    controller.reset(q)
    bad = q.copy()
    bad[13] = np.nan
    with pytest.raises(ValueError, match=r"joint_pos holds non-finite.*thumb_j1"):
        controller.step(bad, qd, skin)
    with pytest.raises(ValueError, match=r"joint_vel must have shape \(16,\), got \(15,\)"):
        controller.step(q, qd[:15], skin)
    with pytest.raises(ValueError, match=r"skin must have shape \(653,\), got \(2, 653\)"):
        controller.step(q, qd, np.zeros((2, 653)))
    with pytest.raises(ValueError, match="skin readings must be >= 0"):
        controller.step(q, qd, skin - 1.0)


def test_targets_are_clamped_to_the_joint_ranges(controller, monkeypatch):
    controller.reset(np.full(16, 0.5))
    monkeypatch.setattr(controller, "policy", lambda obs: np.full((1, 16), 7.0, np.float32))
    target = controller.step(np.full(16, 0.5), np.zeros(16), np.zeros(controller.num_taxels))
    np.testing.assert_array_equal(target, controller.joint_high)
    assert np.all(controller.last_action == 1.0)


def test_safety_step_limit_keeps_targets_near_the_pose(controller, monkeypatch):
    monkeypatch.setattr(controller, "config", BlindControllerConfig(max_step_rad=0.05))
    monkeypatch.setattr(controller, "policy", lambda obs: np.full((1, 16), 1.0, np.float32))
    q = np.clip(np.full(16, 0.5), controller.joint_low, controller.joint_high)
    target = controller.step(q, np.zeros(16), np.zeros(controller.num_taxels))
    np.testing.assert_allclose(target, np.minimum(q + 0.05, controller.joint_high))


def test_a_policy_trained_with_a_target_band_keeps_it_on_the_hand(controller, monkeypatch):
    """The band is part of what the policy's actions mean: the controller applies it as the env did,
    and it is not a safety event."""
    monkeypatch.setattr(controller, "env_config", replace(controller.env_config, target_band_rad=0.1))
    monkeypatch.setattr(controller, "policy", lambda obs: np.full((1, 16), 1.0, np.float32))
    q = np.clip(np.full(16, 0.5), controller.joint_low, controller.joint_high)
    target = controller.step(q, np.zeros(16), np.zeros(controller.num_taxels))
    np.testing.assert_allclose(target, np.minimum(q + 0.1, controller.joint_high))
    assert "max_step_rad" not in controller.safety.active


def test_a_policy_that_needs_ball_positions_is_refused(policy_file, tmp_path):
    data = torch.load(policy_file, weights_only=True)
    data["env_config"]["obs_mode"] = "groundtruth"
    del data["perception"]
    torch.save(data, tmp_path / "gt.pt")
    with pytest.raises(ValueError, match="observes 'groundtruth'"):
        BlindController(BlindControllerConfig(policy=str(tmp_path / "gt.pt")))


def test_ros_adapter_imports_without_ros_and_explains_what_is_missing():
    assert "rospy" not in sys.modules and "rclpy" not in sys.modules
    if importlib.util.find_spec("rospy") is None:
        with pytest.raises(ImportError, match="source your ROS 1 setup"):
            RosNode(RosConfig())


def test_control_tick_reorders_joints_and_stops_on_stale_data(controller):
    names = list(ALLEGRO_JOINT_NAMES)
    perm = np.random.default_rng(0).permutation(16)
    q = np.clip(np.linspace(0.1, 0.9, 16), controller.joint_low, controller.joint_high)
    state = SimpleNamespace(name=[names[i] for i in perm], position=list(q[perm]), velocity=list(0.1 * q[perm]))
    pos, vel = decode_joint_state(state)
    np.testing.assert_array_equal(pos, q)

    class Identity:  # a calibrated skin processor stand-in
        def __call__(self, patches, track=True):
            return np.concatenate([patches[p.name] for p in controller.env_config.skin.patches]).astype(np.float32)

    cfg = RosConfig()
    fields = dict(cfg.tactile_fields)
    skin_msg = SimpleNamespace(**{fields[p.name]: [0.0] * p.size for p in controller.env_config.skin.patches})
    tick = ControlTick(cfg, controller, Identity())
    assert tick() is None  # nothing received yet
    tick.joints(state)
    tick.skin(skin_msg)
    controller.reset(q)
    target = tick()
    controller.reset(q)
    np.testing.assert_array_equal(target, controller.step(q, 0.1 * q, np.zeros(controller.num_taxels)))
    tick.skin.stamp -= 1.0  # a skin frame a second old
    assert tick() is None
    with pytest.raises(ValueError, match="has no field 'palm_Value'"):
        decode_tactile(SimpleNamespace(), cfg.tactile_fields)


def test_rate_limit_and_joint_ranges_log_one_line_each(controller, monkeypatch, caplog):
    import logging

    rate = 0.5  # rad/s: 0.01 rad per 20 ms tick
    monkeypatch.setattr(controller, "config", BlindControllerConfig(max_target_rate=rate))
    q = np.clip(np.full(16, 0.5), controller.joint_low, controller.joint_high)
    controller.reset(q)
    monkeypatch.setattr(controller, "policy", lambda obs: np.full((1, 16), 1.0, np.float32))
    skin = np.zeros(controller.num_taxels)
    with caplog.at_level(logging.WARNING, logger="tacgnn.real"):
        targets = [controller.step(q, np.zeros(16), skin) for _ in range(3)]
    step = rate * controller.control_dt
    np.testing.assert_allclose(targets[0], np.minimum(q + step, controller.joint_high))
    np.testing.assert_allclose(targets[2], np.minimum(q + 3 * step, controller.joint_high))
    assert [r.getMessage() for r in caplog.records] == ["max_target_rate: target changes limited to 0.5 rad/s"]
    caplog.clear()
    monkeypatch.setattr(controller, "config", BlindControllerConfig())
    with caplog.at_level(logging.WARNING, logger="tacgnn.real"):
        controller.step(q, np.zeros(16), skin)  # no limit acts any more: one line says so
        controller.step(q, np.zeros(16), skin)
    assert [r.getMessage() for r in caplog.records] == ["max_target_rate: released after 3 ticks"]


def test_stale_messages_hold_with_one_log_line(controller, caplog):
    import logging

    cfg = RosConfig()
    names = list(ALLEGRO_JOINT_NAMES)
    q = np.clip(np.full(16, 0.4), controller.joint_low, controller.joint_high)
    state = SimpleNamespace(name=names, position=list(q), velocity=[0.0] * 16)
    fields = dict(cfg.tactile_fields)
    skin_msg = SimpleNamespace(**{fields[p.name]: [0.0] * p.size for p in controller.env_config.skin.patches})

    from tacgnn.real.skin import SkinProcessor, calibrate

    layout = controller.env_config.skin
    tick = ControlTick(cfg, controller, SkinProcessor(calibrate(np.ones((2, layout.num_taxels)), layout), layout))
    tick.joints(state)
    tick.skin(skin_msg)
    controller.reset(q)
    assert tick() is not None
    assert tick() is None and tick.held == "answered"  # a joint state is answered once, as the env steps once
    tick.joints(SimpleNamespace(**vars(state)))
    tick.skin.stamp -= 2.5 * cfg.period  # older than 2 control periods
    with caplog.at_level(logging.WARNING, logger="tacgnn.real"):
        assert tick() is None and tick() is None and tick.held == "stale"
        tick.skin(skin_msg)
        assert tick() is not None
    assert [r.getMessage().split(":")[0] for r in caplog.records] == ["stale skin", "stale skin"]
    assert "holding position" in caplog.records[0].getMessage()
    assert "released after 2 ticks" in caplog.records[1].getMessage()
    # a wrongly sized patch is dropped where it arrives (and counted): the tick keeps the good frame
    tick.skin(SimpleNamespace(**{**vars(skin_msg), "palm_Value": [0.0] * 5}))
    assert tick.skin.malformed == 1 and tick.skin.msg is skin_msg


def test_a_policy_with_a_temporal_perception_drives_the_hand_as_in_the_env(tmp_path):
    """The controller keeps the temporal perception's state for its one hand: over an episode its
    targets equal the env's, frame for frame, a warm-up mid-episode leaves the memory as it was,
    and a reset starts it afresh."""
    checkpoint = temporal_blind_run(tmp_path / "run", 2)  # a small blind run, temporal perception in the loop
    ctl = BlindController(BlindControllerConfig(policy=str(checkpoint)))

    class Recorder:
        """The env's perception, keeping each call's frames (what a real hand's skin would send)."""

        def __init__(self, perception):
            self.perception, self.joint_inputs, self.frames = perception, perception.joint_inputs, []

        def bind_env(self, env):
            self.perception.bind_env(env)

        def __call__(self, readings, taxel_pos, joints):
            self.frames.append((readings.copy(), joints.copy()))
            return self.perception(readings, taxel_pos, joints)

    recorder = Recorder(load_perception(checkpoint))
    env = BaodingEnv(replace(ctl.env_config, num_envs=1, seed=0), perception=recorder)
    for episode in range(2):
        obs, _ = env.reset(seed=episode)
        ctl.reset(env.joint_pos[0])
        for step in range(6):
            readings, joints = recorder.frames[-1]
            if step == 3:
                ctl.warm_up(joints[0], env.joint_vel[0], readings[0], ticks=1)
            action = np.clip(ctl.policy(obs), -1, 1)
            target = ctl.step(joints[0], env.joint_vel[0], readings[0])
            np.testing.assert_allclose(target, env.action_to_ctrl(action)[0], atol=1e-5)
            obs, _, terminated, truncated, _ = env.step(action)
            assert not (terminated | truncated).any()
        assert ctl.hand.episode_steps[0] == 6
