"""Datasets: schema, atomic shards, resume after kill -9 equals an uninterrupted run, corruption is caught."""

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from tacgnn.config import ConfigError
from tacgnn.datasets.baoding_data import BaodingDataConfig, generate
from tacgnn.datasets.store import DatasetError, Field, ShardedWriter, load, read_manifest

SMALL = BaodingDataConfig(samples=600, shard_size=200, num_envs=16)


def test_baoding_dataset_has_the_documented_fields(tmp_path):
    generate(SMALL, tmp_path / "ds")
    data = load(tmp_path / "ds", expect={"num_taxels": 653})
    assert data["tactile"].shape == (600, 653) and data["taxel_pos"].shape == (600, 653, 3)
    assert data["ball_pos"].shape == (600, 2, 3) and data["joint_pos"].shape == (600, 16)
    assert ((data["tactile"] > 0).sum(1) > 0).mean() > 0.9  # balls touch the skin
    # taxel positions near the hand; balls on it (a ball rolling off the edge may dip a little
    # below the hand's origin before the fall rule ends its episode)
    assert np.abs(data["taxel_pos"]).max() < 0.25 and (data["ball_pos"][..., 2] > -0.01).all()
    assert np.median(data["ball_pos"][..., 2]) > 0.02
    with pytest.raises(DatasetError, match="num_taxels"):
        load(tmp_path / "ds", expect={"num_taxels": 500})


def test_generation_is_deterministic(tmp_path):
    generate(SMALL, tmp_path / "a")
    generate(SMALL, tmp_path / "b")
    a, b = load(tmp_path / "a"), load(tmp_path / "b")
    assert all(np.array_equal(a[k], b[k]) for k in a)


SCRIPT = """
import sys, time
from tacgnn.datasets.baoding_data import BaodingDataConfig, record_shard, generate
import tacgnn.datasets.baoding_data as bd
cfg = BaodingDataConfig(samples=600, shard_size=200, num_envs=16)
original = bd.record_shard
def slow(cfg, i, policy=None, **kw):
    out = original(cfg, i, policy, **kw)
    print("shard", i, flush=True)
    time.sleep(30 if i == 1 else 0)  # the kill lands while shard 1 is being made
    return out
bd.record_shard = slow
generate(cfg, sys.argv[1])
"""


def test_kill_during_generation_then_resume_equals_uninterrupted(tmp_path):
    root = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-c", SCRIPT, str(root)], stdout=subprocess.PIPE, text=True)
    lines = []
    while len(lines) < 2:  # shard 0 written, shard 1 in progress
        lines.append(proc.stdout.readline())
    time.sleep(0.2)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    manifest = json.loads((root / "manifest.json").read_text())
    assert list(manifest["shards"]) == ["0"]  # only finished shards are recorded
    with pytest.raises(DatasetError, match="incomplete"):
        load(root)
    generate(SMALL, root)  # resume: makes shards 1 and 2 only
    generate(SMALL, tmp_path / "straight")
    a, b = load(root), load(tmp_path / "straight")
    assert all(np.array_equal(a[k], b[k]) for k in a)


def test_flipped_byte_or_truncation_is_caught(tmp_path):
    generate(SMALL, tmp_path / "ds")
    shard = tmp_path / "ds" / "shard_00001.h5"
    raw = bytearray(shard.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    shard.write_bytes(bytes(raw))
    with pytest.raises(DatasetError, match="shard_00001.h5.*checksum"):
        load(tmp_path / "ds")
    shard.write_bytes(bytes(raw[:100]))
    with pytest.raises(DatasetError, match="checksum"):
        load(tmp_path / "ds")
    (tmp_path / "ds" / "manifest.json").write_text("{not json")
    with pytest.raises(DatasetError, match="manifest"):
        load(tmp_path / "ds")


def test_writer_rejects_bad_shards_and_other_metadata(tmp_path):
    writer = ShardedWriter(tmp_path, {"x": Field((3,))}, {"object": "cube"}, num_shards=2, shard_size=4)
    with pytest.raises(DatasetError, match="'x' has shape"):
        writer.write_shard(0, {"x": np.zeros((4, 2))})
    with pytest.raises(DatasetError, match="NaN"):
        writer.write_shard(0, {"x": np.full((4, 3), np.nan)})
    with pytest.raises(DatasetError, match="metadata.object: 'cube' there, 'cylinder' now"):
        ShardedWriter(tmp_path, {"x": Field((3,))}, {"object": "cylinder"}, num_shards=2, shard_size=4)
    with pytest.raises(DatasetError, match="shard_size: 4 there, 8 now"):
        ShardedWriter(tmp_path, {"x": Field((3,))}, {"object": "cube"}, num_shards=2, shard_size=8)
    # a config key the code gained since (default = old behaviour) does not block a resume
    ShardedWriter(tmp_path, {"x": Field((3,))}, {"object": "cube", "new_key": True}, num_shards=2, shard_size=4)


@pytest.mark.parametrize("obj", ["cube", "cylinder", "meat_can"])
def test_grasp_datasets_hold_real_grasps(tmp_path, obj):
    from tacgnn.datasets.grasp_data import GraspDataConfig
    from tacgnn.datasets.grasp_data import generate as generate_grasps
    from tacgnn.envs.grasp import GraspConfig

    cfg = GraspDataConfig(samples=64, shard_size=64, num_envs=32, grasp=GraspConfig(object=obj))
    generate_grasps(cfg, tmp_path / obj)
    data = load(tmp_path / obj, expect={"object": obj})
    assert (data["tactile"] > 0).sum(1).min() >= 3
    rot = data["object_rot"]
    assert np.allclose(rot @ rot.transpose(0, 2, 1), np.eye(3), atol=1e-6)
    assert np.abs(data["object_pos"]).max() < 0.15


def test_meat_can_face_sets_the_side_it_rests_on(tmp_path):
    """`can_face` reaches the grasp through the CLI's --set, and decides which axis of the can
    ends along the palm normal: the 50 mm one (broad face down) or the 82 mm one (narrow)."""
    from tacgnn.cli import main
    from tacgnn.envs.grasp import GraspConfig, PowerGrasp

    normal = PowerGrasp(GraspConfig(object="meat_can", num_envs=1)).palm_axes[:, 0]
    up_axis = {}
    for face in ("broad", "narrow"):
        out = tmp_path / face
        assert main(["make-dataset", "grasp", "--object", "meat_can", "--out", str(out), "--samples", "48",
                     "--shard-size", "48", "--set", f"can_face={face}"]) == 0
        data = load(out, expect={"object": "meat_can"})
        up = np.abs(np.einsum("nij,i->nj", data["object_rot"], normal)).argmax(1)
        up_axis[face] = np.bincount(up, minlength=3) / len(up)
    assert up_axis["broad"][0] > 0.8 and up_axis["narrow"][2] > 0.8, up_axis
    with pytest.raises(ValueError, match="can_face"):
        GraspConfig(object="meat_can", can_face="upside")


def _small_writer(root, num_shards=3):
    return ShardedWriter(root, {"x": Field((3,)), "y": Field((2,))}, {"kind": "test"}, num_shards=num_shards,
                         shard_size=8)


def _make_shard(i):
    rng = np.random.default_rng(i)
    return {"x": rng.normal(size=(8, 3)), "y": rng.normal(size=(8, 2))}


def _rehash(root, index):
    """Record shard `index`'s current bytes in the manifest, as if it had been written so."""
    from tacgnn.datasets.store import _sha256

    manifest = json.loads((root / "manifest.json").read_text())
    manifest["shards"][str(index)]["sha256"] = _sha256(root / manifest["shards"][str(index)]["file"])
    (root / "manifest.json").write_text(json.dumps(manifest))


def test_broken_hdf5_header_with_a_matching_checksum_is_named(tmp_path):
    _small_writer(tmp_path).generate_missing(_make_shard)
    shard = tmp_path / "shard_00001.h5"
    raw = bytearray(shard.read_bytes())
    raw[:8] = b"GARBAGE!"  # the HDF5 signature
    shard.write_bytes(bytes(raw))
    _rehash(tmp_path, 1)
    with pytest.raises(DatasetError, match=r"shard_00001.h5: not a readable HDF5 shard"):
        load(tmp_path)


@pytest.mark.parametrize("value", [np.inf, -np.inf, np.nan])
def test_non_finite_values_in_a_shard_are_refused_naming_it(tmp_path, value):
    import h5py

    _small_writer(tmp_path).generate_missing(_make_shard)
    with h5py.File(tmp_path / "shard_00002.h5", "r+") as h5:
        h5["y"][5, 1] = value
    _rehash(tmp_path, 2)
    with pytest.raises(DatasetError, match=r"shard_00002.h5: field 'y' holds NaN or Inf \(samples \[5\]\)"):
        load(tmp_path)
    assert load(tmp_path, fields=["x"])["x"].shape == (24, 3)  # only the fields read are checked


@pytest.mark.parametrize("damage", ["flipped byte", "broken header", "truncated", "deleted"])
def test_rerun_verifies_every_shard_and_regenerates_the_bad_ones(tmp_path, damage):
    made = []

    def make(i):
        made.append(i)
        return _make_shard(i)

    _small_writer(tmp_path).generate_missing(make)
    straight = load(tmp_path)
    shard = tmp_path / "shard_00001.h5"
    raw = bytearray(shard.read_bytes())
    if damage == "flipped byte":
        raw[len(raw) // 2] ^= 0xFF
    elif damage == "broken header":
        raw[:8] = b"GARBAGE!"
    if damage == "truncated":
        raw = raw[:len(raw) // 3]
    if damage == "deleted":
        shard.unlink()
    else:
        shard.write_bytes(bytes(raw))
        if damage == "broken header":
            _rehash(tmp_path, 1)  # the checksum alone cannot tell
    made.clear()
    assert _small_writer(tmp_path).generate_missing(make) == 1
    assert made == [1]
    repaired = load(tmp_path)
    assert all(np.array_equal(repaired[k], straight[k]) for k in straight)
    assert _small_writer(tmp_path).generate_missing(make) == 0  # now complete: nothing redone


def test_temp_files_of_killed_writers_are_removed(tmp_path):
    _small_writer(tmp_path, num_shards=1).generate_missing(_make_shard)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        stale = [f".manifest.json.{dead.pid}.tmp", f".shard_00000.h5.{dead.pid}.tmp",
                 ".manifest.json.k2j3h4_q", ".shard_00003.h5.abcdEFGH"]  # the last two: older writers' names
        live = f".shard_00001.h5.{alive.pid}.tmp"
        for name in [*stale, live]:
            (tmp_path / name).write_bytes(b"partial")
        _small_writer(tmp_path, num_shards=1)
        left = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("."))
        assert left == [live]  # a writer that still runs keeps its file
    finally:
        alive.kill()
        alive.wait()


def test_make_dataset_rerun_repairs_a_corrupt_shard(tmp_path):
    from tacgnn.cli import main

    out = tmp_path / "cube"
    args = ["make-dataset", "grasp", "--object", "cube", "--out", str(out), "--samples", "64", "--shard-size", "32"]
    assert main(args) == 0
    straight = load(out)
    shard = out / "shard_00000.h5"
    raw = bytearray(shard.read_bytes())
    raw[:8] = b"GARBAGE!"
    shard.write_bytes(bytes(raw))
    _rehash(out, 0)
    assert main(args) == 0  # the rerun finds the bad shard and makes it again
    repaired = load(out)
    assert all(np.array_equal(repaired[k], straight[k]) for k in straight)
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_episode_filter_keeps_only_episodes_that_reach_the_step():
    from tacgnn.datasets.baoding_data import EpisodeFilter

    held = EpisodeFilter(num_envs=2, min_steps=3)
    out = []
    for step in range(1, 5):  # env 0 runs 4 steps; env 1 ends after step 2 and starts again
        frame = {"step": np.array([step, step if step <= 2 else step - 2]), "env": np.array([0, 1])}
        out += held.add(frame, np.array([True, True]), frame["step"])
        held.end(np.array([False, step == 2]))
    kept = [(int(f["env"][0]), int(f["step"][0])) for f in out]
    assert kept == [(0, 1), (0, 2), (0, 3), (0, 4)]  # env 1's short episode and its new one (2 steps) dropped
    frame = {"step": np.array([7, 9])}
    assert EpisodeFilter(2, 0).add(frame, np.array([True, True]), frame["step"]) == [frame]


def test_generation_keeps_long_episodes_whole():
    from tacgnn.datasets.baoding_data import record_shard

    cfg = BaodingDataConfig(samples=300, shard_size=300, num_envs=8, settle_steps=0, keep_every=1, min_episode_steps=30)
    data = record_shard(cfg, 0)
    cut = data["episode"][-1]  # the shard's last episode may be cut short
    for e in np.unique(data["episode"]):
        steps = np.sort(data["step"][data["episode"] == e])
        assert np.array_equal(steps, np.arange(1, len(steps) + 1))  # from its first step, none missing
        assert e == cut or steps[-1] >= 30


def test_a_policy_drives_the_recording_on_the_observation_it_was_trained_on():
    """A ground-truth policy of the canonical ball order with the balls' velocities records
    frames seeing exactly what the 'groundtruth' env of its config shows it, step for step."""
    from dataclasses import replace

    from tacgnn.datasets.baoding_data import record_shard, shard_seed
    from tacgnn.envs.baoding import BaodingConfig, BaodingEnv

    env_cfg = BaodingConfig(obs_mode="tactile", task="continuous", ball_order="canonical", ball_velocity=True)
    cfg = BaodingDataConfig(samples=40, shard_size=40, num_envs=4, action_noise=0.0, env=env_cfg,
                            policy_checkpoint="a policy")
    weights = np.random.default_rng(0).normal(0, 0.3, (60, 16))
    seen: list[np.ndarray] = []

    def policy(obs: np.ndarray) -> np.ndarray:
        seen.append(obs.copy())
        return np.tanh(obs @ weights)

    record_shard(cfg, 0, policy)
    seed = shard_seed(cfg, 0)
    truth = BaodingEnv(replace(env_cfg, obs_mode="groundtruth", tactile=False, num_envs=4, seed=seed))
    obs, _ = truth.reset(seed=seed)
    assert obs.shape == (4, 60) and len(seen) > 5
    for shown in seen:
        np.testing.assert_allclose(shown, obs, atol=1e-6)
        obs = truth.step(np.tanh(obs @ weights))[0]
    assert np.abs(np.stack(seen)[1:, :, 38:44]).max() > 0  # the velocities are shown, not zeros


def test_random_motion_wanders_smoothly_around_the_initial_pose():
    from tacgnn.envs.scripted import RandomMotion

    base = np.linspace(-0.5, 0.5, 16)
    motion = RandomMotion(base, num_envs=256, seed=0, amplitude=(0.15, 0.15), correlation_steps=(20.0, 20.0))
    path = np.stack([motion() for _ in range(400)])  # (steps, envs, joints)
    offset = path - base
    assert abs(offset.mean()) < 0.01 and offset.std() == pytest.approx(0.15, rel=0.05)
    # neighbouring steps nearly agree; 20 steps apart they share about 1/e
    lag1 = np.corrcoef(offset[:-1].ravel(), offset[1:].ravel())[0, 1]
    lag20 = np.corrcoef(offset[:-20].ravel(), offset[20:].ravel())[0, 1]
    assert lag1 > 0.9 and lag20 == pytest.approx(np.exp(-1), abs=0.05)
    assert np.array_equal(RandomMotion(base, 4, seed=1)(), RandomMotion(base, 4, seed=1)())
    varied = RandomMotion(base, 256, seed=2)  # each env its own amplitude, from the default range
    spread = (np.stack([varied() for _ in range(300)]) - base).std(axis=(0, 2))
    assert spread.min() < 0.1 and spread.max() > 0.22


@pytest.mark.parametrize("name", ["wave", "random"])
def test_a_scripted_controller_keeps_its_own_copy_of_the_initial_pose(name):
    """Built from a row of the env's last actions (as every caller does), a controller's path
    must not follow what the env writes there: it would drift with env 0's commands."""
    from tacgnn.datasets.baoding_data import SCRIPTED

    last_action = np.zeros((4, 16))
    free, fed = SCRIPTED[name](last_action[0].copy(), 4, seed=0), SCRIPTED[name](last_action[0], 4, seed=0)
    for _ in range(50):
        expected, actions = free(), fed()
        last_action[:] = actions  # what the env does with each step's actions
        np.testing.assert_array_equal(actions, expected)


def test_random_motion_records_balls_on_the_skin(tmp_path):
    cfg = dataclasses.replace(SMALL, scripted="random")
    generate(cfg, tmp_path / "ds")
    data = load(tmp_path / "ds", expect={"num_taxels": 653})
    assert ((data["tactile"] > 0).sum(1) > 0).mean() > 0.9
    assert read_manifest(tmp_path / "ds")["metadata"]["controller"] == "RandomMotion"
    with pytest.raises(ConfigError, match="scripted"):
        dataclasses.replace(SMALL, scripted="spin")


def test_a_blind_policy_records_the_frames_of_its_own_grip():
    """A blind policy drives the recording on its own perception's ball positions, each shard
    with a perception made afresh: the frames are those of the 'perceived' env, step for step;
    the perception must come with the 'perceived' env and only with it."""
    from dataclasses import replace

    from tacgnn.datasets.baoding_data import record_shard, shard_seed
    from tacgnn.envs.baoding import BaodingEnv
    from tacgnn.learning.checkpoint import load_policy_file, stored_env_config
    from tacgnn.learning.policy import SHIPPED_POLICY, perception_from_checkpoint, policy_from_checkpoint

    data = load_policy_file(SHIPPED_POLICY)
    env_cfg = replace(stored_env_config(data, SHIPPED_POLICY), task="hold")
    act = policy_from_checkpoint(data, SHIPPED_POLICY)
    cfg = BaodingDataConfig(samples=60, shard_size=60, num_envs=3, action_noise=0.0, env=env_cfg,
                            settle_steps=0, keep_every=1, policy_checkpoint=str(SHIPPED_POLICY))
    seen: list[np.ndarray] = []

    def policy(obs: np.ndarray) -> np.ndarray:
        seen.append(obs.copy())
        return act(obs)

    frames = record_shard(cfg, 0, policy, perception=lambda: perception_from_checkpoint(data))
    seed = shard_seed(cfg, 0)
    replay = BaodingEnv(replace(env_cfg, num_envs=3, seed=seed), perception=perception_from_checkpoint(data))
    obs, _ = replay.reset(seed=seed)
    for shown in seen:
        np.testing.assert_array_equal(shown, obs)
        obs, *_, info = replay.step(act(obs))
    np.testing.assert_array_equal(frames["ball_pos"][-3:], info["ball_pos"][-3:])  # no env ended: 3 per step
    assert len(seen) == 20 and np.abs(np.stack(seen)[:, :, 32:38]).max() > 0  # perceived balls, not zeros
    with pytest.raises(ConfigError, match="env.obs_mode"):
        record_shard(cfg, 0, policy)
