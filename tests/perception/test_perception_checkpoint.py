"""Perception checkpoints: unreadable or foreign files are refused naming the file."""

import pytest
import torch

from tacgnn.files import FileProblem
from tacgnn.perception.checkpoint import CHECKPOINT_VERSION, CheckpointError, load_checkpoint, load_model
from tacgnn.perception.train_config import PerceptionTrainConfig
from tacgnn.perception.training import train


def test_bad_checkpoints_fail_naming_the_file(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(FileProblem, match="bad.pt"):
        load_checkpoint(bad)
    (tmp_path / "empty.pt").write_bytes(b"")
    with pytest.raises(FileProblem, match="empty.pt"):
        load_checkpoint(tmp_path / "empty.pt")
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        load_checkpoint(tmp_path / "missing.pt")
    # a checkpoint holding code cannot be loaded: weights_only refuses arbitrary objects
    torch.save({"format_version": 1, "evil": object()}, tmp_path / "evil.pt")
    with pytest.raises(FileProblem, match="evil.pt"):
        load_checkpoint(tmp_path / "evil.pt")
    torch.save({"format_version": CHECKPOINT_VERSION, "kind": "policy", "actor": {}}, tmp_path / "policy.pt")
    with pytest.raises(CheckpointError, match="policy.pt: not a tacgnn perception checkpoint"):
        load_checkpoint(tmp_path / "policy.pt")


def test_weights_of_another_model_are_refused(dataset, tmp_path):
    cfg = PerceptionTrainConfig.for_task("baoding", "mlp", epochs=1, threads=1, max_samples=64)
    train(cfg, dataset, tmp_path / "run", log=lambda *_: None)
    path = tmp_path / "run" / "checkpoint.pt"
    payload = torch.load(path, weights_only=True)
    payload["config"]["model"]["mlp_hidden"] = [8, 8]
    torch.save(payload, path)
    with pytest.raises(CheckpointError, match="checkpoint.pt: the weights do not fit"):
        load_model(path)


def test_every_committed_perception_checkpoint_reads_in_this_code():
    """The report's perception figures rest on these files: a config key added to the code must not
    make them unreadable (a key only training uses is an argument, not a config key)."""
    from pathlib import Path

    from tacgnn.files import read_weights

    root = Path(__file__).resolve().parents[2] / "results"
    files = [f for f in sorted(root.glob("*/checkpoints/*.pt")) if read_weights(f, "file").get("kind") == "perception"]
    assert len(files) >= 8
    for path in files:
        load_model(path)
