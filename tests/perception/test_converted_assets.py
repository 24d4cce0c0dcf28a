"""Policies of the earlier checkpoint format, converted, act as they did before.

`data/format1_{blind,gt}_policy.pt` are the policy files shipped in format version 1 (a temporal
TacGNN in the loop; its teacher); `data/shipped_policy_outputs.npz` holds what the blind policy's
perception perceived and what both commanded on the inputs below, computed from those files as
they were; `experiments/convert_checkpoints.py`'s conversions must give the same numbers, bit for bit.
"""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from tacgnn.learning import checkpoint as ckpt
from tacgnn.learning.policy import SHIPPED_POLICY, load_perception, load_policy
from tacgnn.perception.checkpoint import CheckpointError

FORMAT_1 = Path(__file__).parent / "data"
REFERENCE = FORMAT_1 / "shipped_policy_outputs.npz"
N, T, STEPS = 4, 653, 6


def perceived(perception, g: np.random.Generator) -> np.ndarray:
    """Six steps of four envs with sparse random skin frames, joint angles and actions."""
    env = SimpleNamespace(num_envs=N, episode_steps=np.zeros(N, np.int64), last_action=np.zeros((N, 16), np.float32))
    perception.bind_env(env)
    base = g.uniform(-0.05, 0.05, (T, 3)).astype(np.float32)
    out = []
    for _ in range(STEPS):
        readings = (g.random((N, T)) * (g.random((N, T)) < 0.05)).astype(np.float32)
        positions = (base[None] + g.normal(0, 0.002, (N, T, 3))).astype(np.float32)
        joints = g.uniform(-0.3, 0.3, (N, 16)).astype(np.float32)
        out.append(perception(readings, positions, joints))
        env.episode_steps += 1
        env.last_action = g.uniform(-1, 1, (N, 16)).astype(np.float32)
    return np.stack(out)


def test_converted_policies_act_as_before(experiment_script, tmp_path):
    converter = experiment_script("convert_checkpoints")
    blind, teacher = tmp_path / "blind.pt", tmp_path / "teacher.pt"
    for old, new in ((FORMAT_1 / "format1_blind_policy.pt", blind), (FORMAT_1 / "format1_gt_policy.pt", teacher)):
        ckpt.save(new, converter.convert(torch.load(old, weights_only=True), old))
    torch.manual_seed(0)
    reference = np.load(REFERENCE)
    g = np.random.default_rng(0)
    np.testing.assert_array_equal(perceived(load_perception(blind), g), reference["perception"])
    for path, key in ((blind, "actions"), (teacher, "teacher_actions")):
        policy, _ = load_policy(path)
        obs = g.normal(0, 1, (8, ckpt.load_policy_file(path)["obs_dim"])).astype(np.float32)
        np.testing.assert_array_equal(policy(obs), reference[key])


def test_a_policy_of_the_earlier_format_is_refused_naming_the_converter(tmp_path):
    old = torch.load(SHIPPED_POLICY, weights_only=True)
    old["format_version"] = 1
    path = tmp_path / "old_policy.pt"
    torch.save(old, path)
    with pytest.raises(ckpt.CheckpointError, match=r"format version 1.*convert_checkpoints\.py"):
        load_policy(path)


def test_a_policy_perception_config_lacking_a_key_is_refused_not_filled_in(tmp_path):
    data = torch.load(SHIPPED_POLICY, weights_only=True)
    del data["perception"]["config"]["model"]["pool"]
    path = tmp_path / "policy.pt"
    torch.save(data, path)
    with pytest.raises(CheckpointError, match=r"lacks keys \['model.pool'\]"):
        load_perception(path)
