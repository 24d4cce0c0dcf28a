"""`tacgnn evaluate` and `tacgnn train-policy` on bad input and failing disks: one line on stderr
naming the file, key or value, exit code 2, no traceback; `--debug` shows the traceback."""

import errno
import os
from dataclasses import replace

import pytest
import torch
from test_ppo import ENV, ppo

from tacgnn import cli
from tacgnn.config import to_dict
from tacgnn.envs.baoding import BaodingConfig
from tacgnn.learning.checkpoint import FORMAT_VERSION, CheckpointError, check_policy_fits, list_checkpoints
from tacgnn.learning.train import train

TINY = ["actor_hidden_dims=[16]", "critic_hidden_dims=[16]", "num_envs=2", "num_mini_batches=2"]


@pytest.fixture(scope="module")
def policy(tmp_path_factory):
    """A 1-iteration ground-truth checkpoint (12-step episodes, tiny networks)."""
    run = tmp_path_factory.mktemp("gt")
    train(ENV, replace(ppo(1), num_envs=2, num_mini_batches=2, actor_hidden_dims=(16,), critic_hidden_dims=(16,)),
          run)
    return run / "model_000001.pt"


def one_line_error(capsys, *argv) -> str:
    """Run the CLI; it must exit with code 2 and print exactly one line on stderr, which is returned."""
    try:
        code = cli.main([str(a) for a in argv])
    except SystemExit as stop:  # argparse's errors
        code = stop.code
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2, lines
    assert len(lines) == 1, lines
    assert "Traceback" not in lines[0]
    return lines[0]


# --- evaluate --------------------------------------------------------------------------
def _bad_file(tmp_path, policy, kind):
    path = tmp_path / f"{kind}.pt"
    if kind == "empty":
        path.write_bytes(b"")
    elif kind == "truncated":
        path.write_bytes(policy.read_bytes()[:1000])
    elif kind == "text":
        path.write_text("not a checkpoint")
    elif kind == "foreign":
        torch.save({"weights": torch.zeros(3)}, path)
    elif kind == "perception":  # a perception checkpoint given where a policy belongs
        torch.save({"format_version": FORMAT_VERSION, "config": {"task": "baoding"}, "model": {}, "dataset": {}}, path)
    return path  # "missing": not written


@pytest.mark.parametrize("kind, named", [
    ("missing", "not found"), ("empty", "empty"), ("truncated", "truncated or corrupt"),
    ("text", "is a text file, not a policy file"), ("foreign", "not a tacgnn PPO checkpoint"), ("perception", "lacks"),
])
def test_evaluate_names_a_bad_checkpoint_file(tmp_path, policy, capsys, kind, named):
    path = _bad_file(tmp_path, policy, kind)
    line = one_line_error(capsys, "evaluate", path, "--episodes", 1, "--envs", 1, "--task", "simple")
    assert str(path) in line and named in line


@pytest.mark.parametrize("args, named", [
    (["--episodes", "0"], "--episodes must be >= 1, got 0"),
    (["--envs", "-3"], "--envs must be >= 1, got -3"),
    (["--episodes", "many"], "many"),
    (["--task", "sideways"], "sideways"),
    (["--set", "hand.stifness=2"], "hand.stifness"),
    (["--set", "ball_mass"], "'ball_mass' must look like key=value"),
    (["--set", "max_episode_steps=abc"], "max_episode_steps"),
    (["--perception", "nowhere.pt"], "nowhere.pt"),
])
def test_evaluate_names_a_bad_argument(policy, capsys, args, named):
    line = one_line_error(capsys, "evaluate", policy, "--task", "simple", "--episodes", 1, "--envs", 1, *args)
    assert named in line


def test_evaluate_refuses_another_observation_mode_before_building_the_policy(policy, capsys, monkeypatch):
    """The env's observation mode is compared with the checkpoint's on the configs: the policy
    network is never built (a tensor size error deep in torch before)."""
    import tacgnn.learning.policy as policy_module

    def never(*args, **kwargs):
        raise AssertionError("the policy network was built before the configs were compared")

    monkeypatch.setattr(policy_module, "MLPModel", never)
    line = one_line_error(capsys, "evaluate", policy, "--task", "simple", "--episodes", 1,
                          "--set", "obs_mode=finger_torque")
    assert "obs_mode" in line and "'groundtruth'" in line and "'finger_torque'" in line and str(policy) in line
    with pytest.raises(CheckpointError, match="obs_mode"):  # --debug: the error itself, traceback and all
        cli.main(["evaluate", str(policy), "--task", "simple", "--set", "obs_mode=finger_torque", "--debug"])


def test_evaluate_names_an_unwritable_output(policy, tmp_path, capsys):
    (tmp_path / "file").write_text("")
    line = one_line_error(capsys, "evaluate", policy, "--task", "simple", "--episodes", 1, "--envs", 1,
                          "--out", tmp_path / "file" / "r.json")
    assert str(tmp_path / "file") in line


def test_policy_fits_compares_what_the_policy_observes():
    """Other physics or skin noise are fine for acting; another observation mode, or a skin with
    another number of taxels under a perceiving policy, are named."""
    perceived = BaodingConfig(obs_mode="perceived")
    checkpoint = {"env_config": to_dict(perceived)}
    check_policy_fits(checkpoint, replace(perceived, ball_mass=0.3, skin=replace(perceived.skin, noise=0.3)))
    with pytest.raises(CheckpointError, match=r"\['obs_mode'\]"):
        check_policy_fits(checkpoint, replace(perceived, obs_mode="groundtruth"))
    fewer = replace(perceived.skin, patches=perceived.skin.patches[:-1])
    with pytest.raises(CheckpointError, match=rf"number of taxels.*653, requested {fewer.num_taxels}"):
        check_policy_fits(checkpoint, replace(perceived, skin=fewer))
    groundtruth = {"env_config": to_dict(BaodingConfig())}
    check_policy_fits(groundtruth, BaodingConfig(tactile=False))  # a ground-truth policy needs no skin
    # the balls shown as the policy was trained: another order would act on the wrong ball, silently
    with pytest.raises(CheckpointError, match="trained with ball_order=as_simulated.*--set ball_order=as_simulated"):
        check_policy_fits(groundtruth, BaodingConfig(ball_order="canonical"))
    with pytest.raises(CheckpointError, match="trained with ball_velocity=False"):
        check_policy_fits(groundtruth, BaodingConfig(ball_velocity=True))
    blind = {"env_config": to_dict(BaodingConfig(obs_mode="no_perception"))}
    check_policy_fits(blind, BaodingConfig(obs_mode="no_perception", ball_order="canonical"))  # it sees no balls


# --- train-policy: folders that cannot be written, full disks --------------------------------
def _train_args(run_dir):
    return ["train-policy", "--run-dir", run_dir, "--env", "tactile=false", "max_episode_steps=12",
            "--ppo", "max_iterations=1", *TINY]


def test_train_names_a_run_folder_that_cannot_be_made(tmp_path, capsys):
    (tmp_path / "file").write_text("")
    line = one_line_error(capsys, *_train_args(tmp_path / "file" / "run"))
    assert f"cannot create the run folder {tmp_path / 'file' / 'run'}" in line


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_train_names_an_unwritable_run_folder(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    run.chmod(0o500)
    try:
        line = one_line_error(capsys, *_train_args(run))
    finally:
        run.chmod(0o700)
    assert str(run) in line and "not writable" in line


def test_train_names_a_full_disk(tmp_path, capsys, monkeypatch):
    """ENOSPC at the rename, or torch's own report of a failed write (a RuntimeError from its zip
    writer): one line naming the file, and no temp file left."""
    real_replace = os.replace

    def full(src, dst, *args, **kwargs):
        if str(dst).endswith(".pt"):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", full)
    line = one_line_error(capsys, *_train_args(tmp_path / "a"))
    assert f"cannot write {tmp_path / 'a' / 'model_000001.pt'}: disk full" in line
    monkeypatch.undo()

    def torch_full(obj, fh, *args, **kwargs):
        fh.write(b"PK partial")
        raise RuntimeError("[enforce fail at inline_container.cc:664] . unexpected pos 320 vs 256")

    monkeypatch.setattr(torch, "save", torch_full)
    line = one_line_error(capsys, *_train_args(tmp_path / "b"))
    assert f"cannot write {tmp_path / 'b' / 'model_000001.pt'}" in line
    for run in ("a", "b"):
        assert not list((tmp_path / run).glob(".*.tmp")) and not list_checkpoints(tmp_path / run)
