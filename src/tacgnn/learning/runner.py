"""The PPO training loop, with the perception learning beside it and checkpoints that resume exactly.

One iteration, as `Runner.learn` runs it:

    rollout, num_steps_per_env times:
        act       a ~ pi(. | o) for every env, with V(o) and log pi(a | o) kept   (alg.act)
        step      the envs advance one control step                                (env.step)
        process   the transition goes into the rollout storage; on a time-out
                  r += gamma V(o): truncation, not termination                     (alg.process_env_step)
    returns   GAE: delta_t = r_t + gamma V(o_{t+1}) - V(o_t),
              A_t = delta_t + gamma lam A_{t+1}, R_t = A_t + V(o_t)                (alg.compute_returns)
    update    PPO epochs over mini-batches; a NaN or Inf is refused and rolled back (alg.update)
    log       losses, episode statistics, timings (TensorBoard and the console)
    perceive  in 'perceived' mode, every `perception_every` iterations: the perception
              trains on the frames it recorded during the rollouts
    save      a checkpoint after the first iteration, every save_interval and the last

Over several processes (`tacgnn.learning.distributed`, launched by torchrun) every rank runs
this loop on its own envs; PPO's update averages the gradients of all ranks, so the networks
stay the same everywhere, and rank 0 writes the checkpoints, which hold every rank's env
state and random streams so that the run resumes exactly.

Iterations are counted from 1 as completed updates: ``model_000004.pt`` holds the state
after 4 updates, and the perception updates after every iteration that is a multiple of
`perception_every`, whatever iteration the run started or resumed at, so that a resumed
run repeats an uninterrupted one bit for bit.
"""

from __future__ import annotations

import contextlib
import datetime
import io
import math
import signal
import statistics
import time
from pathlib import Path
from typing import Any, TextIO

import torch
from rsl_rl.env import VecEnv
from rsl_rl.runners import OnPolicyRunner
from rsl_rl.utils.logger import Logger

from tacgnn.config import to_dict
from tacgnn.envs.baoding import BaodingConfig
from tacgnn.learning import checkpoint as ckpt
from tacgnn.learning import distributed
from tacgnn.learning.config import PPOConfig
from tacgnn.learning.guarded_ppo import GuardedPPO, NonFiniteUpdate
from tacgnn.learning.online_perception import OnlinePerception
from tacgnn.learning.rsl_env import RslBaodingEnv

LOG_FILE = "train.log"
"""The run folder's full log: rsl_rl's per-iteration report, the networks, perception updates."""


class _RunLogger(Logger):
    """rsl_rl's logger (TensorBoard, episode statistics) with its ~33-line console report per
    iteration moved to the run's log file, and one line on the console instead; no copy of the
    enclosing repository's git state in the run folder."""

    def __init__(self, *args, log_file: TextIO | None, **kwargs):
        super().__init__(*args, **kwargs)
        self.log_file = log_file
        self.git_status_repos: list[str] = []

    def _store_code_state(self) -> list[str]:
        return []

    def log(self, *args, **kwargs) -> None:
        it, start_it, total_it = kwargs["it"], kwargs["start_it"], kwargs["total_it"]
        success = [float(torch.as_tensor(ep["Episode/success_rate"]).float().mean())
                   for ep in self.ep_extras if "Episode/success_rate" in ep]
        report = io.StringIO()
        with contextlib.redirect_stdout(report):
            super().log(*args, **kwargs)
        if self.disable_logs:
            return
        if self.log_file is not None:
            self.log_file.write(report.getvalue())
            self.log_file.flush()
        done = it + 1 - start_it
        seconds = kwargs["collect_time"] + kwargs["learn_time"]
        steps = self.cfg["num_steps_per_env"] * self.num_envs * self.gpu_world_size
        eta = datetime.timedelta(seconds=int(self.tot_time / max(done, 1) * (total_it - it - 1)))
        parts = [f"iteration {it + 1}/{total_it}"]
        if self.rewbuffer:
            parts.append(f"reward {statistics.mean(self.rewbuffer):.2f}")
        if success:
            parts.append(f"success {100 * statistics.mean(success):.0f} %")
        if self.lenbuffer:
            parts.append(f"episode {statistics.mean(self.lenbuffer):.0f} steps")
        parts += [f"{steps / max(seconds, 1e-9):,.0f} steps/s", f"ETA {eta}"]
        print("  ".join(parts), flush=True)


class Runner:
    """PPO (`GuardedPPO`) on a `RslBaodingEnv`, logging with rsl_rl's logger, writing our checkpoints.

    Attributes:
        alg: the PPO algorithm (actor, critic, optimiser, rollout storage).
        iteration: updates completed so far.
        last_checkpoint: the newest checkpoint written or resumed from (None before one).
        perception_every: iterations between perception updates (perceived mode).
        dist: this process's place in a multi-process run (one process by default).
    """

    def __init__(self, env: RslBaodingEnv, env_cfg: BaodingConfig, ppo_cfg: PPOConfig, run_dir: Path | None,
                 perception: OnlinePerception | None = None, dist: distributed.Distributed | None = None):
        self.env, self.env_cfg, self.ppo_cfg = env, env_cfg, ppo_cfg
        self.run_dir, self.perception = run_dir, perception
        self.dist = dist or distributed.Distributed()
        if self.dist.enabled and perception is not None:
            raise ValueError("the perception in the loop trains on one process's frames; run it in one process")
        self.device = self.dist.device
        cfg = {**ppo_cfg.rsl_rl_cfg(), "multi_gpu": self.dist.rsl_rl_cfg()}
        self.log_file = (open(run_dir / LOG_FILE, "a", encoding="utf-8")  # noqa: SIM115 - closed by close()
                         if run_dir is not None and self.dist.is_main else None)
        networks = io.StringIO()
        with contextlib.redirect_stdout(networks):  # rsl_rl prints both networks: the log file keeps them
            self.alg: GuardedPPO = GuardedPPO.construct_algorithm(env.get_observations().to(self.device), env, cfg,
                                                                  self.device)
        self._log(networks.getvalue())
        self.logger = _RunLogger(log_dir=None if run_dir is None else str(run_dir), cfg=cfg, env_cfg=env.cfg,
                                 num_envs=env.num_envs, is_distributed=self.dist.enabled,
                                 gpu_world_size=self.dist.world_size, gpu_global_rank=self.dist.rank,
                                 device=self.device, log_file=self.log_file)
        self.iteration = 0
        self.stopped_by: str | None = None
        """The signal (SIGINT, SIGTERM) that ended `learn` early, after saving a checkpoint."""
        self.last_checkpoint: Path | None = None
        steps = perception.cfg.update_every_steps if perception is not None else 1
        self.perception_every = max(1, math.ceil(steps / ppo_cfg.num_steps_per_env))

    def _log(self, text: str) -> None:
        if self.log_file is not None and text:
            self.log_file.write(text if text.endswith("\n") else text + "\n")
            self.log_file.flush()

    # --- the loop ------------------------------------------------------------------------
    def learn(self, until: int) -> None:
        """Run iterations until `until` updates are complete.

        SIGINT (Ctrl-C) or SIGTERM ends the run after the iteration under way, with a checkpoint
        of it (`stopped_by` names the signal); a second one stops at once. Under torchrun the
        signals keep their default, as the ranks must save together.
        """
        if self.iteration >= until:
            return
        if self.dist.enabled:
            self._learn(until)
            return
        previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

        def stop(signum, frame):
            self.stopped_by = signal.Signals(signum).name
            for sig, handler in previous.items():  # the next one acts at once
                signal.signal(sig, handler)
            print(f"{self.stopped_by}: saving a checkpoint after iteration {self.iteration + 1}, then stopping "
                  "(again to stop at once, without it)", flush=True)

        for sig in previous:
            signal.signal(sig, stop)
        try:
            self._learn(until)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def _learn(self, until: int) -> None:
        if self.logger.writer is None:
            self.logger.init_logging_writer()
        if self.perception is not None and self.iteration == 0 and self.perception.updates == 0:
            self.warm_up_perception()
        if self.dist.enabled:  # rank 0's networks everywhere (each rank drew its own at construction)
            self.alg.broadcast_parameters()
        obs = self.env.get_observations().to(self.device)
        self.alg.train_mode()
        start = self.iteration
        while self.iteration < until:
            begin = time.time()
            with torch.inference_mode():
                for _ in range(self.ppo_cfg.num_steps_per_env):
                    actions = self.alg.act(obs)
                    obs, rewards, dones, extras = self.env.step(actions)
                    obs, rewards, dones = obs.to(self.device), rewards.to(self.device), dones.to(self.device)
                    self.alg.process_env_step(obs, rewards, dones, extras)
                    self.logger.process_env_step(rewards, dones, extras)
                self.alg.compute_returns(obs)
            collected = time.time()
            losses = self._update()
            self.iteration += 1
            self.logger.log(it=self.iteration - 1, start_it=start, total_it=until, collect_time=collected - begin,
                            learn_time=time.time() - collected, loss_dict=losses,
                            learning_rate=self.alg.learning_rate, action_std=self.alg.get_policy().output_std,
                            rnd_weight=None)
            if self.perception is not None and self.iteration % self.perception_every == 0:
                self.update_perception()
            if (self.iteration == 1 or self.iteration % self.ppo_cfg.save_interval == 0 or self.iteration == until
                    or self.stopped_by):
                self.save_checkpoint()
            if self.stopped_by:
                return

    def _update(self) -> dict[str, float]:
        try:
            return self.alg.update()
        except NonFiniteUpdate as err:
            raise FloatingPointError(f"PPO update {self.iteration + 1}: {err}. "
                                     f"Last checkpoint: {self.last_checkpoint or 'none yet'}") from err

    def close(self) -> None:
        if self.logger.writer is not None:
            self.logger.writer.close()  # rsl_rl leaves its TensorBoard writer open
        if self.log_file is not None:
            self.log_file.close()
            self.log_file = None

    # --- the perception in the loop ------------------------------------------------------
    def update_perception(self) -> None:
        """Train the perception on its recorded frames; log how its error changed."""
        assert self.perception is not None
        start = time.perf_counter()
        metrics = self.perception.update()
        metrics["perception/update_seconds"] = time.perf_counter() - start
        torch.set_num_threads(self.ppo_cfg.torch_threads)  # the update set the perception's
        if self.logger.writer is not None:
            for key, value in metrics.items():
                self.logger.writer.add_scalar(key, value, self.iteration)
        print(f"[perception] iteration {self.iteration}: {_metrics_line(metrics)}", flush=True)
        self._log(f"[perception] iteration {self.iteration}: {_metrics_line(metrics)}")

    def warm_up_perception(self) -> None:
        """Train the perception on the starting policy's own states before PPO moves the policy.

        A blind run starts from a ground-truth teacher and a perception trained on the teacher's
        rollouts. Acting on perceived balls, the teacher reaches states that dataset lacks, the
        perception errs there, episodes fail, and PPO can settle on holding the balls still
        (Table III, TacGNN seed 1 without warm-up: 0 % success from iteration 50 on). So, DAgger
        style: the policy acts (sampled actions, as in PPO's rollouts; normalisers frozen), its
        frames and the true balls train the perception; repeat `warmup_rounds` times.
        """
        assert self.perception is not None
        cfg = self.perception.cfg
        actor = self.alg.get_policy()
        self.alg.eval_mode()  # the observation normaliser must not learn from these steps
        obs = self.env.get_observations().to(self.device)
        for round_ in range(1, cfg.warmup_rounds + 1):
            with torch.inference_mode():
                for _ in range(cfg.update_every_steps):
                    obs, *_ = self.env.step(actor(obs, stochastic_output=True))
                    obs = obs.to(self.device)
            metrics = self.perception.update()
            torch.set_num_threads(self.ppo_cfg.torch_threads)
            print(f"[perception warm-up] round {round_}/{cfg.warmup_rounds}: {_metrics_line(metrics)}", flush=True)
        self.alg.train_mode()

    # --- checkpoints ---------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """The checkpoint of the current state (format: `tacgnn.learning.checkpoint`)."""
        state = {
            "format_version": ckpt.FORMAT_VERSION,
            "iteration": self.iteration,
            "env_config": to_dict(self.env_cfg),
            "ppo_config": to_dict(self.ppo_cfg),
            "obs_dim": self.env.num_obs,
            "num_actions": self.env.num_actions,
            **self.alg.save(),  # actor, critic and optimizer state dicts (normalisers are actor/critic buffers)
            **self._rank_state(),
            "world_size": self.dist.world_size,
        }
        if self.perception is not None:
            state["perception"] = self.perception.state_dict()
        return state

    def _rank_state(self) -> dict[str, Any]:
        """What differs between ranks: the envs and the random streams."""
        # rsl_rl draws actions and mini-batch permutations from torch's global RNG only.
        rng = {"torch": torch.get_rng_state()}
        if self.device.startswith("cuda"):
            rng["cuda"] = torch.cuda.get_rng_state(torch.device(self.device))
        return {"rng": rng, "env_state": self.env.state_dict()}

    def save_checkpoint(self, run_dir: Path | None = None) -> Path | None:
        """Write model_<iteration>.pt (and the perception's frames) into run_dir (default: the run's).

        Every rank must call it (the ranks' states are gathered); rank 0 alone writes, and only
        rank 0 returns the path.
        """
        run_dir = run_dir or self.run_dir
        if run_dir is None:
            return None
        others = distributed.gather_to_main(self._rank_state(), self.dist)
        if not self.dist.is_main:
            distributed.barrier(self.dist)
            return None
        if self.perception is not None:  # frames first: a checkpoint on disk always has its frames
            ckpt.save_frames(run_dir, self.iteration, self.perception.frames_state_dict())
        target = ckpt.checkpoint_path(run_dir, self.iteration)
        state = self.state_dict()
        if self.dist.enabled:
            assert others is not None
            state["rank_states"] = others[1:]  # rank r > 0 resumes from rank_states[r - 1]
        ckpt.save(target, state)
        distributed.barrier(self.dist)  # the file is on disk when save_checkpoint returns on any rank
        if self.perception is not None:
            ckpt.remove_frames_except(run_dir, self.iteration)
        self.last_checkpoint = target
        return target

    def restore(self, checkpoint: dict[str, Any], frames: dict[str, Any] | None = None) -> None:
        """Continue from `checkpoint` (read by `load_checkpoint`): models, optimiser, RNG, env, perception.

        A checkpoint of a multi-process run resumes with as many processes, each rank from its own state.
        """
        written_by = int(checkpoint.get("world_size", 1))
        if written_by != self.dist.world_size:
            raise ckpt.CheckpointError(f"checkpoint of iteration {checkpoint['iteration']} was written by "
                                       f"{written_by} process(es); resume it with as many, not "
                                       f"{self.dist.world_size}")
        self.alg.load(checkpoint, load_cfg=None, strict=True)  # also restores the adaptive learning rate
        self.iteration = checkpoint["iteration"]
        own = checkpoint if self.dist.is_main else checkpoint["rank_states"][self.dist.rank - 1]
        self.env.load_state_dict(own["env_state"])
        torch.set_rng_state(own["rng"]["torch"])
        if "cuda" in own["rng"] and self.device.startswith("cuda"):
            torch.cuda.set_rng_state(own["rng"]["cuda"], torch.device(self.device))
        if self.perception is not None:
            if "perception" not in checkpoint:
                raise ckpt.CheckpointError("checkpoint has no perception state, but this run trains one")
            self.perception.load_state_dict(checkpoint["perception"])
            if frames is not None:
                self.perception.load_frames_state_dict(frames)


class DataParallelRunner(OnPolicyRunner):
    """rsl_rl's runner, multi-process on GPUs (nccl) and on the CPU (gloo), for any VecEnv.

    rsl_rl's `_configure_multi_gpu` insists on ``cuda:LOCAL_RANK`` and nccl; this one takes the
    backend from the device (`tacgnn.learning.distributed`). The rest (parameter broadcast at
    the start, all-reduced gradients, logs and saves on rank 0 only) is rsl_rl's. Seeding the
    ranks' envs apart is the caller's job (`distributed.rank_seed`).
    """

    def _configure_multi_gpu(self) -> None:
        setup = distributed.from_environment("cpu" if self.device == "cpu" else "cuda")
        if setup.enabled and setup.device != self.device:
            raise ValueError(f"device {self.device!r} on the rank with LOCAL_RANK={setup.local_rank}: "
                             f"expected {setup.device!r}")
        self.setup = setup
        self.gpu_world_size, self.is_distributed = setup.world_size, setup.enabled
        self.gpu_global_rank, self.gpu_local_rank = setup.rank, setup.local_rank
        self.cfg["multi_gpu"] = setup.rsl_rl_cfg()
        distributed.init(setup)


def make_runner(env: VecEnv, ppo_cfg: PPOConfig, log_dir: Path | None = None,
                device: str = "cpu") -> OnPolicyRunner:
    """A plain rsl_rl runner for any VecEnv from `ppo_cfg` (tests, benchmarks, other tasks); no checkpoints.

    Under torchrun it is a data-parallel one (`DataParallelRunner`).
    """
    runner = DataParallelRunner(env, ppo_cfg.rsl_rl_cfg(), log_dir=None if log_dir is None else str(log_dir),
                                device=device)
    runner.logger.git_status_repos = []
    return runner


def _metrics_line(metrics: dict[str, float]) -> str:
    """'rmse_cm_before 0.8, rmse_cm_after 0.7, ...' from {'perception/rmse_cm_before': 0.8, ...}."""
    return ", ".join(f"{k.split('/')[1]} {v:.4g}" for k, v in metrics.items())
