"""Data-parallel PPO over 2 processes on the CPU (gloo), launched by torchrun as on GPUs.

Run as a script by torchrun (`_worker`), this file trains a tiny Baoding problem on each rank
and saves what the rank ended with; the first test compares the ranks. The others check the
launches that cannot work (a device that is not here, variables torchrun did not set, a
checkpoint of another number of processes): one line, exit 2, before anything is written.
"""

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from unittest import mock

import pytest
import torch

from tacgnn.cli import main as cli_main
from tacgnn.envs.baoding import BaodingConfig
from tacgnn.learning import checkpoint as ckpt
from tacgnn.learning import distributed
from tacgnn.learning.config import PPOConfig
from tacgnn.learning.rsl_env import RslBaodingEnv
from tacgnn.learning.runner import make_runner

ENV = BaodingConfig(tactile=False, max_episode_steps=6)
PPO = PPOConfig(num_envs=4, num_steps_per_env=4, num_mini_batches=2, num_learning_epochs=2, save_interval=100,
                actor_hidden_dims=(32,), critic_hidden_dims=(32,))


def _worker(out: Path) -> None:
    """One rank: train 2 iterations, resume to 3, train 3 straight; save what the rank had after each."""
    from tacgnn.learning import train as train_module

    runners = []

    class Recorded(train_module.Runner):  # type: ignore[name-defined]
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            runners.append(self)

    setup = distributed.from_environment("cpu")
    for name, run, iterations, resume in (("first", "run", 2, False), ("resumed", "run", 3, True),
                                          ("straight", "straight", 3, False)):
        saved = mock.Mock(wraps=ckpt.save)
        with mock.patch.object(train_module, "Runner", Recorded), mock.patch.object(ckpt, "save", saved):
            train_module.train(ENV, replace(PPO, max_iterations=iterations), out / run, resume=resume, dist=setup)
        alg = runners[-1].alg
        torch.save({"actor": alg.actor.state_dict(), "critic": alg.critic.state_dict(),
                    "rollout": alg.storage.observations["policy"].clone(),
                    "backend": torch.distributed.get_backend(),
                    "saves": [Path(call.args[0]).name for call in saved.call_args_list]},
                   out / f"{name}_rank{setup.rank}.pt")
    # rsl_rl's own loop on any VecEnv, through the runner subclass that picks gloo on the CPU
    env = RslBaodingEnv(replace(ENV, num_envs=4, seed=distributed.rank_seed(0, setup)))
    runner = make_runner(env, PPO)
    runner.learn(2)
    torch.save({"actor": runner.alg.actor.state_dict(), "rollout": runner.alg.storage.observations["policy"].clone(),
                "distributed": runner.is_distributed}, out / f"rsl_rl_rank{setup.rank}.pt")
    distributed.shutdown(setup)


def _torchrun(out: Path) -> dict[str, list[dict]]:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2", __file__, str(out)]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return {name: [torch.load(out / f"{name}_rank{r}.pt", weights_only=True) for r in (0, 1)]
            for name in ("first", "resumed", "straight", "rsl_rl")}


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_two_cpu_ranks_train_one_policy_on_different_experience_and_resume_exactly(tmp_path):
    runs = _torchrun(tmp_path)
    ranks = runs["first"]
    assert [r["backend"] for r in ranks] == ["gloo", "gloo"]
    # the gradients were averaged over the ranks: the same networks on both after 2 updates ...
    assert _same(ranks[0]["actor"], ranks[1]["actor"]) and _same(ranks[0]["critic"], ranks[1]["critic"])
    first = ckpt.load_checkpoint(tmp_path / "run" / "model_000001.pt")
    assert not _same(first["actor_state_dict"], ranks[0]["actor"])  # ... which did change them
    # ... although the ranks' rollouts differed (their envs are seeded apart)
    assert not torch.equal(ranks[0]["rollout"], ranks[1]["rollout"])
    # rank 0 alone wrote the checkpoints, which hold rank 1's envs for the resume
    assert ranks[0]["saves"] == ["model_000001.pt", "model_000002.pt"] and ranks[1]["saves"] == []
    last = ckpt.load_checkpoint(tmp_path / "run" / "model_000002.pt")
    assert last["world_size"] == 2 and len(last["rank_states"]) == 1

    resumed, straight = runs["resumed"], runs["straight"]
    assert resumed[0]["saves"] == ["model_000003.pt"] and resumed[1]["saves"] == []
    # each rank went on from its own envs, as they were when the checkpoint was written ...
    assert torch.equal(resumed[0]["rollout"][0], last["env_state"]["obs"])
    assert torch.equal(resumed[1]["rollout"][0], last["rank_states"][0]["env_state"]["obs"])
    # ... so that 2 + 1 iterations are 3 straight ones, bit for bit, on every rank
    for rank in (0, 1):
        assert _same(resumed[rank]["actor"], straight[rank]["actor"])
        assert torch.equal(resumed[rank]["rollout"], straight[rank]["rollout"])
    assert _same(resumed[0]["actor"], resumed[1]["actor"]) and not _same(resumed[0]["actor"], ranks[0]["actor"])

    # rsl_rl's own runner (make_runner, any VecEnv): also one policy from the ranks' different rollouts
    plain = runs["rsl_rl"]
    assert plain[0]["distributed"] and _same(plain[0]["actor"], plain[1]["actor"])
    assert not torch.equal(plain[0]["rollout"], plain[1]["rollout"])


def test_a_checkpoint_resumes_only_with_as_many_processes(tmp_path, capsys):
    from tacgnn.learning.train import train

    run_dir = tmp_path / "run"
    train(ENV, replace(PPO, max_iterations=1), run_dir)
    state = ckpt.load_checkpoint(run_dir / "model_000001.pt")
    assert state["world_size"] == 1 and "rank_states" not in state
    ckpt.save(run_dir / "model_000001.pt", {**state, "world_size": 2})
    code = cli_main(["train-policy", "--run-dir", str(run_dir), "--resume", "--ppo", "max_iterations=2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "written by 2 process(es)" in err[0], err


@pytest.mark.parametrize("environ, device, message", [
    ({}, "cuda", "no CUDA device here"),
    ({"WORLD_SIZE": "2", "RANK": "1", "LOCAL_RANK": "1", "MASTER_ADDR": "localhost", "MASTER_PORT": "1"}, "cuda",
     "no CUDA device here"),
    ({"WORLD_SIZE": "2", "RANK": "0", "LOCAL_RANK": "0", "MASTER_ADDR": "localhost", "MASTER_PORT": "1"}, "cuda:1",
     "each rank takes cuda:LOCAL_RANK"),
    ({"WORLD_SIZE": "2", "RANK": "2", "LOCAL_RANK": "0"}, "cpu", "RANK=2"),
    ({"WORLD_SIZE": "2", "RANK": "0", "LOCAL_RANK": "0"}, "cpu", "MASTER_ADDR and MASTER_PORT not set"),
    ({"WORLD_SIZE": "two"}, "cpu", "WORLD_SIZE='two'"),
    ({}, "tpu", "expected 'cpu', 'cuda' or 'cuda:N'"),
])
def test_a_device_or_launch_that_cannot_work_is_one_line_exit_2(monkeypatch, capsys, tmp_path, environ, device,
                                                                 message):
    if device.startswith("cuda") and torch.cuda.is_available():
        pytest.skip("CUDA is present")
    for name in ("WORLD_SIZE", "RANK", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT"):
        monkeypatch.delenv(name, raising=False)
    for name, value in environ.items():
        monkeypatch.setenv(name, value)
    code = cli_main(["train-policy", "--device", device, "--run-dir", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and message in err[0], err
    assert not (tmp_path / "run").exists()


def test_a_missing_gpu_is_named_with_the_rank_that_wanted_it(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    environ = {"WORLD_SIZE": "2", "RANK": "1", "LOCAL_RANK": "1", "MASTER_ADDR": "localhost", "MASTER_PORT": "1"}
    with pytest.raises(ValueError, match=r"LOCAL_RANK=1 .*needs cuda:1, but this machine has 1 CUDA device"):
        distributed.from_environment("cuda", environ)
    setup = distributed.from_environment("cuda", {**environ, "RANK": "0", "LOCAL_RANK": "0"})
    assert (setup.device, setup.backend, setup.rsl_rl_cfg()) == ("cuda:0", "nccl", {
        "global_rank": 0, "local_rank": 0, "world_size": 2})
    assert distributed.from_environment("cpu", environ).backend == "gloo"


if __name__ == "__main__":
    _worker(Path(sys.argv[1]))
