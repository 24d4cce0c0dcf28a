"""The MuJoCo Warp backend (`sim.backend: warp`) against the C engine, on the CPU.

One control step from the same state, the skin on the same contacts, the env's rules
and divergence handling on Warp, the host-mirror path a GPU uses, and bad input.
The first run compiles MuJoCo Warp's kernels (about a minute); they are cached after.
"""

import copy
from dataclasses import replace

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco_warp")

import mujoco  # noqa: E402
import mujoco.batch  # noqa: E402

from tacgnn.config import ConfigError, to_dict  # noqa: E402
from tacgnn.envs.baoding import BaodingConfig, BaodingEnv, RandomizationConfig  # noqa: E402
from tacgnn.envs.observation import BALL_COLUMNS  # noqa: E402
from tacgnn.learning.online_perception import OnlinePerception, OnlinePerceptionConfig  # noqa: E402
from tacgnn.perception.models import PerceptionModelConfig  # noqa: E402
from tacgnn.sim.backend import make_sim  # noqa: E402
from tacgnn.sim.scene import SimConfig  # noqa: E402
from tacgnn.sim.skin_signal import SkinSignalConfig  # noqa: E402
from tacgnn.sim.tactile import TactileModel, skin_sensor_columns  # noqa: E402
from tacgnn.sim.tactile_device import DeviceTactile  # noqa: E402
from tacgnn.sim.warp_backend import WarpSim, WarpUnavailable  # noqa: E402

# Per-env gravity, friction, gains, damping and torque limits (joint friction's constraint rows part
# the engines by more than these tests allow); the ball mass and the armature stay at their compiled
# values (MuJoCo 4's C engine keeps a free body's compiled inertia, dof_M0, unless set_const runs;
# MuJoCo Warp recomputes it: see warp_backend.py). The motors' and encoders' effects and the real
# skin's signal chain are the engine's neighbours, not its part: they run on the host, alike for both
# engines (tests/test_randomization.py, tests/test_skin_signal.py).
ON_TIME = {"action_latency": (0.0, 0.0), "joint_latency": (0.0, 0.0), "skin_latency": (0.0, 0.0),
           "backlash": (0.0, 0.0), "joint_bias": (0.0, 0.0), "joint_noise": 0.0, "velocity_noise": 0.0,
           "action_noise": 0.0, "joint_friction": (0.0, 0.0)}
CFG = BaodingConfig(num_envs=4, task="middle", disturbance_interval=1, skin_signal=SkinSignalConfig(preset="ideal"),
                    randomization=RandomizationConfig(enabled=True, ball_mass=(0.15, 0.15), armature_scale=(1.0, 1.0),
                                                      **ON_TIME))
ENV_BUFFERS = ("episode_steps", "angle", "vec_angle", "hold_count", "last_action")


def on_warp(cfg: BaodingConfig) -> BaodingConfig:
    return replace(cfg, sim=replace(cfg.sim, backend="warp"))


def copy_env(c: BaodingEnv, w: BaodingEnv) -> None:
    """Give the Warp env the C env's whole state: physics, per-env model fields, task buffers, RNGs,
    motors and encoders."""
    for name in ("qpos", "qvel", "ctrl", "xfrc_applied", "qacc_warmstart"):
        getattr(w.sim, name)[:] = getattr(c.sim, name)
    randomized = [name for name in mujoco.batch.MODEL_FIELDS if c.sim.batch.expanded(name) is not None]
    assert "opt.gravity" in randomized
    for name in randomized:
        w.sim.expand(name)[:] = c.sim.batch.expanded(name)
    for name in ENV_BUFFERS:
        getattr(w, name)[:] = getattr(c, name)
    w.set_rng_state(c.rng_state())
    w.hand_io.load_state_dict(c.hand_io.state_dict())  # the motors' queued targets, the encoders' state
    w.sim.forward()


@pytest.fixture(scope="module")
def pair():
    """A C env driven 25 steps into contact, and a Warp env given its state."""
    c, w = BaodingEnv(CFG), BaodingEnv(on_warp(CFG))
    c.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(25):
        c.step(np.clip(c.last_action + 0.05 * rng.standard_normal(c.last_action.shape), -1, 1))
    copy_env(c, w)
    c.sim.forward()  # both engines' poses and contacts at the current state (the state is unchanged)
    return c, w


def test_skin_on_the_device_equals_the_compiled_skin(pair):
    """The torch skin model against TactileModel on the same contacts, noise and all."""
    c, w = pair
    sim = c.sim
    device = DeviceTactile(CFG.skin, c.model)
    for seed in (None, 7):
        def rng(seed=seed):
            return None if seed is None else np.random.default_rng(seed)  # the same noise stream for both

        ref = c.tactile.readings(sim.sensordata, sim.xpos, sim.xmat, rng())
        out = device.readings(sim.sensordata, sim.xpos, sim.xmat, rng())
        assert (ref > 0).sum() >= CFG.num_envs
        assert np.abs(out - ref).max() <= 1e-5  # N
    np.testing.assert_allclose(device.positions(sim.xpos, sim.xmat), c.tactile.positions(sim.xpos, sim.xmat),
                               atol=1e-6)
    # on the Warp engine's own (float32) contacts, read from its arrays as torch tensors, no copies
    views = w.sim.device_views()
    out = w.tactile.readings(views["sensordata"], views["xpos"], views["xmat"], np.random.default_rng(3))
    assert isinstance(out, torch.Tensor)
    ref = c.tactile.readings(w.sim.sensordata, w.sim.xpos, w.sim.xmat, np.random.default_rng(3))
    assert (ref > 0).sum() >= CFG.num_envs and np.abs(out.numpy() - ref).max() <= 1e-5


def test_skin_fed_by_the_engine_reads_the_device_not_the_host(pair):
    """`engine_readings` reads the Warp engine's device arrays: on a sim with host mirrors
    (as on a GPU) it gives the compiled skin's readings on the engine's contacts even with
    the mirrors overwritten, and leaves them on the device: nothing crosses to the host until
    a consumer asks for numpy (`to_host`)."""
    c, w = pair
    n, t = CFG.num_envs, CFG.skin.num_taxels
    sim = WarpSim(c.model, n, mirror=True)
    for name in ("qpos", "qvel", "ctrl", "xfrc_applied", "qacc_warmstart"):
        getattr(sim, name)[:] = getattr(w.sim, name)
    sim.forward()
    ref = c.tactile.readings(sim.sensordata, sim.xpos, sim.xmat, np.random.default_rng(5))
    ref_clean, ref_pos = c.tactile.readings(sim.sensordata, sim.xpos, sim.xmat), c.tactile.positions(sim.xpos, sim.xmat)
    assert (ref > 0).sum() >= n
    sim.sensordata[:], sim.xpos[:], sim.xmat[:] = 0.0, np.nan, np.nan  # the host mirrors, not the engine
    skin = DeviceTactile(CFG.skin, c.model)
    out = skin.engine_readings(sim, slice(None), np.random.default_rng(5))
    assert isinstance(out, torch.Tensor) and out.device == torch.device("cpu")  # the engine's device here
    assert skin.host_bytes == 0  # no input went up, no reading came down
    assert np.abs(skin.to_host(out) - ref).max() <= 1e-5  # N
    assert skin.host_bytes == n * t * 4  # asked for: the readings down
    assert isinstance(skin.device_readings, torch.Tensor) and skin.device_readings.shape == (n, t)
    assert torch.equal(skin.device_readings, out)
    # some rows (a reset): those rows replaced on the device, the others kept
    before = skin.device_readings
    rows = np.array([2, 0])
    out = skin.engine_readings(sim, rows, None)
    assert np.abs(out.numpy() - ref_clean[rows]).max() <= 1e-5 and out.shape == (2, t)
    np.testing.assert_array_equal(skin.device_readings[[1, 3]].numpy(), before[[1, 3]].numpy())
    np.testing.assert_array_equal(skin.device_readings[rows].numpy(), out.numpy())
    np.testing.assert_allclose(skin.engine_positions(sim, rows).numpy(), ref_pos[rows], atol=1e-6)


def test_warp_env_steps_with_the_skin_on_the_device():
    """The env on Warp takes its skin from the device arrays and hands it out there: a step
    copies no skin array to the host, and what it hands out is the compiled skin's reading."""
    # randomisation off: its noise draws would come before the skin's in the step
    cfg = on_warp(replace(CFG, num_envs=2, obs_mode="tactile", randomization=RandomizationConfig()))
    env = BaodingEnv(cfg)
    env.reset(seed=0)
    compiled, t = TactileModel(cfg.skin, env.model), cfg.skin.num_taxels
    for _ in range(30):  # until the balls, dropped from above the palm, press the skin
        before, rng = env.tactile.host_bytes, copy.deepcopy(env._rng)  # the skin draws its noise seed first
        obs, _, terminated, truncated, info = env.step(env.last_action.copy())
        assert not (terminated | truncated).any()
        assert env.tactile.host_bytes == before  # readings and taxel positions stay on the device
        assert isinstance(info["tactile"], torch.Tensor) and isinstance(obs["taxel_pos"], torch.Tensor)
        if (info["tactile"] > 0).sum() >= 4:
            break
    assert torch.equal(info["tactile"], env.tactile.device_readings)
    assert torch.equal(obs["taxel_pos"], env.tactile.device_positions)
    ref = compiled.readings(env.sim.sensordata, env.sim.xpos, env.sim.xmat, rng)
    readings = env.skin_to_host(info["tactile"])  # a consumer that needs numpy: counted
    assert env.tactile.host_bytes - before == t * 4 * 2
    assert (ref > 0).sum() >= 4 and np.abs(readings - ref).max() <= 1e-5
    np.testing.assert_allclose(env.skin_to_host(obs["taxel_pos"]), compiled.positions(env.sim.xpos, env.sim.xmat),
                               atol=1e-6)


def test_perception_in_the_loop_reads_the_skin_where_the_engine_leaves_it():
    """'perceived' on Warp: the perception takes the skin's device tensors (no skin array comes
    down in the step) and sees what it sees on the C engine from the same state; its recorded
    frames are the C engine's too."""
    cfg = replace(CFG, obs_mode="perceived")
    skin = to_dict(cfg.skin)
    perceptions = [OnlinePerception(OnlinePerceptionConfig(model=PerceptionModelConfig(name="mlp"), buffer_size=64),
                                    skin, seed=0) for _ in range(2)]
    c, w = BaodingEnv(cfg, perception=perceptions[0]), BaodingEnv(on_warp(cfg), perception=perceptions[1])
    c.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(25):
        c.step(np.clip(c.last_action + 0.05 * rng.standard_normal(c.last_action.shape), -1, 1))
    copy_env(c, w)
    w.perceived_balls[:] = c.perceived_balls
    action = np.clip(c.last_action + 0.3 * rng.standard_normal(c.last_action.shape), -1, 1)
    obs_c, _, term, trunc, info_c = c.step(action)
    before = w.tactile.host_bytes
    obs_w, _, _, _, info_w = w.step(action)
    assert w.tactile.host_bytes == before  # readings and taxel positions stayed on the device
    assert isinstance(info_w["tactile"], torch.Tensor) and isinstance(info_c["tactile"], np.ndarray)
    assert not (term | trunc).any() and (info_c["tactile"] > 0).sum() >= CFG.num_envs
    balls = BALL_COLUMNS  # the perceived ball positions in the observation
    assert np.abs(obs_w[:, balls] - obs_c[:, balls]).max() < 1e-4  # m
    for p, info in zip(perceptions, (info_c, info_w)):
        p.record(info)
    assert perceptions[0].size == perceptions[1].size == CFG.num_envs
    assert (perceptions[1].readings - perceptions[0].readings).abs().max() <= 1e-5
    assert (perceptions[1].positions - perceptions[0].positions).abs().max() <= 1e-4  # cm


def test_one_control_step_matches_the_c_engine(pair):
    c, w = pair
    forces = c.tactile.contacts(c.sim.sensordata)[0]
    assert (forces > 0).sum((1, 2)).min() >= 1  # balls resting on the skin: the step has contacts
    assert np.abs(w.sim.xpos - c.sim.xpos).max() < 1e-6  # same state, same poses
    action = np.clip(c.last_action + 0.3 * np.random.default_rng(1).standard_normal(c.last_action.shape), -1, 1)
    _, rew_c, term_c, trunc_c, info_c = c.step(action)
    _, rew_w, term_w, trunc_w, info_w = w.step(action)
    assert not (term_c | trunc_c).any() and not (term_w | trunc_w).any()
    assert np.abs(info_w["ball_pos"] - info_c["ball_pos"]).max() < 1e-4  # m
    assert np.abs(w.joint_pos - c.joint_pos).max() < 1e-4  # rad
    assert np.abs(c.sim.xfrc_applied).max() > 0  # the kicks of the 'middle' task were applied, equally
    np.testing.assert_allclose(w.sim.xfrc_applied, c.sim.xfrc_applied, atol=1e-7)
    np.testing.assert_allclose(rew_w, rew_c, atol=0.05)  # 0.5 per degree of rotation


def test_control_steps_match_over_many_states():
    """32 envs x 4 states, fingers pressing balls and links on the palm: every env within
    1e-4 after one control step. (With Warp's CCD box-box test, 3 % of env steps were not.)
    And on each step's Warp contacts, the skin fed by the engine's device arrays reads as
    the compiled skin (to 1e-5 N; a float32 link-frame transform was 2e-5 N off)."""
    cfg = replace(CFG, num_envs=32)
    c, w = BaodingEnv(cfg), BaodingEnv(on_warp(cfg))
    c.reset(seed=0)
    rng = np.random.default_rng(0)
    joint_gap, ball_gap, compared, skin_gap, pressed = [], [], 0, [], 0
    for _ in range(4):
        for _ in range(10):
            c.step(np.clip(c.last_action + 0.05 * rng.standard_normal(c.last_action.shape), -1, 1))
        w.load_state_dict(c.state_dict())
        action = np.clip(c.last_action + 0.3 * rng.standard_normal(c.last_action.shape), -1, 1)
        _, _, terminated, truncated, info_c = c.step(action)
        _, _, _, _, info_w = w.step(action)
        kept = ~(terminated | truncated)  # rows the step did not reset
        compared += kept.sum()
        joint_gap.append(np.abs(w.joint_pos - c.joint_pos)[kept].max())
        ball_gap.append(np.abs(info_w["ball_pos"] - info_c["ball_pos"])[kept].max())
        seed = int(rng.integers(1 << 30))
        ref = c.tactile.readings(w.sim.sensordata, w.sim.xpos, w.sim.xmat, np.random.default_rng(seed))
        pressed += (ref > 0).sum()
        skin_gap.append(np.abs(w.tactile.engine_readings(w.sim, slice(None), np.random.default_rng(seed)).numpy()
                               - ref).max())
    assert compared >= 100
    assert max(joint_gap) < 1e-4 and max(ball_gap) < 1e-4, (joint_gap, ball_gap)
    assert pressed >= 100 and max(skin_gap) <= 1e-5, skin_gap


def test_a_diverging_env_is_reset_alone_on_warp():
    """Timestep x400 in env 1 explodes it (it overflows its constraint rows): it is flagged
    diverged and reset, the others step on."""
    cfg = on_warp(replace(CFG, randomization=RandomizationConfig()))
    env = BaodingEnv(replace(cfg, sim=replace(cfg.sim, warp_nconmax=256)))  # room for the exploding env's contacts
    env.reset(seed=0)
    env.sim.expand("opt.timestep")[1] = 2.0
    obs, reward, terminated, _, info = env.step(env.last_action.copy())
    assert info["diverged"].tolist() == [False, True, False, False]
    assert terminated[1] and reward[1] == 0 and np.isfinite(obs).all()
    env.sim.expand("opt.timestep")[1] = CFG.sim.timestep
    _, _, _, _, info = env.step(env.last_action.copy())
    assert not info["diverged"].any() and np.isfinite(info["ball_pos"]).all()


def test_host_mirror_path_equals_the_views(pair):
    """The GPU path keeps host copies of every array: on the CPU it must give what the views give."""
    c, _ = pair
    sims = WarpSim(c.model, 2), WarpSim(c.model, 2, mirror=True)
    for sim in sims:
        sim.qpos[:] = c.sim.qpos[:2]
        sim.ctrl[:] = c.sim.ctrl[:2]
        sim.expand("opt.gravity")[1] = (0.0, 0.0, -7.0)
        sim.forward()
        sim.step(2)
        sim.reset(np.array([0]))
        sim.qpos[0] = c.sim.qpos[2]
        sim.forward(np.array([0]))
    view, mirror = sims
    for name in ("qpos", "qvel", "xpos", "xmat", "sensordata", "actuator_force"):
        np.testing.assert_array_equal(getattr(mirror, name), getattr(view, name), err_msg=name)
    assert np.abs(view.qpos[1] - c.sim.qpos[1]).max() > 1e-6  # env 1 moved; env 0 was reset and placed
    assert view.host_bytes == 0  # the views copy nothing


def test_host_mirrors_move_only_the_rows_written_and_the_arrays_read(pair):
    """A GPU run's bus traffic: before an engine call only the rows the host changed go up, after it
    an array comes down when the host first reads it, and an array nobody reads never does."""
    c, _ = pair
    view, mirror = WarpSim(c.model, 3), WarpSim(c.model, 3, mirror=True)
    for sim in (view, mirror):
        sim.qpos[:] = c.sim.qpos[:3]
        sim.ctrl[:] = c.sim.ctrl[:3]
        sim.forward()
        sim.step(2)
    _ = mirror.xpos, mirror.xmat  # up to date on the host
    before = mirror.host_bytes
    for sim in (view, mirror):
        sim.ctrl[1] += 0.05  # one env's command
        sim.step(1)  # reads qpos and qvel (the divergence check) and the overflow flags
    row = mirror.ctrl[1].nbytes
    read = mirror._host["qpos"].nbytes + mirror._host["qvel"].nbytes + 3 * 4
    assert mirror.host_bytes - before == row + read
    before = mirror.host_bytes
    np.testing.assert_array_equal(mirror.xpos, view.xpos)  # read after the step: it comes down, once
    np.testing.assert_array_equal(mirror.xpos, view.xpos)
    assert mirror.host_bytes - before == mirror.xpos.nbytes
    assert not np.array_equal(mirror._host["xmat"], view.xmat)  # not read: still the last step's
    np.testing.assert_array_equal(mirror.xmat, view.xmat)  # until it is
    # the engine's state as the host left it: a row written with the arrays out of date lands
    for sim in (view, mirror):
        sim.qvel[2] = 0.0
        sim.step(1)
    for name in ("qpos", "qvel", "ctrl", "xpos", "sensordata", "actuator_force", "qacc_warmstart"):
        np.testing.assert_array_equal(getattr(mirror, name), getattr(view, name), err_msg=name)


def test_host_mirror_leaves_the_skins_sensor_columns_on_the_device(pair):
    """The env's Warp sim (`make_sim`) copies down only the sensordata columns host code reads
    (the balls' contact sensors): the skin's columns stay on the device, NaN on the host, and
    each step moves exactly their bytes less than a mirror of everything."""
    c, _ = pair
    skin_columns = skin_sensor_columns(c.model)
    assert len(skin_columns) > 0 and c.model.nsensordata > len(skin_columns)
    host = np.setdiff1d(np.arange(c.model.nsensordata), skin_columns)
    np.testing.assert_array_equal(make_sim(c.model, 2, replace(CFG.sim, backend="warp")).host_sensors, host)
    full = WarpSim(c.model, 2, mirror=True)
    part = WarpSim(c.model, 2, mirror=True, device_only_sensors=skin_columns)  # as make_sim's on a GPU
    for sim in (full, part):
        sim.qpos[:] = c.sim.qpos[:2]
        sim.ctrl[:] = c.sim.ctrl[:2]
        sim.forward()
    bytes_before = full.host_bytes, part.host_bytes
    full.step(1)
    part.step(1)
    np.testing.assert_array_equal(part.sensordata[:, host], full.sensordata[:, host])
    assert np.isnan(part.sensordata[:, skin_columns]).all()
    assert (full.sensordata[:, skin_columns] != 0).any()  # the skin is pressed: there was something to skip
    np.testing.assert_array_equal(part.device_views()["sensordata"].numpy(), full.sensordata)
    saved = (full.host_bytes - bytes_before[0]) - (part.host_bytes - bytes_before[1])
    assert saved == 2 * len(skin_columns) * full.sensordata.itemsize


def test_forward_of_some_envs_leaves_the_others_derived_arrays(pair):
    """As in the C batch: a reset env's poses are recomputed, the others' stay as of their last step."""
    _, w = pair
    before = w.sim.xpos.copy()
    qpos = w.sim.qpos.copy()
    w.sim.qpos[:, 2] += 0.01  # every env moved, only env 0 recomputed
    w.sim.forward(np.array([0]))
    assert np.abs(w.sim.xpos[0] - before[0]).max() > 1e-3
    np.testing.assert_array_equal(w.sim.xpos[1:], before[1:])
    w.sim.qpos[:] = qpos
    w.sim.forward()


def test_checkpoints_move_between_backends_and_resume_exactly_on_warp(pair):
    """The env's state_dict (MuJoCo's integration-state layout, per-env model fields, task
    buffers, RNGs) from the C engine loads into the Warp env and steps as the C env does;
    a Warp checkpoint resumes bit for bit."""
    c, w = pair
    w.load_state_dict(c.state_dict())
    assert np.abs(w.sim.batch.state.copy() - c.sim.batch.state).max() < 1e-5  # float32 round-off
    action = c.last_action.copy()
    _, _, _, _, info_c = c.step(action)
    saved = w.state_dict()
    obs, reward, _, _, info_w = w.step(action)
    assert np.abs(info_w["ball_pos"] - info_c["ball_pos"]).max() < 1e-4
    w.load_state_dict(saved)
    obs2, reward2, *_ = w.step(action)
    np.testing.assert_array_equal(obs2, obs)
    np.testing.assert_array_equal(reward2, reward)


def test_bad_backend_input_is_named():
    with pytest.raises(ConfigError, match="sim.backend"):
        SimConfig(backend="gpu")
    model = BaodingEnv(replace(CFG, num_envs=1)).model
    model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_FWDINV
    with pytest.raises(WarpUnavailable, match="mjENBL_FWDINV"):
        WarpSim(model, 1)


def test_missing_package_is_named_at_config_time(monkeypatch):
    import importlib.util
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "mujoco_warp" else real(name, *a))
    with pytest.raises(ConfigError, match="mujoco-warp"):
        SimConfig(backend="warp")
