"""Offline training: a tiny run that learns, exact resume, schedules, the NaN guard, config errors."""

import pytest
import torch

from tacgnn.config import ConfigError
from tacgnn.datasets.store import DatasetError
from tacgnn.perception.checkpoint import CheckpointError, load_checkpoint, load_model
from tacgnn.perception.data import load_tactile, split
from tacgnn.perception.objectives import Objective
from tacgnn.perception.train_config import PerceptionTrainConfig
from tacgnn.perception.training import lr_factor, train


def quiet(*_):
    pass


def test_tacgnn_learns_ball_positions_and_resumes_exactly(dataset, tmp_path):
    cfg = PerceptionTrainConfig.for_task("baoding", "tacgnn", epochs=4, threads=1)
    train(cfg, dataset, tmp_path / "full", log=quiet)
    history = load_checkpoint(tmp_path / "full" / "checkpoint.pt")["history"]
    assert history[-1]["loss"] < 0.7 * history[0]["loss"]
    # interrupted after 2 epochs, resumed to 4: identical weights
    train(PerceptionTrainConfig.for_task("baoding", "tacgnn", epochs=2, threads=1), dataset,
          tmp_path / "part", log=quiet)
    payload = load_checkpoint(tmp_path / "part" / "checkpoint.pt")
    payload["config"]["epochs"] = 4  # same run, longer budget
    torch.save(payload, tmp_path / "part" / "checkpoint.pt")
    train(cfg, dataset, tmp_path / "part", resume=True, log=quiet)
    a, b = load_model(tmp_path / "full" / "checkpoint.pt")[0], load_model(tmp_path / "part" / "checkpoint.pt")[0]
    assert all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), b.state_dict().values()))
    assert not list((tmp_path / "part").glob(".*.tmp"))  # no temp files left behind


def test_model_beats_the_mean_predictor(dataset, tmp_path):
    cfg = PerceptionTrainConfig.for_task("baoding", "mlp", epochs=30, threads=1)
    m = train(cfg, dataset, tmp_path / "mlp", log=quiet)
    tr, te = split(load_tactile(dataset, "baoding"), 0.8, 0)
    mean_rmse = Objective("baoding").metrics(tr.targets.mean(0).expand_as(te.targets), te.targets)
    assert m["test/position_rmse_cm"] < 0.9 * mean_rmse["position_rmse_cm"]


def test_gcn_takes_rest_positions_from_the_caller_or_the_skin(dataset, tmp_path):
    """Without rest positions the GCN's graph comes from the dataset's skin at rest; given ones are kept."""
    from tacgnn.datasets.store import read_manifest
    from tacgnn.perception.rest_positions import rest_positions_cm

    cfg = PerceptionTrainConfig.for_task("baoding", "gcn", epochs=1, threads=1, max_samples=64)
    train(cfg, dataset, tmp_path / "skin", log=quiet)
    stored = load_checkpoint(tmp_path / "skin" / "checkpoint.pt")["rest_positions_cm"]
    assert torch.equal(stored, rest_positions_cm(read_manifest(dataset)["metadata"]["skin"]))
    given = stored + 1.0
    train(cfg, dataset, tmp_path / "given", log=quiet, rest_positions_cm=given)
    assert torch.equal(load_checkpoint(tmp_path / "given" / "checkpoint.pt")["rest_positions_cm"], given)


@pytest.mark.parametrize("fault", ["loss", "gradient"])
def test_non_finite_loss_or_gradient_stops_training_and_keeps_the_last_checkpoint(dataset, tmp_path,
                                                                                  monkeypatch, poison_loss, fault):
    """The run stops naming the batch; the checkpoint it leaves is the last good one."""
    cfg = PerceptionTrainConfig.for_task("baoding", "mlp", epochs=2, threads=1)
    batches_per_epoch = -(-640 // cfg.batch_size)  # 80 % of 800 frames
    poison_loss(fault, at_call=batches_per_epoch + 3)
    with pytest.raises(FloatingPointError, match=f"non-finite {fault}.* at epoch 1, batch 2 of .*run"):
        train(cfg, dataset, tmp_path / "run", log=quiet)
    payload = load_checkpoint(tmp_path / "run" / "checkpoint.pt")
    assert payload["epoch"] == 0 and all(torch.isfinite(t).all() for t in payload["model"].values())
    monkeypatch.undo()
    train(cfg, dataset, tmp_path / "run", resume=True, log=quiet)  # and the run goes on from it
    assert load_checkpoint(tmp_path / "run" / "checkpoint.pt")["epoch"] == 1


def test_lr_schedules():
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
    cfg = PerceptionTrainConfig.for_task("baoding", "tacgnn", epochs=1, threads=1, lr=1e-12)
    train(cfg, dataset, tmp_path / "b", log=quiet)
    model = load_model(tmp_path / "b" / "checkpoint.pt")[0]
    mean = split(load_tactile(dataset, "baoding"), 0.8, 0)[0].targets.mean(0)
    torch.testing.assert_close(model.head[-1].bias.detach(), mean, atol=1e-6, rtol=1e-6)


def test_wrong_dataset_and_config_values_are_named(dataset, tmp_path):
    with pytest.raises(DatasetError, match="kind='baoding'"):
        train(PerceptionTrainConfig.for_task("cube", "mlp", epochs=1), dataset, tmp_path / "x")
    with pytest.raises(ConfigError, match="out_dim"):
        PerceptionTrainConfig(task="cube")
    with pytest.raises(ConfigError, match="'task'"):
        PerceptionTrainConfig(task="teapot")
    for threads in (0, 10_000):
        with pytest.raises(ConfigError, match="'threads'"):
            PerceptionTrainConfig(threads=threads)


def test_a_run_started_from_a_checkpoint_starts_where_it_ended(dataset, tmp_path):
    """init_from: one more epoch from a trained model starts at its error, far below a fresh start;
    a resume reads its own checkpoint; a checkpoint of another network is refused, naming it."""
    cfg = PerceptionTrainConfig.for_task("baoding", "tacgnn", epochs=4, threads=1)
    trained = train(cfg, dataset, tmp_path / "first", log=quiet)
    first = tmp_path / "first" / "checkpoint.pt"
    fresh = load_checkpoint(first)["history"][0]["loss"]
    more = PerceptionTrainConfig.for_task("baoding", "tacgnn", epochs=1, threads=1, lr=1e-6)
    again = train(more, dataset, tmp_path / "more", log=quiet, init_from=first)
    assert load_checkpoint(tmp_path / "more" / "checkpoint.pt")["history"][0]["loss"] < 0.7 * fresh
    assert again["test/position_rmse_cm"] == pytest.approx(trained["test/position_rmse_cm"], rel=0.02)
    # resumed, the run's weights come from its own checkpoint, and it still names where it started
    longer = PerceptionTrainConfig.for_task("baoding", "tacgnn", epochs=2, threads=1, lr=1e-6)
    train(longer, dataset, tmp_path / "more", resume=True, log=quiet, init_from=tmp_path / "gone.pt")
    resumed = load_checkpoint(tmp_path / "more" / "checkpoint.pt")
    assert resumed["epoch"] == 1 and resumed["init_from"] == str(first)
    wider = PerceptionTrainConfig.for_task("baoding", "tacgnn", epochs=1, threads=1, model_kw={"channels": 64})
    with pytest.raises(CheckpointError, match="init_from .* differs in \\['model'\\]"):
        train(wider, dataset, tmp_path / "wider", log=quiet, init_from=first)


def test_a_run_can_start_from_the_perception_inside_a_blind_policy(tmp_path):
    """init_from a blind policy file: the model starts with the weights the policy acts with; a
    policy without a perception, or with another network, is refused, naming the file."""
    from tacgnn.config import from_dict
    from tacgnn.learning.policy import SHIPPED_GROUND_TRUTH, SHIPPED_POLICY
    from tacgnn.perception.checkpoint import build_perception
    from tacgnn.perception.models import PerceptionModelConfig
    from tacgnn.perception.models.temporal import MemoryConfig
    from tacgnn.perception.training import start_from

    stored = torch.load(SHIPPED_POLICY, weights_only=True)["perception"]
    cfg = PerceptionTrainConfig(task="baoding", temporal=True, split="episode",
                                model=from_dict(PerceptionModelConfig, stored["config"]
                                ["model"]), memory=from_dict(MemoryConfig, stored["config"]["memory"]))
    torch.manual_seed(0)
    model = build_perception(cfg.model, True, cfg.memory, None)
    start_from(model, cfg, str(SHIPPED_POLICY))
    assert all(torch.equal(model.state_dict()[k], v) for k, v in stored["model"].items())
    with pytest.raises(CheckpointError, match="init_from .*baoding_gt_policy.pt: a policy trained without"):
        start_from(model, cfg, str(SHIPPED_GROUND_TRUTH))
    wider = PerceptionTrainConfig(task="baoding", temporal=True, split="episode", memory=cfg.memory,
                                  model=from_dict(PerceptionModelConfig, {**stored["config"]["model"], "channels": 64}))
    with pytest.raises(CheckpointError, match="differs in \\['model'\\]"):
        start_from(build_perception(wider.model, True, wider.memory, None), wider, str(SHIPPED_POLICY))
