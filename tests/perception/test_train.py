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


@pytest.mark.parametrize("fault", ["loss", "gradient"])
def test_non_finite_loss_or_gradient_stops_training_and_keeps_the_last_checkpoint(dataset, tmp_path,
                                                                                  monkeypatch, poison_loss, fault):
    """Reliability item 3: the run stops naming the batch; the checkpoint it leaves is the last good one."""
    cfg = PerceptionTrainConfig.for_task("baoding", "mlp", epochs=2, threads=1)
    batches_per_epoch = -(-640 // cfg.batch_size)  # 80 % of 800 frames
    poison_loss(fault, at_call=batches_per_epoch + 3)
    with pytest.raises(FloatingPointError, match=f"non-finite {fault}.* at epoch 1, batch 2 of .*run"):
        train(cfg, dataset, tmp_path / "run", log=lambda *_: None)
    payload = load_checkpoint(tmp_path / "run" / "checkpoint.pt")
    assert payload["epoch"] == 0 and all(torch.isfinite(t).all() for t in payload["model"].values())
    monkeypatch.undo()
    train(cfg, dataset, tmp_path / "run", resume=True, log=lambda *_: None)  # and the run goes on from it
    assert load_checkpoint(tmp_path / "run" / "checkpoint.pt")["epoch"] == 1


def test_lr_schedules():
    from tacgnn.perception.train import lr_factor

    def cfg(**kw):
        return PerceptionTrainConfig.for_task("baoding", **kw)

    assert lr_factor(cfg(lr_schedule="constant"), 50, 100, 10) == 1.0
    cos = cfg(lr_schedule="cosine", lr_final=0.1)
    assert lr_factor(cos, 0, 100, 10) == pytest.approx(1.0)
    assert lr_factor(cos, 100, 100, 10) == pytest.approx(0.1)
    assert lr_factor(cos, 50, 100, 10) == pytest.approx(0.55)
    exp = cfg(lr_schedule="exp", lr_decay=0.5)
    # exp depends on the epoch only, not on the run's length: a resumed longer run matches
    assert lr_factor(exp, 20, 100, 10) == lr_factor(exp, 20, 1000, 10) == pytest.approx(0.25)
    assert lr_factor(cfg(lr_schedule="constant", warmup_epochs=1.0), 4, 100, 10) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="lr_schedule"):
        cfg(lr_schedule="linear")


def test_output_bias_starts_at_the_mean_label(dataset, tmp_path):
    """init_output_bias: before any step the model of an empty frame predicts the mean label."""
    from tacgnn.perception.train import load_tactile, split

    cfg = PerceptionTrainConfig.for_task("baoding", "tacgnn", epochs=1, threads=1, lr=1e-12)
    train(cfg, dataset, tmp_path / "b", log=lambda *_: None)
    model = load_model(tmp_path / "b" / "checkpoint.pt")[0]
    mean = split(load_tactile(dataset, "baoding"), 0.8, 0)[0].targets.mean(0)
    torch.testing.assert_close(model.head[-1].bias.detach(), mean, atol=1e-6, rtol=1e-6)


def test_checkpoints_from_before_new_keys_load_as_trained(dataset, tmp_path):
    """A checkpoint written before the readout/schedule options existed rebuilds the paper's model."""
    cfg = PerceptionTrainConfig.for_task("baoding", "tacgnn", epochs=1, threads=1, lr_schedule="constant",
                                         init_output_bias=False,
                                         model_kw=dict(use_force=False, force_feature="raw", pool="last"))
    train(cfg, dataset, tmp_path / "old", log=lambda *_: None)
    path = tmp_path / "old" / "checkpoint.pt"
    payload = torch.load(path, weights_only=True)
    for key in ("lr_schedule", "lr_final", "lr_decay", "warmup_epochs", "init_output_bias"):
        payload["config"].pop(key)
    for key in ("force_feature", "pos_scale", "message_layers", "head_layers", "head_hidden", "residual", "pool"):
        payload["config"]["model"].pop(key)
    torch.save(payload, path)
    model, loaded, _ = load_model(path)
    assert loaded.model.pool == "last" and loaded.lr_schedule == "constant" and not loaded.model.use_force
    assert model.head[0].in_features == 32


def test_ball_visibility_split():
    """Ball 0 has an activated taxel at its surface, ball 1 none: errors land in the right group."""
    from tacgnn.perception.train import TactileData, ball_visibility_errors

    positions = torch.zeros(2, 3, 3)
    positions[:, 0] = torch.tensor([0.0, 0.0, -2.6])  # under ball 0 (centre at 0)
    positions[:, 1] = torch.tensor([20.0, 0.0, 0.0])  # active, but far from both balls
    readings = torch.tensor([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
    positions[:, 2] = torch.tensor([6.0, 0.0, -2.6])  # under ball 1, but not active
    targets = torch.tensor([[0.0, 0, 0, 6, 0, 0]] * 2)
    pred = targets + torch.tensor([[0.1, 0.1, 0.1, 1.0, 1.0, 1.0]])
    out = ball_visibility_errors(pred, TactileData(readings, positions, targets), match_balls=False)
    assert out["seen_rmse_cm"] == pytest.approx(0.1) and out["blind_rmse_cm"] == pytest.approx(1.0)
    assert out["blind_fraction"] == pytest.approx(0.5)
    # with matching, a prediction of the balls in swapped order is scored against the swap
    swapped = pred[:, [3, 4, 5, 0, 1, 2]]
    again = ball_visibility_errors(swapped, TactileData(readings, positions, targets), match_balls=True)
    assert again["seen_rmse_cm"] == pytest.approx(0.1)
