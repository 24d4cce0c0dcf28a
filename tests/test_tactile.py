"""The tactile model: one contact presses 4-5 taxels of the right patch and keeps its force."""

from dataclasses import replace

import mujoco
import numpy as np
import pytest

from tacgnn.hand.allegro import HandConfig
from tacgnn.hand.skin_layout import TYPICAL_CONTACT_FORCE, default_skin
from tacgnn.sim.scene import SimConfig, add_sphere, compile_with_skin, hand_scene
from tacgnn.sim.tactile import TactileModel

BALL_RADIUS = 0.02625


def _press_scene(skin):
    sim, hand = SimConfig(), HandConfig()
    spec = hand_scene(hand, sim)
    spec.option.gravity = [0, 0, 0]
    add_sphere(spec, "ball", BALL_RADIUS, 0.15, (0, 0, 0.3), 1.0)
    model = compile_with_skin(spec, skin, sim)
    pose = np.clip([0, 0.3, 0.3, 0.3] * 3 + [0.8, 0.3, 0.3, 0.3], *np.asarray(hand.joint_ranges).T)
    return model, mujoco.MjData(model), TactileModel(skin, model), pose


def press(model, data, tactile, pose, patch, force, steps=40):
    """Push the ball onto the middle of a patch with `force` newtons; return readings, contact force."""
    mujoco.mj_resetData(model, data)
    data.qpos[:16] = data.ctrl[:] = pose
    mujoco.mj_forward(model, data)
    lo, hi = tactile.layout.offsets()[patch], tactile.layout.offsets()[patch + 1]
    pos = tactile.positions(data.xpos[None], data.xmat[None])[0, lo:hi]
    rot = data.xmat[tactile.body_ids[patch]].reshape(3, 3)
    normal = (tactile.local_normals[lo:hi] @ rot.T).mean(0)
    normal /= np.linalg.norm(normal)
    data.qpos[16:19] = pos.mean(0) + normal * (BALL_RADIUS + 5e-4)
    ball = model.body("ball").id
    for _ in range(steps):
        data.xfrc_applied[ball, :3] = -force * normal
        mujoco.mj_step(model, data)
    contact_force = 0.0
    for i in range(data.ncon):
        f = np.zeros(6)
        mujoco.mj_contactForce(model, data, i, f)
        contact_force += f[0]
    return tactile.readings(data.sensordata[None], data.xpos[None], data.xmat[None])[0], contact_force


@pytest.fixture(scope="module")
def scene():
    return _press_scene(replace(default_skin(), noise=0.0))


@pytest.mark.parametrize("patch", range(12))
def test_ball_on_each_patch_presses_a_few_taxels_with_the_contact_force(scene, patch):
    model, data, tactile, pose = scene
    readings, contact_force = press(model, data, tactile, pose, patch, force=TYPICAL_CONTACT_FORCE)
    lo, hi = tactile.layout.offsets()[patch], tactile.layout.offsets()[patch + 1]
    active = np.flatnonzero(readings > 0)
    assert np.all((active >= lo) & (active < hi)), "only the pressed patch reads"
    assert 2 <= len(active) <= 7  # 4-5 on average over where a contact lands: test_faithful_hand.py
    assert contact_force > 1.0
    assert readings.sum() == pytest.approx(contact_force, rel=0.02)


def test_pressed_area_grows_with_force(scene):
    model, data, tactile, pose = scene
    light, _ = press(model, data, tactile, pose, 0, force=0.1)
    heavy, _ = press(model, data, tactile, pose, 0, force=3.0)
    assert (heavy > 0).sum() > (light > 0).sum()


def test_no_contact_reads_zero_and_noise_is_switchable():
    skin = default_skin()
    model, data, tactile, pose = _press_scene(skin)
    mujoco.mj_forward(model, data)
    assert not tactile.readings(data.sensordata[None], data.xpos[None], data.xmat[None]).any()
    readings, _ = press(model, data, tactile, pose, 0, force=0.5)
    rng = np.random.default_rng(0)
    noisy = tactile.readings(data.sensordata[None], data.xpos[None], data.xmat[None], rng)[0]
    assert ((noisy > 0) == (readings > 0)).all()
    ratio = noisy[readings > 0] / readings[readings > 0]
    assert not np.allclose(ratio, 1.0) and np.all(np.abs(ratio - 1) < 0.6)


def test_threshold_zeroes_small_readings(scene):
    model, data, tactile, pose = scene
    readings, _ = press(model, data, tactile, pose, 0, force=0.5)
    strict = TactileModel(replace(tactile.layout, threshold=float(np.sort(readings[readings > 0])[1])), model)
    out = strict.readings(data.sensordata[None], data.xpos[None], data.xmat[None])[0]
    assert 0 < (out > 0).sum() < (readings > 0).sum()
    assert (out[out > 0] == readings[out > 0]).all()
