"""kill -9 at random moments of a training run: no checkpoint is ever corrupt, and the
resumed run ends where an uninterrupted one does, bit for bit (reliability tests 4 and 5)."""

import os
import signal
import subprocess
import sys
import time
from dataclasses import replace

import numpy as np
import torch

from tacgnn.learning.ppo import list_checkpoints, load_checkpoint, train

from test_ppo import ENV, ppo

ITERATIONS = 10
# the same run in a child process; it prints a line after every iteration's checkpoint
CHILD = """
import sys
from dataclasses import replace
from tacgnn.learning.ppo import train
sys.path.insert(0, {tests!r})
from test_ppo import ENV, ppo
train(ENV, replace(ppo({iterations}), save_interval=1), {run_dir!r}, resume={resume})
"""


def _start(run_dir, resume: bool) -> subprocess.Popen:
    code = CHILD.format(tests=os.path.dirname(__file__), iterations=ITERATIONS, run_dir=str(run_dir), resume=resume)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)


def _kill_after_checkpoints(proc, run_dir, count: int, extra_delay: float) -> None:
    """SIGKILL once the run has written `count` more checkpoints, plus a delay that lands the
    kill somewhere inside the next iteration (stepping, updating or saving)."""
    start = len(list_checkpoints(run_dir)) if run_dir.exists() else 0
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if run_dir.exists() and len(list_checkpoints(run_dir)) >= start + count:
            break
        time.sleep(0.005)
    time.sleep(extra_delay)
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGKILL)
    proc.wait()


def test_kill_9_during_training_then_resume_equals_uninterrupted(tmp_path):
    straight = train(ENV, replace(ppo(ITERATIONS), save_interval=1), tmp_path / "straight")
    run_dir = tmp_path / "killed"
    rng = np.random.default_rng(0)
    kills = 0
    resume = False
    while True:
        proc = _start(run_dir, resume)
        _kill_after_checkpoints(proc, run_dir, count=2, extra_delay=float(rng.uniform(0, 0.05)))
        if proc.returncode == 0:
            break
        assert proc.returncode == -signal.SIGKILL, proc.stderr.read().decode()[-2000:]
        kills += 1
        for path in list_checkpoints(run_dir):  # every checkpoint that exists is whole
            load_checkpoint(path)
        resume = True
    assert kills >= 2, "the kills landed in the middle of the run"
    a, b = load_checkpoint(straight), load_checkpoint(list_checkpoints(run_dir)[-1])
    assert b["iteration"] == ITERATIONS
    for key in ("actor_state_dict", "critic_state_dict"):
        for name, tensor in a[key].items():
            assert torch.equal(tensor, b[key][name]), f"{key}.{name}"
    assert torch.equal(a["env_state"]["sim_state"], b["env_state"]["sim_state"])
