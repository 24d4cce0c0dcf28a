"""The hand is no stronger, softer or more forgiving than the real one.

Torque limits hold, links collide and start clear, spawns never overlap, balls do not sink,
the skin reports the force of contacts on the area it covers, and randomisation acts.
"""

from dataclasses import replace

import mujoco
import numpy as np
import pytest

from tacgnn.config import ConfigError
from tacgnn.envs.baoding import BaodingConfig, BaodingEnv, RandomizationConfig, RewardConfig
from tacgnn.hand.allegro import HandConfig
from tacgnn.hand.skin_layout import TYPICAL_CONTACT_FORCE, Patch, default_skin
from tacgnn.sim.scene import SimConfig
from tacgnn.sim.tactile import TactileModel


def _ball_contacts(model, data, ball_geoms):
    for j in range(data.ncon):
        c = data.contact[j]
        if ball_geoms & {int(c.geom[0]), int(c.geom[1])}:
            yield j, c


def test_actuator_torque_never_exceeds_the_limit_and_per_joint_limits_apply():
    limits = tuple(0.3 if k % 2 else 0.6 for k in range(16))
    env = BaodingEnv(BaodingConfig(num_envs=8, hand=replace(BaodingConfig().hand, torque_limit=limits)))
    rng = np.random.default_rng(0)
    peak = np.zeros(16)
    for _ in range(30):  # bang-bang targets: the position servo asks for far more than the limit
        env.step(rng.choice([-1.0, 1.0], size=(8, 16)))
        peak = np.maximum(peak, np.abs(env.sim.actuator_force).max(0))
    assert np.all(peak <= np.asarray(limits) + 1e-9)
    # the fingers' wide ranges let the servo ask for more than the limit, so the limit binds
    # (the thumb's Baoding ranges are 0.1-0.2 rad: kp x range stays near the limit)
    assert np.all(peak[:12] >= 0.99 * np.asarray(limits)[:12])


@pytest.mark.parametrize("bad", [0.0, -0.5, float("nan"), (0.5,) * 15])
def test_bad_torque_limit_is_refused_naming_the_key(bad):
    with pytest.raises(ConfigError, match="hand.torque_limit"):
        HandConfig(torque_limit=bad)


def test_target_ranges_keep_the_joints_inside_them_while_actions_keep_their_mapping():
    """A software limit on the commands: full-range actions move index_j1 only within its
    target range, where the joint range alone lets it go much further. The model's actuators
    clamp to the same range, so a command that bypasses the env cannot leave it either."""
    base = BaodingConfig(num_envs=4, tactile=False)
    ranges = list(base.hand.joint_ranges)
    ranges[1] = (0.2, 0.6)  # index_j1, joint range (-0.196, 1.61)
    narrow = replace(base, hand=replace(base.hand, target_ranges=tuple(ranges)))
    reached, envs = {}, {}
    for name, cfg in (("joint ranges", base), ("target ranges", narrow)):
        env = envs[name] = BaodingEnv(cfg)
        env.reset(seed=0)
        low_high = []
        for sign in (1.0, -1.0):  # up for 0.4 s, then down for 0.4 s
            for _ in range(20):
                env.step(np.full((4, 16), sign))
            low_high.append(env.joint_pos[:, 1])
        reached[name] = low_high
        np.testing.assert_allclose(env.action_to_ctrl(np.ones((1, 16)))[0, :12],
                                   np.asarray(cfg.hand.joint_target_ranges())[:12, 1])
    assert np.all(reached["joint ranges"][0] > 1.0)  # (going down, the balls stop it before 0.2)
    # within the target range but for what the balls push the servo off it (0.5 N m)
    assert np.all(reached["target ranges"][0] < 0.65) and np.all(reached["target ranges"][1] > 0.15)
    np.testing.assert_allclose(envs["target ranges"].model.actuator_ctrlrange[:16], ranges)
    # what the policy sees is unchanged: proprioception and actions scale by the joint ranges
    np.testing.assert_array_equal(envs["target ranges"].joint_low, envs["joint ranges"].joint_low)


@pytest.mark.parametrize("bad", [((0.0, 0.1),) * 15, ((-0.6, 0.4),) + ((0.0, 0.1),) * 15,
                                 ((0.3, 0.2),) + ((0.0, 0.1),) * 15])
def test_target_ranges_outside_the_joint_ranges_are_refused_naming_the_key(bad):
    with pytest.raises(ConfigError, match="hand.target_ranges"):
        HandConfig(target_ranges=bad)


def test_no_geometry_overlaps_at_the_start_pose_and_fingers_collide():
    env = BaodingEnv(BaodingConfig(num_envs=1, joint_noise=0.0, spawn_noise=0.0))
    m, d = env.model, mujoco.MjData(env.model)
    d.qpos[:] = env.sim.qpos[0]
    mujoco.mj_forward(m, d)
    assert d.ncon == 0 or min(d.contact.dist[:d.ncon]) >= 0, "nothing overlaps at the start"
    # push the index finger's tip into the middle finger: link-to-link contacts exist
    q = env.initial_ctrl.copy()
    q[0], q[4] = env.joint_high[0], env.joint_low[4]
    d.qpos[env.joint_qpos_adr] = q
    mujoco.mj_forward(m, d)
    names = {(m.geom(int(c.geom[0])).name, m.geom(int(c.geom[1])).name) for c in d.contact[:d.ncon]}
    assert any("index" in a and "middle" in b or "middle" in a and "index" in b for a, b in names)


def test_spawned_balls_never_overlap_each_other_or_a_link():
    env = BaodingEnv(BaodingConfig(num_envs=500, spawn_noise=0.02))  # twice the default noise
    m, d = env.model, mujoco.MjData(env.model)
    balls = set(env.ball_geom.tolist())
    for seed in range(4):
        env.reset(seed=seed)
        for i in range(env.num_envs):
            d.qpos[:] = env.sim.qpos[i]
            mujoco.mj_kinematics(m, d)
            mujoco.mj_collision(m, d)
            assert all(c.dist >= 0 for _, c in _ball_contacts(m, d, balls)), f"reset {seed}, env {i}"


def test_spawn_offsets_inside_the_hand_are_refused():
    with pytest.raises(ConfigError, match="spawn_offsets"):
        BaodingEnv(BaodingConfig(num_envs=1, spawn_offsets=((0.0, -0.01, 0.05), (0.01, -0.01, 0.05))))


def test_a_resting_ball_does_not_sink():
    env = BaodingEnv(BaodingConfig(num_envs=1, joint_noise=0.0, spawn_noise=0.0))
    m, d = env.model, mujoco.MjData(env.model)
    balls = set(env.ball_geom.tolist())
    deepest = 0.0
    for _ in range(100):  # 2 s holding the start pose
        env.step(np.tile(env.ctrl_to_action(env.initial_ctrl), (1, 1)))
        env.sim.batch.get_data(0, d)
        mujoco.mj_forward(m, d)
        deepest = max([deepest] + [-c.dist for _, c in _ball_contacts(m, d, balls)])
    assert deepest < 0.002


@pytest.mark.parametrize("bad", [dict(contact_timeconst=0.005), dict(contact_solimp=(0.99, 0.9, 0.001)),
                                 dict(contact_dampratio=0.0)])
def test_unstable_contact_parameters_are_refused(bad):
    with pytest.raises(ConfigError, match="sim.contact"):
        SimConfig(**bad)


def test_ball_friction_is_the_friction_of_its_contacts_with_the_hand():
    env = BaodingEnv(BaodingConfig(num_envs=1, ball_friction=0.3, joint_noise=0.0, spawn_noise=0.0))
    m, d = env.model, mujoco.MjData(env.model)
    for _ in range(5):
        env.step(np.tile(env.ctrl_to_action(env.initial_ctrl), (1, 1)))
    env.sim.batch.get_data(0, d)
    mujoco.mj_forward(m, d)
    frictions = [c.friction[0] for _, c in _ball_contacts(m, d, set(env.ball_geom.tolist()))]
    assert frictions and np.allclose(frictions, 0.3)


def test_randomisation_changes_what_the_physics_uses():
    cfg = BaodingConfig(num_envs=16, randomization=RandomizationConfig(enabled=True, torque_limit_scale=(0.2, 0.4)))
    env = BaodingEnv(cfg)
    limits = env.sim.expand("actuator_forcerange")[:, :, 1]
    assert np.all((limits >= 0.1 - 1e-9) & (limits <= 0.2 + 1e-9)) and limits.std() > 0
    assert env.sim.expand("geom_friction")[:, env.ball_geom[0], 0].std() > 0
    assert env.sim.expand("opt.gravity")[:, 2].std() > 0
    rng = np.random.default_rng(0)
    peak = np.zeros((16, 16))
    for _ in range(10):
        env.step(rng.choice([-1.0, 1.0], size=(16, 16)))
        peak = np.maximum(peak, np.abs(env.sim.actuator_force))
    assert np.all(peak <= limits + 1e-9), "each env's motors obey its own drawn limit"


def _press_on_surface(tactile, model, data, patch_index, cells, force):
    """Readings of one contact of `force` N at grid coordinates `cells` of a patch (no noise)."""
    p = tactile.layout.patches[patch_index]
    local, _ = p.surface_points(cells[None])
    b = model.body(p.body).id
    world = local[0] @ data.xmat[b].reshape(3, 3).T + data.xpos[b]
    sd = np.zeros((1, model.nsensordata))
    adr = model.sensor_adr[model.sensor(f"skin_{p.name}").id]
    sd[0, adr], sd[0, adr + 1], sd[0, adr + 4:adr + 7] = 1.0, force, world
    return tactile.readings(sd, data.xpos[None], data.xmat[None])[0]


def _noiseless_skin_at_the_start_pose():
    """(skin, model, data at the start pose, its noise-free tactile model)."""
    skin = replace(default_skin(), noise=0.0)
    env = BaodingEnv(BaodingConfig(num_envs=1, skin=skin))
    m, d = env.model, mujoco.MjData(env.model)
    d.qpos[:] = env.sim.qpos[0]
    mujoco.mj_forward(m, d)
    return skin, m, d, TactileModel(skin, m)


def test_taxels_report_the_force_of_contacts_on_the_covered_area():
    skin, m, d, tactile = _noiseless_skin_at_the_start_pose()
    rng = np.random.default_rng(0)
    for k, patch in enumerate(skin.patches):
        cells = patch.grid_cells().astype(float)
        points = cells[rng.integers(0, len(cells), 60)] + rng.uniform(-0.5, 0.5, (60, 2))
        for force in (0.5, 2.0):
            shares = [_press_on_surface(tactile, m, d, k, c, force).sum() / force for c in points]
            assert min(shares) >= 0.98, (patch.name, force)


def test_cap_rows_are_not_bunched():
    for patch in default_skin().patches:
        if patch.surface != "capsule":
            continue
        pos, _ = patch.local_positions()
        cells = patch.grid_cells()
        for row in range(patch.rows):
            ring = pos[cells[:, 0] == row]
            gaps = np.linalg.norm(np.diff(ring, axis=0), axis=1)
            assert gaps.min() >= 0.8 * patch.pitch, (patch.name, row)


def test_a_cap_layout_that_leaves_the_surface_is_refused():
    with pytest.raises(ConfigError, match="skin.tip.rows"):
        Patch(name="tip", body="index_distal", surface="capsule", rows=30, cols=6, pitch=0.0026,
              origin=(0, 0, 0.009), radius=0.012, length=0.02)


@pytest.mark.parametrize("task, steps", [("hard", 5), ("hold", 50), ("simple", 0)])
def test_success_waits_for_the_task_s_hold(task, steps):
    env = BaodingEnv(BaodingConfig(num_envs=1, task=task))
    reached, no_fall = np.array([True]), np.array([False])
    results = [bool(env._success(reached, no_fall)[0]) for _ in range(steps + 1)]
    assert results == [False] * steps + [True]
    assert not env._success(reached, np.array([True]))[0], "a fall during the hold is no success"


def test_squeezing_the_balls_costs_reward_above_the_free_force():
    env = BaodingEnv(BaodingConfig(num_envs=2))
    for _ in range(10):  # close every finger as hard as the motors allow
        *_, info = env.step(np.ones((2, 16)))
    forces = env.ball_contact_forces()
    expected = -0.05 * np.maximum(forces - 5.0, 0).sum(1)
    assert forces.max() > 5.0 and np.allclose(info["reward_terms"]["squeeze"], expected)
    env.reset(seed=0)
    *_, info = env.step(np.tile(env.ctrl_to_action(env.initial_ctrl), (2, 1)))
    assert (info["reward_terms"]["squeeze"] == 0).all(), "holding the balls gently is free"


def test_the_tail_hinge_charges_only_the_force_above_its_own_threshold():
    reward = RewardConfig(squeeze_tail=-1.0, squeeze_tail_force=8.0)
    env = BaodingEnv(BaodingConfig(num_envs=2, reward=reward))
    for _ in range(10):  # close every finger as hard as the motors allow
        *_, info = env.step(np.ones((2, 16)))
    forces = env.ball_contact_forces()
    assert forces.max() > 8.0, "the fist presses a ball harder than the hinge's force"
    assert np.allclose(info["reward_terms"]["squeeze_tail"], -np.maximum(forces - 8.0, 0).sum(1))
    assert np.allclose(info["reward_terms"]["squeeze"], -0.05 * np.maximum(forces - 5.0, 0).sum(1))
    with pytest.raises(ConfigError, match="reward.squeeze_tail_force"):
        RewardConfig(squeeze_free_force=5.0, squeeze_tail_force=4.0)


def test_a_typical_contact_activates_4_to_5_taxels_on_every_patch():
    """The paper's 4-5 taxels per ball contact, on average over where the contact lands, at the
    task's typical contact force (TYPICAL_CONTACT_FORCE, measured on the ground-truth policy)."""
    skin, m, d, tactile = _noiseless_skin_at_the_start_pose()
    rng = np.random.default_rng(1)
    for k, patch in enumerate(skin.patches):
        cells = patch.grid_cells().astype(float)
        inner = cells[(cells[:, 0] > 0) & (cells[:, 0] < patch.rows - 1)]
        points = inner[rng.integers(0, len(inner), 100)] + rng.uniform(-0.5, 0.5, (100, 2))
        counts = [(_press_on_surface(tactile, m, d, k, c, TYPICAL_CONTACT_FORCE) > 0).sum() for c in points]
        assert 3.8 <= np.mean(counts) <= 5.0, (patch.name, np.mean(counts))


def test_a_policy_of_the_earlier_hand_is_refused_naming_what_differs():
    from tacgnn.config import to_dict
    from tacgnn.learning.checkpoint import CheckpointError, stored_env_config

    env_config = to_dict(BaodingConfig())
    assert stored_env_config({"env_config": env_config}, "new.pt").hand.torque_limit == 0.5
    del env_config["hand"]["torque_limit"]
    with pytest.raises(CheckpointError, match="hand.torque_limit"):
        stored_env_config({"env_config": env_config}, "old.pt")


def test_randomised_ball_mass_is_the_mass_the_dynamics_use():
    cfg = BaodingConfig(num_envs=2, randomization=RandomizationConfig(enabled=True, ball_mass=(0.5, 0.5),
                                                                       gravity=(9.81, 9.81)))
    env = BaodingEnv(cfg)
    for b, adr in enumerate(env.ball_qpos_adr):  # both balls in free air, 1 m above the hand
        env.sim.qpos[:, adr:adr + 3] = (0.3 * (2 * b - 1), 0.0, 1.0)
    env.sim.qvel[:] = 0.0
    env.sim.xfrc_applied[:] = 0.0
    env.sim.xfrc_applied[:, env.ball_body[0], 2] = 2.0  # 2 N up on ball 0
    qacc = env.sim.batch.bind("qacc")  # an output array, filled by the next call
    env.sim.forward(np.arange(2))
    dof = env.ball_dof_adr[0] + 2
    assert np.allclose(qacc[:, dof], 2.0 / 0.5 - 9.81, atol=1e-6)  # a = F / m - g with the drawn 0.5 kg
