"""Training on sequences: windows, exact resume, the CLI, and checkpoints of one kind refused as the other."""

import dataclasses

import pytest
import torch

from tacgnn.perception.checkpoint import CheckpointError, load_model
from tacgnn.perception.evaluation import error_by_steps_since_touch
from tacgnn.perception.evaluation import evaluate as evaluate_sequence
from tacgnn.perception.models.temporal import MemoryConfig
from tacgnn.perception.train_config import TEMPORAL_ROUTE, PerceptionTrainConfig
from tacgnn.perception.training import train as train_sequence
from tests.perception.models.test_temporal import small
from tests.perception.sequence_helpers import episodes, write_dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    arrays = episodes(12, 20, seed=5)  # 240 frames
    return write_dataset(tmp_path_factory.mktemp("seq") / "ds", arrays)


def config(temporal=True, **kw):
    """A temporal MLP on windows of 6 frames, or (temporal=False) the MLP alone on the same split."""
    model = small("mlp")
    route = {**TEMPORAL_ROUTE, "window": 6, "burn_in": 4} if temporal else {"split": "episode"}
    return PerceptionTrainConfig(**{"model": dataclasses.replace(model.frame, out_dim=6),
                                    "memory": MemoryConfig(feature=model.feature, hidden=model.hidden),
                                    **route, "epochs": 2, "batch_size": 4, **kw})


def quiet(_):
    pass


def test_a_run_resumed_with_more_epochs_equals_an_uninterrupted_one(tmp_path, dataset):
    full = train_sequence(config(), dataset, tmp_path / "full", log=quiet)
    train_sequence(config(epochs=1), dataset, tmp_path / "part", log=quiet)
    resumed = train_sequence(config(), dataset, tmp_path / "part", resume=True, log=quiet)
    a = torch.load(tmp_path / "full" / "checkpoint.pt", weights_only=True)["model"]
    b = torch.load(tmp_path / "part" / "checkpoint.pt", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert {k: v for k, v in full.items() if k != "seconds"} == {k: v for k, v in resumed.items() if k != "seconds"}
    for key in ("test/position_rmse_cm", "test/touched_rmse_cm", "test/untouched_rmse_cm"):
        assert 0 < full[key] < 10
    metrics = evaluate_sequence(tmp_path / "full" / "checkpoint.pt", dataset)
    assert metrics["position_rmse_cm"] == pytest.approx(full["test/position_rmse_cm"])
    curve = error_by_steps_since_touch(tmp_path / "full" / "checkpoint.pt", dataset, [0, 1, 3])
    assert curve["count"][0] > 0 and curve["count"][1] > 0 and len(curve["rmse_cm"]) == 3
    # the bins split the evaluated balls: their errors pool back into the overall RMSE
    pooled = sum(c * r ** 2 for c, r in zip(curve["count"], curve["rmse_cm"]) if c) / sum(curve["count"])
    assert pooled ** 0.5 == pytest.approx(metrics["position_rmse_cm"], rel=1e-4)


def test_kinds_of_model_are_told_apart_on_loading(tmp_path, dataset):
    train_sequence(config(epochs=1), dataset, tmp_path / "temporal", log=quiet)
    train_sequence(config(False, epochs=1), dataset, tmp_path / "frame", log=quiet)

    with pytest.raises(CheckpointError, match="a single-frame mlp model.*needs a temporal one"):
        load_model(tmp_path / "frame" / "checkpoint.pt", temporal=True)
    with pytest.raises(CheckpointError, match="a temporal mlp model.*needs a single-frame one"):
        load_model(tmp_path / "temporal" / "checkpoint.pt", temporal=False)
    model, cfg, _ = load_model(tmp_path / "temporal" / "checkpoint.pt")
    assert cfg.temporal and model.cfg.feature == cfg.memory.feature
    frame, cfg, _ = load_model(tmp_path / "frame" / "checkpoint.pt")
    assert not cfg.temporal and cfg.window == 1 and frame.out_dim == 6


def test_checkpoints_of_another_version_or_lacking_a_key_are_refused(tmp_path, dataset):
    train_sequence(config(epochs=1), dataset, tmp_path / "run", log=quiet)
    path = tmp_path / "run" / "checkpoint.pt"
    payload = torch.load(path, weights_only=True)
    torch.save({**payload, "format_version": 1}, tmp_path / "v1.pt")
    with pytest.raises(CheckpointError, match=r"v1.pt: a perception checkpoint of format version 1, this code reads "
                                              r"version 3; convert it once with .*convert_checkpoints.py"):
        load_model(tmp_path / "v1.pt")
    del payload["config"]["memory"]["hidden"]
    torch.save(payload, tmp_path / "lacking.pt")
    with pytest.raises(CheckpointError, match=r"lacking.pt: its config lacks keys \['memory.hidden'\]"):
        load_model(tmp_path / "lacking.pt")


def test_cli_trains_evaluates_and_names_bad_windows(tmp_path, dataset, capsys):
    from tacgnn.cli import main

    frame = ["--set", "memory.feature=16", "memory.hidden=16", "window=4", "burn_in=2", "batch_size=4"]
    assert main(["train-perception", "--temporal", "--model", "mlp", "--dataset", str(dataset), "--run",
                 str(tmp_path / "t"), "--epochs", "1", *frame]) == 0
    assert main(["eval-perception", "--checkpoint", str(tmp_path / "t" / "checkpoint.pt"), "--dataset",
                 str(dataset)]) == 0
    out = capsys.readouterr().out
    assert "touched_rmse_cm" in out and "untouched_rmse_cm" in out
    code = main(["train-perception", "--temporal", "--model", "mlp", "--dataset", str(dataset), "--run",
                 str(tmp_path / "long"), "--window", "21"])
    err = capsys.readouterr().err
    assert code == 2 and "window of 21 frames is longer than every episode" in err and len(err.splitlines()) == 1
    code = main(["train-perception", "--temporal", "--model", "gcn", "--dataset", str(dataset), "--run",
                 str(tmp_path / "gcn")])
    assert code == 2 and "model.name" in capsys.readouterr().err


def test_single_frame_on_the_same_split_reads_frames_one_by_one(tmp_path, dataset):
    final = train_sequence(config(False, epochs=1, batch_size=16), dataset, tmp_path / "f", log=quiet)
    assert 0 < final["test/position_rmse_cm"] < 10


def test_extra_training_episodes_join_training_and_leave_the_test_episodes(tmp_path, dataset):
    extra = write_dataset(tmp_path / "extra", episodes(4, 20, seed=5))  # ids that collide with the main ones
    logs: list[str] = []
    cfg = config(epochs=1, extra_train=(str(extra),))
    final = train_sequence(cfg, dataset, tmp_path / "run", log=logs.append)
    plain = train_sequence(config(epochs=1), dataset, tmp_path / "plain", log=quiet)
    # 10 of the main 12 episodes train (80 %), and the 4 extra ones
    assert any("280 training frames in 14 episodes" in line for line in logs)
    payload = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    assert payload["dataset"]["extra_train_frames"] == 80 and payload["config"]["extra_train"] == [str(extra)]
    # the test episodes are the main dataset's own: the metrics come from the same frames
    assert final["test/position_rmse_cm"] != plain["test/position_rmse_cm"]
    assert evaluate_sequence(tmp_path / "run" / "checkpoint.pt", dataset)["position_rmse_cm"] == \
        pytest.approx(final["test/position_rmse_cm"])
    from tacgnn.datasets.baoding_data import schema
    from tacgnn.datasets.store import DatasetError, ShardedWriter

    fewer = episodes(2, 20, seed=6)
    fewer = {**fewer, "tactile": fewer["tactile"][:, :95], "taxel_pos": fewer["taxel_pos"][:, :95]}
    ShardedWriter(tmp_path / "fewer", schema(95), {"kind": "baoding", "num_taxels": 95}, num_shards=1,
                  shard_size=40).generate_missing(lambda i: fewer)
    with pytest.raises(DatasetError, match=r"fewer \(extra_train\): has 95 taxels"):
        train_sequence(config(epochs=1, extra_train=(str(tmp_path / "fewer"),)), dataset, tmp_path / "bad", log=quiet)


def test_validation_picks_the_epoch_and_the_test_split_is_scored_once_with_it(tmp_path, dataset):
    import json

    logs: list[str] = []
    result = train_sequence(config(epochs=3, val_fraction=0.25), dataset, tmp_path / "v", log=logs.append)
    history = json.loads((tmp_path / "v" / "history.json").read_text())
    # every epoch is scored on validation only; the test figures appear once, in the result
    assert all("val/position_rmse_cm" in row and not any(k.startswith("test/") for k in row) for row in history)
    best = min(history, key=lambda row: row["val/position_rmse_cm"])["epoch"]
    assert result["epoch"] == best and json.loads((tmp_path / "v" / "test.json").read_text()) == result
    chosen = torch.load(tmp_path / "v" / "best.pt", weights_only=True)
    assert chosen["epoch"] == best
    # the test split is the one without validation: the same frames, so the chosen model's figure is its own
    assert evaluate_sequence(tmp_path / "v" / "best.pt", dataset)["position_rmse_cm"] == \
        pytest.approx(result["test/position_rmse_cm"])
    from tacgnn.perception.evaluation import load_data, split_data

    data = load_data(config(), dataset, 0)
    with_val = split_data(config(val_fraction=0.25), data)
    without = split_data(config(), data)
    assert torch.equal(with_val[2].episode, without[2].episode) and without[1] is None
    train_ids, val_ids = set(with_val[0].episode.tolist()), set(with_val[1].episode.tolist())
    assert not train_ids & val_ids and train_ids | val_ids == set(without[0].episode.tolist())


def test_mixed_datasets_share_every_split(tmp_path, dataset):
    from tacgnn.perception.evaluation import load_data, split_data

    other = write_dataset(tmp_path / "other", episodes(12, 20, seed=5))  # the same ids: joined, they must differ
    cfg = config(val_fraction=0.25, mix=(str(other),))
    data = load_data(cfg, dataset, 0)
    assert len(data) == 480 and len(data.episodes()) == 24
    parts = split_data(cfg, data)
    # each split holds episodes of both datasets (ids above the first dataset's come from the second)
    first = set(load_data(config(), dataset, 0).episode.tolist())
    for part in parts:
        ids = set(part.episode.tolist())
        assert ids & first and ids - first
    with pytest.raises(Exception, match="needs split=episode"):
        PerceptionTrainConfig(mix=(str(other),))


def test_the_whole_of_another_dataset_is_read_without_the_training_mix(tmp_path, dataset):
    from tacgnn.perception.evaluation import test_data

    other = write_dataset(tmp_path / "other", episodes(3, 20, seed=7))
    cfg = with_taxels_of(config(mix=(str(dataset),)))
    assert len(test_data(cfg, other, whole=True)) == 60


def with_taxels_of(cfg):
    from tacgnn.perception.checkpoint import with_taxels
    from tests.perception.sequence_helpers import T

    return with_taxels(cfg, T)


def test_a_checkpoint_of_the_previous_format_converts_to_the_same_model(tmp_path, dataset, experiment_script):
    """Format 2 lacked the validation and mix keys; converted, it loads with the values it was
    trained with (none) and the same weights."""
    train_sequence(config(epochs=1), dataset, tmp_path / "run", log=quiet)
    payload = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    old = {**payload, "format_version": 2,
           "config": {k: v for k, v in payload["config"].items() if k not in ("val_fraction", "mix")}}
    torch.save(old, tmp_path / "v2.pt")
    with pytest.raises(CheckpointError, match="version 2"):
        load_model(tmp_path / "v2.pt")
    converter = experiment_script("convert_checkpoints")
    assert converter.main([str(tmp_path / "v2.pt")]) == 0
    model, cfg, _ = load_model(tmp_path / "v2.pt")
    assert cfg.val_fraction == 0.0 and cfg.mix == ()
    for name, weights in model.state_dict().items():
        assert torch.equal(weights, payload["model"][name])
