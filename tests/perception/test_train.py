"""Perception training: objectives, a tiny run that learns, checkpoints, resume, bad input."""

import numpy as np
import pytest
import torch

from tacgnn.datasets.baoding_data import BaodingDataConfig, generate
from tacgnn.perception.objectives import Objective, targets
from tacgnn.perception.train import PerceptionTrainConfig, evaluate, load_checkpoint, load_model, train


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("data") / "baoding"
    generate(BaodingDataConfig(samples=800, shard_size=400, num_envs=32), root)
    return root


def test_baoding_loss_is_permutation_invariant():
    obj = Objective("baoding")
    target = torch.randn(5, 6)
    swapped = target[:, [3, 4, 5, 0, 1, 2]]
    assert obj.loss(swapped, target) == 0.0
    assert obj.loss(target + 1, target) == pytest.approx(1.0)


@pytest.mark.parametrize("task", ["cube", "meat_can", "cylinder"])
def test_orientation_error_knows_symmetry_and_units(task):
    obj = Objective(task)
    rot = torch.linalg.qr(torch.randn(4, 3, 3))[0]
    rot = rot * torch.sign(torch.det(rot))[:, None, None]
    data = {"object_pos": np.zeros((4, 3)), "object_rot": rot.numpy()}
    target = torch.from_numpy(targets(data, task))
    assert obj.metrics(target, target)["orientation_rmse_deg"] == pytest.approx(0.0, abs=0.1)
    # a 10 degree turn about the object's z axis reads as 10 degrees
    c, s = np.cos(np.radians(10)), np.sin(np.radians(10))
    turned = rot.numpy() @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    if task == "cylinder":  # turning about its own axis is ignored: turn about x instead
        turned = rot.numpy() @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    pred = torch.from_numpy(targets({"object_pos": np.zeros((4, 3)), "object_rot": turned}, task))
    assert obj.metrics(pred, target)["orientation_rmse_deg"] == pytest.approx(10.0, abs=0.1)
    if task == "cube":  # a quarter turn of a cube looks the same
        quarter = rot.numpy() @ np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
        pred = torch.from_numpy(targets({"object_pos": np.zeros((4, 3)), "object_rot": quarter}, task))
        assert obj.metrics(pred, target)["orientation_rmse_deg"] == pytest.approx(0.0, abs=0.1)


def test_tacgnn_learns_ball_positions_and_resumes_exactly(dataset, tmp_path):
    cfg = PerceptionTrainConfig.for_task("baoding", "tacgnn", epochs=4, threads=1)
    train(cfg, dataset, tmp_path / "full", log=lambda *_: None)
    history = load_checkpoint(tmp_path / "full" / "checkpoint.pt")["history"]
    assert history[-1]["loss"] < 0.7 * history[0]["loss"]
    # interrupted after 2 epochs, resumed to 4: identical weights
    train(PerceptionTrainConfig.for_task("baoding", "tacgnn", epochs=2, threads=1), dataset,
          tmp_path / "part", log=lambda *_: None)
    payload = load_checkpoint(tmp_path / "part" / "checkpoint.pt")
    payload["config"]["epochs"] = 4  # same run, longer budget
    torch.save(payload, tmp_path / "part" / "checkpoint.pt")
    train(cfg, dataset, tmp_path / "part", resume=True, log=lambda *_: None)
    a, b = load_model(tmp_path / "full" / "checkpoint.pt")[0], load_model(tmp_path / "part" / "checkpoint.pt")[0]
    assert all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), b.state_dict().values()))


def test_model_beats_the_mean_predictor(dataset, tmp_path):
    cfg = PerceptionTrainConfig.for_task("baoding", "mlp", epochs=30, threads=1)
    m = train(cfg, dataset, tmp_path / "mlp", log=lambda *_: None)
    from tacgnn.perception.train import load_tactile, split

    tr, te = split(load_tactile(dataset, "baoding"), 0.8, 0)
    mean_rmse = Objective("baoding").metrics(tr.targets.mean(0).expand_as(te.targets), te.targets)
    assert m["test/position_rmse_cm"] < 0.9 * mean_rmse["position_rmse_cm"]


def test_bad_checkpoints_and_datasets_fail_loudly(dataset, tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="bad.pt"):
        load_checkpoint(bad)
    with pytest.raises(FileNotFoundError):
        load_checkpoint(tmp_path / "missing.pt")
    cfg = PerceptionTrainConfig.for_task("cube", "mlp", epochs=1)
    with pytest.raises(ValueError, match="kind='baoding'"):
        train(cfg, dataset, tmp_path / "x")
    with pytest.raises(ValueError, match="out_dim"):
        PerceptionTrainConfig(task="cube")
    # a checkpoint holding code cannot be loaded: weights_only refuses arbitrary objects
    torch.save({"format_version": 1, "evil": object()}, tmp_path / "evil.pt")
    with pytest.raises(ValueError, match="evil.pt"):
        load_checkpoint(tmp_path / "evil.pt")
    train(PerceptionTrainConfig.for_task("baoding", "mlp", epochs=1), dataset, tmp_path / "ok", log=lambda *_: None)
    assert "position_rmse_cm" in evaluate(tmp_path / "ok" / "checkpoint.pt", dataset, dead_fraction=0.1)
