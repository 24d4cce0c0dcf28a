"""Training a user can watch: one line per iteration on the console, the full report in the
run folder, a closing line naming the checkpoint; Ctrl-C (SIGINT) and SIGTERM save the
iteration under way, and the run resumes from it bit for bit."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch

SMALL = ["num_envs=4", "num_steps_per_env=4", "num_mini_batches=1", "num_learning_epochs=1", "save_interval=1000"]


def _train(run: Path, iterations: int, *extra: str, background: bool = False):
    argv = [sys.executable, "-m", "tacgnn.cli", "train-policy", "--run-dir", str(run), *extra,
            "--ppo", f"max_iterations={iterations}", *SMALL]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    if background:
        return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    return subprocess.run(argv, capture_output=True, text=True, env=env, timeout=600)


def _actor(path: Path) -> dict:
    return torch.load(path, weights_only=True)["actor_state_dict"]


def test_one_line_per_iteration_and_the_full_log_in_the_run(tmp_path):
    done = _train(tmp_path / "run", 3)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.strip().splitlines()
    iterations = [line for line in lines if line.startswith("iteration ")]
    assert [line.split()[1] for line in iterations] == ["1/3", "2/3", "3/3"]
    assert all("steps/s" in line and "ETA" in line for line in iterations)
    assert len(lines) == 4 and "model_000003.pt" in lines[-1]  # the closing line names the checkpoint
    run = tmp_path / "run"
    log = (run / "train.log").read_text()
    assert log.count("Learning iteration") == 3 and "Actor Model" in log  # rsl_rl's report, kept
    assert (run / "config.yaml").is_file() and not (run / "git").exists()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_saves_the_iteration_under_way_and_the_run_resumes_bit_for_bit(tmp_path, sig):
    run = tmp_path / "stopped"
    proc = _train(run, 1000, background=True)
    assert proc.stdout is not None
    for line in proc.stdout:  # stop it in the middle of the run, away from any save
        if line.startswith("iteration 3/"):
            proc.send_signal(sig)
            break
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == (130 if sig == signal.SIGINT else 128 + sig.value), err
    stopped = re.search(r"stopped by SIG\w+ after iteration (\d+): saved (\S+);", out)
    assert stopped, out + err
    at = int(stopped.group(1))
    assert at >= 3 and Path(stopped.group(2)) == run / f"model_{at:06d}.pt" and Path(stopped.group(2)).is_file()
    resumed = _train(run, at + 2, "--resume")
    assert resumed.returncode == 0, resumed.stderr
    straight = _train(tmp_path / "straight", at + 2)
    assert straight.returncode == 0, straight.stderr
    a, b = _actor(run / f"model_{at + 2:06d}.pt"), _actor(tmp_path / "straight" / f"model_{at + 2:06d}.pt")
    assert all(torch.equal(a[k], b[k]) for k in a)
