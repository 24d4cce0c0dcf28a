"""The hand as uncertain as a real one: ranges drawn as configured, latency and encoder effects with
known answers, the nominal hand recovered when the ranges collapse, bad input named."""

from dataclasses import replace

import numpy as np
import pytest

from tacgnn.config import ConfigError, override
from tacgnn.envs.baoding import BaodingConfig, BaodingEnv, training_env_config
from tacgnn.envs.randomization import HandIO, RandomizationConfig

CFG = BaodingConfig(num_envs=8, tactile=False)


def rollout(cfg, actions):
    env = BaodingEnv(cfg)
    env.reset(seed=3)
    joints = []
    for a in actions:
        env.step(a)
        joints.append(env.joint_pos.copy())
    return env, np.array(joints)


def test_training_randomises_the_hand_at_least_as_widely_as_the_authors():
    r = training_env_config().randomization
    assert r.enabled
    assert r.damping_scale[0] <= 0.3 and r.damping_scale[1] >= 3.0
    assert r.stiffness_scale[0] <= 0.75 and r.stiffness_scale[1] >= 1.5
    assert r.friction_scale[0] <= 0.7 and r.friction_scale[1] >= 1.3
    assert r.gravity == (7.0, 12.0) and r.action_latency[1] >= 0.04 and r.action_noise >= 0.05


def test_every_env_draws_its_physics_inside_the_ranges_damping_log_uniformly():
    cfg = replace(CFG, num_envs=64, randomization=RandomizationConfig(enabled=True))
    env = BaodingEnv(cfg)
    env.reset(seed=0)
    r, hand = cfg.randomization, cfg.hand
    damping = env.sim.batch.expanded("dof_damping")[:, env.joint_dof_adr] / np.asarray(hand.joint_damping())
    assert ((r.damping_scale[0] - 1e-9 <= damping) & (damping <= r.damping_scale[1] + 1e-9)).all()
    # log-uniform on [0.3, 3]: the median is the geometric mean, sqrt(0.9) = 0.95 (uniform: 1.65)
    assert 0.8 < np.median(damping) < 1.15
    friction = env.sim.batch.expanded("dof_frictionloss")[:, env.joint_dof_adr]
    assert (friction >= 0).all() and (friction <= 0.03).all() and np.unique(friction).size > 500
    mass = env.sim.batch.expanded("body_mass")[:, env.ball_body]
    assert ((0.075 <= mass) & (mass <= 0.225)).all()
    assert set(np.unique(env.hand_io.action_delay)) <= set(range(9)) and env.hand_io.action_delay.any()


def test_collapsed_ranges_are_the_nominal_hand():
    """`RandomizationConfig.nominal` is the starting point of the robustness table: with every range
    on its nominal value the randomised hand moves as the nominal one."""
    actions = np.random.default_rng(0).uniform(-1, 1, (8, 8, 16))
    _, nominal = rollout(CFG, actions)
    _, collapsed = rollout(replace(CFG, randomization=RandomizationConfig.nominal(CFG.ball_mass)), actions)
    np.testing.assert_allclose(collapsed, nominal, atol=1e-9)


def test_an_action_latency_of_one_control_step_delays_the_hand_by_one_step():
    """With 20 ms of latency (one control step) the motors get each action one step late: the same
    as the nominal hand sent the initial targets first, then the actions."""
    actions = np.random.default_rng(1).uniform(-1, 1, (12, 8, 16))
    late = RandomizationConfig.nominal(CFG.ball_mass, action_latency=(0.02, 0.02))
    env, delayed = rollout(replace(CFG, randomization=late), actions)
    first = BaodingEnv(CFG)
    first.reset(seed=3)
    hold = first.last_action.copy()
    _, shifted = rollout(CFG, np.concatenate([hold[None], actions[:-1]]))
    np.testing.assert_allclose(delayed, shifted, atol=1e-9)


def test_a_latency_between_control_steps_switches_targets_inside_the_step():
    io = HandIO(RandomizationConfig(enabled=True, action_latency=(0.01, 0.01)), 1, substeps=4, timestep=0.005,
                control_dt=0.02)
    drawn = {"action_latency": np.array([0.01]), "joint_latency": np.zeros(1), "skin_latency": np.zeros(1),
             "backlash": np.zeros((1, 16)), "joint_bias": np.zeros((1, 16))}
    io.reset(np.array([0]), drawn, np.zeros((1, 16)), np.zeros((1, 16)), np.zeros((1, 16)))
    io.push(np.ones((1, 16)))
    # 2 physics steps (10 ms) of the old target, then the new one
    assert [float(io.target_at(s)[0, 0]) for s in range(4)] == [0.0, 0.0, 1.0, 1.0]
    assert io.targets_of_step()[0, :, 0].tolist() == [0.0, 0.0, 1.0, 1.0]  # all four at once


def test_backlash_holds_the_reading_until_the_joint_has_crossed_half_the_band():
    cfg = RandomizationConfig.nominal(0.15)
    io = HandIO(cfg, 1, 4, 0.005, 0.02)
    drawn = {"action_latency": np.zeros(1), "joint_latency": np.zeros(1), "skin_latency": np.zeros(1),
             "backlash": np.full((1, 16), 0.02), "joint_bias": np.zeros((1, 16))}
    zero = np.zeros((1, 16))
    io.reset(np.array([0]), drawn, zero, zero, zero)
    rng = np.random.default_rng(0)
    readings = []
    for q in (0.005, 0.009, 0.015, 0.0):
        io.observe(np.full((1, 16), q), zero, rng)
        readings.append(float(io.readings(slice(None), zero, zero)[0][0, 0]))
    # within +-0.01 of the reading nothing moves; then it trails the joint by 0.01
    np.testing.assert_allclose(readings, [0.0, 0.0, 0.005, 0.005], atol=1e-12)


def test_joint_latency_reads_the_state_between_the_last_two_control_steps():
    cfg = RandomizationConfig.nominal(0.15, joint_latency=(0.01, 0.01))
    io = HandIO(cfg, 1, 4, 0.005, 0.02)
    drawn = {"action_latency": np.zeros(1), "joint_latency": np.array([0.01]), "skin_latency": np.zeros(1),
             "backlash": np.zeros((1, 16)), "joint_bias": np.zeros((1, 16))}
    zero = np.zeros((1, 16))
    io.reset(np.array([0]), drawn, zero, zero, zero)
    io.observe(np.full((1, 16), 1.0), zero, np.random.default_rng(0))
    np.testing.assert_allclose(io.readings(slice(None), zero, zero)[0], 0.5)  # half a step late


def test_the_policy_reads_the_encoders_the_critic_the_truth():
    cfg = replace(CFG, randomization=RandomizationConfig.nominal(CFG.ball_mass, joint_bias=(0.01, 0.01)))
    env = BaodingEnv(cfg)
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step(env.last_action.copy())
    truth = env.groundtruth_obs()
    scale = 2 / (env.joint_high - env.joint_low)  # positions are scaled to [-1, 1]
    np.testing.assert_allclose(obs[:, :16] - truth[:, :16], np.broadcast_to(0.01 * scale, (8, 16)), atol=1e-5)


@pytest.mark.parametrize("key,value", [
    ("randomization.action_latency", [0.0, 0.012]),  # not a whole number of 5 ms steps
    ("randomization.joint_latency", [-0.005, 0.0]),
    ("randomization.damping_scale", [3.0, 0.3]),
    ("randomization.action_noise", -0.1),
    ("randomization.gravity", [1e308, 1e308]),
])
def test_bad_randomisation_names_its_key(key, value):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        override(BaodingConfig(randomization=RandomizationConfig(enabled=True)), {key: value})


def test_action_rate_and_effort_costs_known_answer():
    """action_rate x |a_t - a_(t-1)|^2 and effort x sum (torque / nominal limit)^2, per env."""
    from tacgnn.envs.baoding_terms import reward_terms

    cfg = replace(CFG, reward=replace(CFG.reward, action_rate=-0.01, effort=-0.1))
    change = np.zeros((2, 16))
    change[0, :4] = 2.0  # four joints flipped end to end
    effort = np.zeros((2, 16))
    effort[1, :3] = 1.0  # three joints at the limit
    none = np.zeros(2, bool)
    terms = reward_terms(cfg, np.zeros(2), np.zeros((2, 16)), change, effort, none, none, none, np.zeros((2, 8)),
                         np.abs(effort))
    np.testing.assert_allclose(terms["action_rate"], [-0.16, 0.0])
    np.testing.assert_allclose(terms["effort"], [0.0, -0.3])
    np.testing.assert_allclose(terms["saturation"], [0.0, 0.0])  # off by default


def test_the_saturation_cost_charges_the_top_of_each_envs_own_torque_limit():
    """saturation x sum over joints of max(|torque| / limit - knee, 0) / (1 - knee), the limit each env drew:
    known answers, then an env whose limits are drawn (x0.8-1.2) charges by its own."""
    from tacgnn.envs.baoding_terms import reward_terms

    cfg = replace(CFG, reward=replace(CFG.reward, saturation=-0.5, saturation_knee=0.8))
    load = np.zeros((3, 16))
    load[0, :2] = 1.0  # two joints at the limit: 2 x -0.5
    load[1, 5] = 0.9  # half way from the knee: -0.25
    load[2, :] = 0.79  # all below the knee: free
    none = np.zeros(3, bool)
    terms = reward_terms(cfg, np.zeros(3), np.zeros((3, 16)), np.zeros((3, 16)), load, none, none, none,
                         np.zeros((3, 8)), load)
    np.testing.assert_allclose(terms["saturation"], [-1.0, -0.25, 0.0])

    env = BaodingEnv(replace(training_env_config(), num_envs=16, tactile=False, obs_mode="groundtruth",
                             reward=replace(CFG.reward, saturation=-1.0)))
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.random.default_rng(0).uniform(-1, 1, (16, 16)))
    limit = env.sim.batch.expanded("actuator_forcerange")[..., 1]
    assert np.ptp(limit[:, 0]) > 0.05  # the envs' limits differ
    load = np.abs(env.sim.actuator_force) / limit
    assert (load > 0.999).any() and (load < 0.9).any()
    np.testing.assert_allclose(info["reward_terms"]["saturation"], -np.maximum(load - 0.9, 0).sum(1) / 0.1)
    for key, value in (("reward.saturation", 0.1), ("reward.saturation_knee", 1.0)):
        with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
            override(CFG, {key: value})


@pytest.mark.parametrize("frames_late", [1, 2])
def test_a_late_skin_shows_the_frame_of_that_many_steps_ago(frames_late):
    """Skin latency delays the skin frame the policy sees, nothing else: the late env's frame of step t
    is the on-time env's frame of step t - k (the reset's frame before that), even after a resume."""
    cfg = replace(CFG, num_envs=4, tactile=True, obs_mode="tactile")
    late = RandomizationConfig.nominal(cfg.ball_mass, skin_latency=(0.02 * frames_late,) * 2)
    actions = np.random.default_rng(2).uniform(-0.3, 0.3, (10, 4, 16))
    seen = {}
    for name, r in (("on_time", RandomizationConfig.nominal(cfg.ball_mass)), ("late", late)):
        env = BaodingEnv(replace(cfg, randomization=r))
        obs, _ = env.reset(seed=3)
        frames = [obs["tactile"].copy()]
        for t, a in enumerate(actions):
            if name == "late" and t == 5:  # a resume in the middle keeps the late frames
                state = env.state_dict()
                env = BaodingEnv(replace(cfg, randomization=r))
                env.load_state_dict(state)
            obs, _, terminated, truncated, _ = env.step(a)
            assert not (terminated | truncated).any()
            frames.append(obs["tactile"].copy())
        seen[name] = np.array(frames)
    assert seen["on_time"][1:].any()
    expected = np.concatenate([np.repeat(seen["on_time"][:1], frames_late, 0), seen["on_time"][:-frames_late]])
    np.testing.assert_array_equal(seen["late"], expected)


def test_a_common_share_of_hands_moves_their_joints_together():
    """With `joint_common` that share of hands has one damping factor for all joints (a whole hand
    near x3 occurs, as the robustness table's row), the others per joint as before; 0 leaves the
    draws as they were."""
    from tacgnn.envs.randomization import draw_ranges

    plain = RandomizationConfig()
    u = np.random.default_rng(0).random((4000, plain.draws_per_reset() + 4))
    alone = draw_ranges(plain, u[:, :-4])["damping_scale"]
    mixed = draw_ranges(RandomizationConfig(joint_common=0.5), u)["damping_scale"]
    assert RandomizationConfig(joint_common=0.5).draws_per_reset() == plain.draws_per_reset() + 4
    assert (mixed >= 0.3 - 1e-9).all() and (mixed <= 3.0 + 1e-9).all()
    uniform = np.ptp(mixed, axis=1) == 0
    assert 0.45 < uniform.mean() < 0.55
    np.testing.assert_array_equal(mixed[~uniform], alone[~uniform])  # the other hands: as without
    assert (mixed[uniform, 0] > 2.5).mean() > 0.05 and (np.exp(np.log(alone).mean(1)) > 2.2).mean() == 0
    np.testing.assert_array_equal(draw_ranges(RandomizationConfig(joint_common=0.0), u[:, :-4])["damping_scale"], alone)
    with pytest.raises(ConfigError, match="randomization.joint_common"):
        RandomizationConfig(joint_common=1.5)


def test_a_target_band_keeps_the_motors_off_their_torque_limit():
    """Bang-bang actions drive the nominal motors to their 0.5 N m limit; with targets kept within
    0.15 rad of the measured angles (3 N m/rad x 0.15 = 0.45 N m) a motor reaches it only when a joint
    still moving away overshoots inside a step, and every target stays within the band of the angles
    read when it was sent."""
    actions = np.sign(np.random.default_rng(2).uniform(-1, 1, (30, 8, 16)))

    def saturated_share(cfg):
        env = BaodingEnv(cfg)
        env.reset(seed=3)
        at_limit = []
        for a in actions:
            before = env.joint_pos.copy()
            env.step(a)
            sent = env.hand_io.targets[:, 0]
            if cfg.target_band_rad:
                assert np.all(np.abs(sent - before) <= cfg.target_band_rad + 1e-12)
            at_limit.append(np.abs(env.sim.actuator_force[:, :16]) >= 0.5 - 1e-6)
        return np.mean(at_limit)

    assert saturated_share(CFG) > 0.2
    assert saturated_share(replace(CFG, target_band_rad=0.15)) < 0.002


def test_a_negative_target_band_names_its_key():
    with pytest.raises(ConfigError, match="target_band_rad"):
        override(CFG, {"target_band_rad": -0.1})


def test_targets_that_switch_inside_a_step_give_the_same_physics_in_one_engine_call():
    """A latency between control steps steps the physics in one call with a control per physics
    step (`BatchedSim.step_controls`); the per-substep path (taken for `reward.squeeze_peak`) sets
    the controls and steps one physics step at a time. The same trajectory, bit for bit."""
    actions = np.random.default_rng(2).uniform(-1, 1, (10, 8, 16))
    late = RandomizationConfig.nominal(CFG.ball_mass, action_latency=(0.01, 0.01))
    cfg = replace(CFG, randomization=late)
    one_call, joints = rollout(cfg, actions)
    per_substep, joints_per_substep = rollout(replace(cfg, reward=replace(cfg.reward, squeeze_peak=True)), actions)
    assert np.array_equal(joints, joints_per_substep)
    assert np.array_equal(one_call.sim.batch.state, per_substep.sim.batch.state)
    assert not np.array_equal(joints[1:], joints[:-1])  # the hand moved


def test_a_warning_inside_a_step_of_switching_targets_steps_on_as_one_call_per_physics_step():
    """A rollout stops a simulation at a MuJoCo warning (here a bad control, which `step` replaces
    by 0 and steps on after): `step_controls` then steps the control step again, one physics step
    per call, so the env with the warning ends where the per-step path leaves it."""
    env = BaodingEnv(CFG)
    env.reset(seed=0)
    sim = env.sim
    start = sim.batch.state.copy()
    controls = np.repeat(sim.ctrl[:, None], 4, axis=1)
    controls[1, 1, 0] = np.nan
    diverged = sim.step_controls(controls)
    one_call = sim.batch.state.copy()
    sim.batch.state[...] = start
    per_step = np.zeros(CFG.num_envs, bool)
    for k in range(4):
        sim.ctrl[:] = controls[:, k]
        per_step |= sim.step(1)
    assert np.array_equal(one_call, sim.batch.state) and np.array_equal(diverged, per_step)
    assert sim.time[1] == sim.time[0] > 0  # env 1 stepped all four physics steps
