"""The Baoding env: spaces, physics sanity, task rules, faults, reproducibility."""

from dataclasses import replace

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from tacgnn.config import ConfigError, override
from tacgnn.envs.baoding import BaodingConfig, BaodingEnv, BaodingSingleEnv, RandomizationConfig
from tacgnn.envs.observation import BALL_COLUMNS
from tacgnn.envs.scripted import FingerWave


def make(n=4, **kw):
    return BaodingEnv(BaodingConfig(num_envs=n, **kw))


def hold(env):
    """Actions that keep every env's hand in its initial pose."""
    return env.last_action.copy()


@pytest.mark.parametrize("mode,dim", [("groundtruth", 54), ("no_perception", 54), ("finger_torque", 64),
                                      ("noise_2", 54), ("noise_10", 54)])
def test_observation_sizes(mode, dim):
    env = make(2, obs_mode=mode)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (2, dim) and obs.dtype == np.float32
    obs, *_ = env.step(hold(env))
    assert np.isfinite(obs).all()
    if mode == "no_perception":
        assert not obs[:, BALL_COLUMNS].any()


def test_tactile_observation_is_the_raw_skin():
    env = make(2, obs_mode="tactile")
    obs, _ = env.reset(seed=0)
    assert obs["tactile"].shape == (2, 653) and obs["taxel_pos"].shape == (2, 653, 3)
    assert obs["proprio"].shape == (2, 48)
    for _ in range(10):
        obs, _, _, _, info = env.step(hold(env))
    assert (obs["tactile"] > 0).any() and np.array_equal(obs["tactile"], info["tactile"])


def test_balls_rest_on_a_still_hand_for_200_steps():
    env = make(4, max_episode_steps=400)
    env.reset(seed=1)
    for t in range(200):
        _, _, terminated, truncated, info = env.step(hold(env))
        assert not (terminated | truncated).any()
        if t == 49:
            settled = info["angle_deg"].copy()
    height = (info["ball_pos"] - env.palm_centre) @ env.palm_axes[:, 0]
    assert np.all(height > 0.02)  # still above the palm, resting on it
    assert np.abs(settled).max() < 45  # the dropped balls roll into place in the first 50 steps ...
    assert np.abs(info["angle_deg"] - settled).max() < 2  # ... and then stay there


def test_check_env_single():
    check_env(BaodingSingleEnv(BaodingConfig()), skip_render_check=True)


def test_seeded_runs_reproduce_bit_for_bit():
    def run():
        env = make(3, task="middle", randomization=RandomizationConfig(enabled=True))
        obs, _ = env.reset(seed=7)
        wave = FingerWave(env.last_action[0], 3, seed=7)
        out = [obs]
        for _ in range(60):
            obs, r, *_ = env.step(wave())
            out += [obs, r]
        return out

    a, b = run(), run()
    assert all(np.array_equal(x, y) for x, y in zip(a, b))


def _teleport_balls(env, positions_fn):
    """Replace physics with a scripted ball trajectory: positions_fn(step) -> (2, 3)."""
    sim = env.sim
    step_count = [0]

    def fake_step(nstep):
        step_count[0] += 1
        q = sim.qpos.copy()
        for b, adr in enumerate(env.ball_qpos_adr):
            q[:, adr:adr + 3] = positions_fn(step_count[0])[b]
        sim.qpos[:] = q
        sim.qvel[:] = 0
        sim.forward()
        return np.zeros(env.num_envs, bool)

    sim.step = fake_step
    # start the episode's angle from the trajectory's first point
    for b, adr in enumerate(env.ball_qpos_adr):
        sim.qpos[:, adr:adr + 3] = positions_fn(0)[b]
    sim.forward()
    env.vec_angle[:] = env._ball_vector_angle(np.arange(env.num_envs))


def _world_circle(env, deg_per_step):
    """Balls turning about the palm normal by deg_per_step (palm plane)."""
    axes = env.palm_axes
    centre = env.palm_centre + axes @ np.array([0.037, 0.0, 0.035])

    def positions(t):
        a = np.deg2rad(deg_per_step * t)
        v = 0.028 * (np.cos(a) * axes[:, 1] + np.sin(a) * axes[:, 2])
        return np.stack([centre - v, centre + v])

    return positions


@pytest.mark.parametrize("angle", [90.0, 180.0])
def test_rotation_by_hand_succeeds_at_the_configured_angle(angle):
    env = make(1, success_angle_deg=angle, reward=replace(BaodingConfig().reward, action=0.0, squeeze=0.0))
    env.reset(seed=0)
    _teleport_balls(env, _world_circle(env, 10.0))
    steps = int(angle / 10)
    for t in range(1, steps + 1):
        _, reward, terminated, _, info = env.step(hold(env))
        if t < steps:
            assert not terminated[0]
            assert reward[0] == pytest.approx(0.5 * 10.0, abs=1e-6)
    assert terminated[0] and info["success"][0]
    assert reward[0] == pytest.approx(0.5 * 10.0 + 250.0, abs=1e-6)
    assert info["angle_deg"][0] == pytest.approx(angle, abs=1e-6)


def test_rotation_the_wrong_way_is_penalised_and_never_succeeds():
    env = make(1)
    env.reset(seed=0)
    _teleport_balls(env, _world_circle(env, -10.0))
    env.step(hold(env))
    for _ in range(30):
        _, reward, terminated, _, info = env.step(hold(env))
        assert reward[0] < 0 and not info["success"][0]


def test_dropped_ball_triggers_the_fall_penalty():
    env = make(1)
    env.reset(seed=0)
    _teleport_balls(env, lambda t: np.array([[0.03, -0.01, -0.10], [-0.03, -0.01, 0.04]]))
    _, reward, terminated, truncated, info = env.step(hold(env))
    assert terminated[0] and info["fall"][0] and not truncated[0]
    assert info["reward_terms"]["fall"][0] == -100.0


def test_timeout_truncates_with_penalty():
    env = make(2, max_episode_steps=5)
    env.reset(seed=0)
    for _ in range(5):
        _, reward, terminated, truncated, info = env.step(hold(env))
    assert truncated.all() and not terminated.any()
    assert np.all(info["reward_terms"]["timeout"] == -50.0)
    assert np.all(env.episode_steps == 0)  # auto-reset, same step


def test_disturbance_every_10_steps_only_in_middle_and_hard():
    for task, expect in (("simple", False), ("middle", True)):
        env = make(2, task=task)
        env.reset(seed=0)
        kicked = []
        for _ in range(25):
            env.step(hold(env))
            kicked.append(np.abs(env.sim.xfrc_applied[:, env.ball_body]).sum() > 0)
        # the force set before step k+1 is visible after it: kicks at steps 10 and 20
        assert [i for i, k in enumerate(kicked) if k] == ([10, 20] if expect else [])


def test_hard_task_needs_the_hold():
    env = make(1, task="hard", success_angle_deg=30.0)
    env.reset(seed=0)
    traj = _world_circle(env, 10.0)
    _teleport_balls(env, lambda t: traj(min(t, 3)))  # reach 30 deg at step 3, then hold
    results = [env.step(hold(env)) for _ in range(8)]
    done_at = [i + 1 for i, r in enumerate(results) if r[2][0]]
    assert done_at[0] == 3 + 5 and results[done_at[0] - 1][4]["success"][0]


def test_nan_in_one_env_resets_only_that_env():
    def run(poison):
        env = make(4)
        env.reset(seed=3)
        wave = FingerWave(env.last_action[0], 4, seed=3)
        rows = []
        for t in range(20):
            if poison and t == 5:
                env.sim.qvel[2, :] = np.nan
            obs, reward, terminated, truncated, info = env.step(wave())
            assert np.isfinite(obs).all() and np.isfinite(reward).all()
            rows.append((obs, reward, info["diverged"]))
        return rows

    clean, poisoned = run(False), run(True)
    assert poisoned[5][2].tolist() == [False, False, True, False]
    for (o1, r1, _), (o2, r2, _) in zip(clean, poisoned):
        keep = [0, 1, 3]
        assert np.array_equal(o1[keep], o2[keep]) and np.array_equal(r1[keep], r2[keep])


def test_diverging_simulation_is_reported_not_stepped_over():
    env = make(2, sim=replace(BaodingConfig().sim, timestep=0.02, contact_timeconst=0.04), control_dt=0.02)
    env.sim.batch.expand("opt.timestep")[:] = 2.0  # x100 ...
    env.sim.batch.expand("actuator_forcerange")[:] = (-1e3, 1e3)  # ... and motors unlimited: explodes
    env.reset(seed=0)
    diverged = False
    for _ in range(5):
        obs, reward, *_, info = env.step(hold(env) + 0.9)
        diverged |= info["diverged"].any()
        assert np.isfinite(obs).all() and np.isfinite(reward).all()
    assert diverged


def test_bad_actions_and_configs_fail_loudly():
    env = make(2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="non-finite"):
        env.step(np.full((2, 16), np.nan))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((3, 16)))
    with pytest.raises(ConfigError, match="did you mean 'task'"):
        override(BaodingConfig(), {"taks": "hard"})
    with pytest.raises(ConfigError, match="ball_mass"):
        BaodingConfig(ball_mass=-0.1)
    with pytest.raises(ConfigError, match="index_j1"):
        override(BaodingConfig(), {"hand.joint_ranges": [[-0.1, 0.1], [1.0, 0.0]] + [[0, 1]] * 14})


def test_domain_randomisation_draws_per_env_physics_in_range():
    env = make(8, randomization=RandomizationConfig(enabled=True))
    env.reset(seed=0)
    mass = env.sim.batch.expanded("body_mass")[:, env.ball_body]
    gravity = -env.sim.batch.expanded("opt.gravity")[:, 2]
    assert np.all((0.075 <= mass) & (mass <= 0.225)) and np.unique(mass).size == mass.size
    assert np.all((7 <= gravity) & (gravity <= 12)) and np.unique(gravity).size == 8


def test_a_ball_randomised_to_its_compiled_mass_keeps_its_compiled_physics():
    """The randomised inertia is MuJoCo's own to the last bit, so a ball drawn at the compiled mass
    leaves the engine's derived constants (the mass matrix dof_M0) exactly as compiled."""
    from tacgnn.envs.baoding import sphere_inertia

    env = make(4, randomization=RandomizationConfig.nominal(0.15))
    assert np.array_equal(sphere_inertia(env.model.body_mass[env.ball_body], BaodingConfig().ball_radius),
                          env.model.body_inertia[env.ball_body, 0])
    env.reset(seed=0)
    assert env.sim.batch.expanded("dof_M0") is None


def test_track_ball_identities_known_answer():
    from tacgnn.envs.baoding import track_ball_identities

    prev = np.array([[0.0, 0, 0, 5, 0, 0], [0.0, 0, 0, 5, 0, 0]])
    pred = np.array([[5.1, 0, 0, 0.1, 0, 0],   # swapped: each ball near the other's last place
                     [0.2, 0, 0, 4.9, 0, 0]])  # in order
    out = track_ball_identities(pred, prev)
    np.testing.assert_allclose(out, [[0.1, 0, 0, 5.1, 0, 0], [0.2, 0, 0, 4.9, 0, 0]])


@pytest.mark.parametrize("track", [True, False])
def test_perceived_balls_keep_their_identity(track):
    """A perception that knows where the balls are but not which is which (it returns them in a
    random order each step): with tracking the policy still sees ball 0 as ball 0 throughout."""
    rng = np.random.default_rng(0)
    env = BaodingEnv(BaodingConfig(num_envs=8, obs_mode="perceived", track_balls=track))

    def unordered(tactile, taxel_pos):
        truth = env.ball_positions().reshape(-1, 6)
        flip = rng.random(len(truth)) < 0.5
        return np.where(flip[:, None], truth[:, [3, 4, 5, 0, 1, 2]], truth)

    env.perception = unordered
    obs, _ = env.reset(seed=0)
    wrong = []
    for _ in range(30):
        wrong.append(np.abs(obs[:, BALL_COLUMNS] - env.ball_positions().reshape(-1, 6)).max(1) > 1e-6)
        obs, *_ = env.step(np.tile(env.last_action[:1], (8, 1)))
    wrong = np.array(wrong)
    if track:
        assert not wrong.any()
    else:
        assert wrong.mean() > 0.3  # without tracking the order is a coin flip


def test_random_state_round_trip_and_older_checkpoints(caplog):
    env = make(3)
    env.reset(seed=4)
    saved = env.rng_state()
    ids = np.arange(3)
    draws = env._env_draws(ids, 5), env._rng.random(4)
    env.reset(seed=99)
    env.set_rng_state(saved)
    assert np.array_equal(env._env_draws(ids, 5), draws[0]) and np.array_equal(env._rng.random(4), draws[1])
    with pytest.raises(ValueError, match="3 env streams"):
        make(2).set_rng_state(saved)
    env.set_rng_state(saved["main"])  # one generator, as saved before per-env streams
    assert "not bit-for-bit" in caplog.text
    assert np.array_equal(env._rng.random(4), draws[1])


@pytest.mark.parametrize("key,value", [("success_angle_deg", 1e9), ("spawn_clearance", -1.0),
                                       ("max_episode_steps", 10**12), ("ball_mass", 1e308), ("ball_radius", 1e308),
                                       ("control_dt", 1e308), ("hand.torque_limit", 1e-30), ("hand.armature", 1e308),
                                       ("sim.timestep", 1e-9), ("sim.contact_timeconst", 1e308)])
def test_values_that_would_hang_or_break_the_simulation_are_refused_naming_the_key(key, value):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        override(BaodingConfig(), {key: value})
