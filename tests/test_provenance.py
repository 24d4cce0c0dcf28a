"""Result files name their checkpoints the same way from every clone, worktree and working directory."""

from __future__ import annotations

import hashlib
from pathlib import Path

from tacgnn.provenance import CHECKOUT, provenance

ASSET = Path("src/tacgnn/assets/baoding_gt_policy.pt")


def test_a_file_of_the_checkout_is_named_relative_to_it_from_any_working_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a relative path from here would not name the file
    block = provenance({"policy": CHECKOUT / ASSET}, 0, None)["checkpoints"]["policy"]
    assert block["path"] == str(ASSET)
    assert block["sha256"] == hashlib.sha256((CHECKOUT / ASSET).read_bytes()).hexdigest()


def test_a_file_outside_the_checkout_keeps_the_path_it_was_given(tmp_path):
    weights = tmp_path / "w.pt"
    weights.write_bytes(b"weights")
    assert provenance({"w": weights}, 0, None)["checkpoints"]["w"]["path"] == str(weights)
