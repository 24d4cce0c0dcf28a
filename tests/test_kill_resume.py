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
from test_ppo import ENV, ppo

from tacgnn.learning.checkpoint import list_checkpoints, load_checkpoint
from tacgnn.learning.train import train

ITERATIONS = 10
# the same run in a child process; it prints a line after every iteration's checkpoint
CHILD = """
import sys
from dataclasses import replace
from tacgnn.learning.train import train
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
    assert not list(run_dir.glob(".*.tmp")), "temp files of killed writes are removed when the run resumes"
    a, b = load_checkpoint(straight), load_checkpoint(list_checkpoints(run_dir)[-1])
    assert b["iteration"] == ITERATIONS
    for key in ("actor_state_dict", "critic_state_dict"):
        for name, tensor in a[key].items():
            assert torch.equal(tensor, b[key][name]), f"{key}.{name}"
    assert torch.equal(a["env_state"]["sim_state"], b["env_state"]["sim_state"])


# --- perceived mode: the perception's frames and the env's perceived balls resume too ----------
def _perceived_run(run_dir, iterations, resume=False):
    """A tiny perceived-mode run: 4 envs, 12-step episodes with kicks, tiny networks, a 64-frame
    perception buffer that wraps, a warm-up round, a perception update every 2 iterations."""
    from tacgnn.envs.baoding import BaodingConfig
    from tacgnn.learning.config import PPOConfig
    from tacgnn.learning.online_perception import OnlinePerceptionConfig
    from tacgnn.perception.models import PerceptionModelConfig

    env = BaodingConfig(obs_mode="perceived", task="middle", max_episode_steps=12)
    ppo = PPOConfig(num_envs=4, num_steps_per_env=4, max_iterations=iterations, save_interval=100,
                    num_learning_epochs=2, num_mini_batches=2, actor_hidden_dims=(16,), critic_hidden_dims=(16,))
    loop = OnlinePerceptionConfig(model=PerceptionModelConfig(name="mlp"), update_every_steps=8, epochs=1,
                                  buffer_size=64, batch_size=16, warmup_rounds=1)
    return train(env, ppo, run_dir, resume=resume, perception_cfg=loop)


def _assert_identical(a, b, where="checkpoint"):
    """Deep equality of checkpoint trees, tensors bit for bit."""
    assert type(a) is type(b), where
    if isinstance(a, dict):
        assert list(a) == list(b), where
        for key in a:
            _assert_identical(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_identical(x, y, f"{where}[{i}]")
    elif isinstance(a, torch.Tensor):
        assert a.dtype == b.dtype and a.shape == b.shape and torch.equal(a, b), where
    else:
        assert a == b, where


def test_perceived_mode_resume_is_bit_identical(tmp_path, monkeypatch):
    """Reliability test 5 with the perception in the loop: 3 iterations, stop, 3 more == 6 straight.

    Every observation the policy saw after the stop, and everything in the final checkpoint
    (weights, optimisers, normalisers, env state with the perceived balls, the perception with
    its generator) and the perception's frame buffer, are equal bit for bit. The stop falls
    between two perception updates (every 2 iterations), so their schedule must not restart."""
    from tacgnn.learning.checkpoint import frames_path
    from tacgnn.learning.rsl_env import RslBaodingEnv

    seen = []
    step = RslBaodingEnv.step

    def recording_step(self, actions):
        out = step(self, actions)
        seen.append(out[0]["policy"].clone())
        return out

    monkeypatch.setattr(RslBaodingEnv, "step", recording_step)
    straight = _perceived_run(tmp_path / "straight", 6)
    straight_obs, seen[:] = list(seen), []
    assert _perceived_run(tmp_path / "resumed", 3).name == "model_000003.pt"
    seen.clear()
    resumed = _perceived_run(tmp_path / "resumed", 6, resume=True)
    assert len(seen) == 3 * 4 and len(straight_obs) > len(seen)
    for i, (a, b) in enumerate(zip(straight_obs[-len(seen):], seen)):
        assert torch.equal(a, b), f"observation of step {i} after the resume"
    a, b = load_checkpoint(straight), load_checkpoint(resumed)
    assert b["iteration"] == 6 and b["perception"]["updates"] == a["perception"]["updates"] == 1 + 3
    _assert_identical(a, b)
    runs = (tmp_path / "straight", tmp_path / "resumed")
    frames = [torch.load(frames_path(run, 6), weights_only=True) for run in runs]
    assert frames[0]["frames"]["size"] == 64  # the buffer wrapped
    _assert_identical(*frames, where="frames")
    # only the newest checkpoint keeps its frames
    assert sorted(p.name for p in (tmp_path / "resumed").glob("perception_frames_*")) == ["perception_frames_000006.pt"]


def test_env_state_dict_restores_every_per_env_array():
    """BaodingEnv.state_dict -> a fresh env: every per-env array of the env equals the original's
    (so a new one left out of EPISODE_STATE fails here), and both then step identically."""
    from tacgnn.envs.baoding import BaodingConfig, BaodingEnv, RandomizationConfig

    def perception(tactile, taxel_pos):  # deterministic, input-dependent, different for the two balls
        w = tactile[..., None] + 1e-3
        centre = (w * taxel_pos).sum(1) / w.sum(1)
        return np.concatenate([centre, centre[:, ::-1]], axis=1)

    cfg = BaodingConfig(num_envs=3, obs_mode="perceived", task="middle", max_episode_steps=7, ball_velocity=True,
                        randomization=RandomizationConfig(enabled=True))
    a, b = BaodingEnv(cfg, perception=perception), BaodingEnv(cfg, perception=perception)
    rng = np.random.default_rng(0)
    a.reset(seed=1)
    b.reset(seed=2)
    for _ in range(9):  # past a reset and a kick
        a.step(rng.uniform(-1, 1, (3, 16)))
    a.hold_count[1] = 2  # as if holding at the goal (hard task), so that it differs from a fresh env's
    b.load_state_dict(a.state_dict())
    per_env = [k for k, v in vars(a).items() if isinstance(v, np.ndarray) and v.ndim and len(v) == 3]
    assert {"episode_steps", "perceived_balls", "hold_count", "true_velocity"} <= set(per_env)
    for key in per_env:
        assert np.array_equal(getattr(a, key), getattr(b, key)), key
    assert a.rng_state() == b.rng_state()
    for t in range(12):
        actions = rng.uniform(-1, 1, (3, 16))
        (oa, ra, *_), (ob, rb, *_) = a.step(actions), b.step(actions)
        assert np.array_equal(oa, ob) and np.array_equal(ra, rb), f"step {t}"


# --- temp files of killed writes ---------------------------------------------------------------
def _tiny(iterations):
    return replace(ppo(iterations), num_envs=4, num_steps_per_env=4, save_interval=1, num_mini_batches=2,
                   actor_hidden_dims=(16,), critic_hidden_dims=(16,))


def _dead_pid() -> int:
    child = subprocess.Popen(["true"])
    child.wait()
    return child.pid


def test_30_resumes_after_killed_writes_leave_no_temp_file(tmp_path, capsys):
    """Each cycle leaves what a writer killed mid-write leaves (temp files of a checkpoint, the
    perception's frames and the run config, named by a dead pid), then resumes one iteration
    further: after 30 cycles no temp file is left, a live writer's temp file is kept, and every
    checkpoint reads."""
    run = tmp_path / "run"
    train(ENV, _tiny(1), run)
    live = subprocess.Popen(["sleep", "60"])  # another process still writing: its file must stay
    try:
        busy = run / f".model_000099.pt.{live.pid}.tmp"
        busy.write_bytes(b"being written")
        for cycle in range(30):
            pid, it = _dead_pid(), cycle + 2
            for name in (f"model_{it:06d}.pt", f"perception_frames_{it:06d}.pt", "config.yaml"):
                (run / f".{name}.{pid}.tmp").write_bytes(b"partial")
            assert len(list(run.glob(".*.tmp"))) == 4
            train(ENV, _tiny(it), run, resume=True)
            assert list(run.glob(".*.tmp")) == [busy], f"cycle {cycle}"
        capsys.readouterr()
    finally:
        live.kill()
        live.wait()
    assert [p.name for p in list_checkpoints(run)][-1] == "model_000031.pt"
    for path in list_checkpoints(run):
        load_checkpoint(path)


# a child that resumes the run and is stopped inside its next checkpoint write
SLOW_WRITER = """
import sys, time, torch
from dataclasses import replace
real_save = torch.save
def slow_save(obj, fh, *args, **kwargs):
    real_save(obj, fh, *args, **kwargs)
    fh.flush()
    print("writing", flush=True)
    time.sleep(60)  # killed here, before the rename
torch.save = slow_save
sys.path.insert(0, {tests!r})
from test_kill_resume import _tiny, ENV
from tacgnn.learning.train import train
train(ENV, _tiny(5), {run_dir!r}, resume=True)
"""


def test_kill_9_inside_checkpoint_writes_then_resume_leaves_no_temp_file(tmp_path):
    """Three real kill -9 while a checkpoint is being written: each leaves its temp file, the next
    run removes it before it starts, and the run that completes leaves none."""
    run = tmp_path / "run"
    train(ENV, _tiny(1), run)
    code = SLOW_WRITER.format(tests=os.path.dirname(__file__), run_dir=str(run))
    for cycle in range(3):
        proc = subprocess.Popen([sys.executable, "-c", code], env={**os.environ, "OMP_NUM_THREADS": "1"},
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        line = ""
        while line != "writing\n" and proc.poll() is None:
            line = proc.stdout.readline()
        assert proc.poll() is None, proc.stderr.read()[-2000:]
        temps = list(run.glob(".*.tmp"))
        assert [p.name for p in temps] == [f".model_000002.pt.{proc.pid}.tmp"], f"cycle {cycle}: {temps}"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        proc.stdout.close()
        proc.stderr.close()
    assert len(list(run.glob(".*.tmp"))) == 1  # the last kill's
    assert train(ENV, _tiny(3), run, resume=True).name == "model_000003.pt"
    assert not list(run.glob(".*.tmp"))
