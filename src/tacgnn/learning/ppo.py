"""PPO on the Baoding env with rsl_rl: config, training with exact resume, policy loading.

`PPOConfig` holds the paper's / authors' settings (their rl_games config) as defaults and
turns into the dict rsl_rl 5.5.1's `OnPolicyRunner` reads. `train` runs rsl_rl's loop with
our checkpoints, which differ from rsl_rl's own in three ways:

* written atomically (temp file in the same directory, then ``os.replace``), so a crash or
  a full disk never leaves a half-written ``model_*.pt`` behind;
* self-describing: env and PPO configs as plain dicts, a format version, the obs size;
* complete: besides model, optimiser (with the adaptive learning rate) and observation
  normaliser, the torch RNG and the env's whole state, so that resuming continues the run
  bit for bit as if it had never stopped.

They hold only tensors and plain Python data and are read with ``torch.load(weights_only=True)``.

    python -m tacgnn.learning.ppo --run-dir runs/gt --env task=simple --ppo max_iterations=5000
    python -m tacgnn.learning.ppo --run-dir runs/gt --resume
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import random
import re
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Literal

import numpy as np
import torch
import yaml
from rsl_rl.models import MLPModel
from rsl_rl.runners import OnPolicyRunner
from tensordict import TensorDict

from tacgnn.config import ConfigError, check, from_dict, override, parse_overrides, to_dict
from tacgnn.envs.baoding import BaodingConfig
from tacgnn.learning.online_perception import OnlinePerception, OnlinePerceptionConfig
from tacgnn.learning.rsl_env import RslBaodingEnv

FORMAT_VERSION = 1
CHECKPOINT_KEYS = ("format_version", "iteration", "env_config", "ppo_config", "obs_dim", "num_actions",
                   "actor_state_dict", "critic_state_dict", "optimizer_state_dict", "rng", "env_state")
# PPO settings that fix the network's shape: a checkpoint cannot be resumed under others.
ARCHITECTURE_KEYS = ("actor_hidden_dims", "critic_hidden_dims", "activation", "obs_normalization")

Activation = Literal["elu", "selu", "relu", "crelu", "lrelu", "tanh", "sigmoid", "softplus", "gelu", "swish", "mish"]


class CheckpointError(ValueError):
    """A checkpoint is unreadable, not ours, or does not match the requested config; names the file."""


@dataclass(frozen=True)
class PPOConfig:
    """PPO hyperparameters; defaults are the TacGNN authors' (rl_games) settings where known."""

    num_envs: int = 256
    """Parallel envs; replaces the env config's num_envs. Batch = num_envs x num_steps_per_env."""
    num_steps_per_env: int = 8
    """Rollout horizon per env and iteration (rl_games' horizon_length)."""
    max_iterations: int = 20000
    """Total iterations of the run; a resumed run continues until the counter reaches it."""
    learning_rate: float = 5e-3
    """Adam step size; under the adaptive schedule only its start."""
    schedule: Literal["adaptive", "fixed"] = "adaptive"
    """'adaptive': lr / 1.5 when the mini-batch KL > 2 desired_kl, x 1.5 when < desired_kl / 2."""
    desired_kl: float = 0.02
    """Target KL(old || new) per mini-batch of the adaptive schedule."""
    gamma: float = 0.99
    """Discount; with 50 Hz control the horizon 1 / (1 - gamma) is 100 steps = 2 s."""
    lam: float = 0.95
    """GAE lambda: A_t = sum_k (gamma lam)^k delta_{t+k}, delta_t = r_t + gamma V(s_{t+1}) - V(s_t)."""
    clip_param: float = 0.2
    """PPO ratio clip epsilon (also clips the value update, see use_clipped_value_loss)."""
    num_learning_epochs: int = 5
    """Passes over each rollout (rl_games' mini_epochs)."""
    num_mini_batches: int = 4
    """Mini-batches per epoch: 256 x 8 = 2048 samples -> 512 per gradient step."""
    value_loss_coef: float = 1.0
    """Weight of the value loss in the joint actor-critic loss."""
    use_clipped_value_loss: bool = True
    """Clip the value update to +- clip_param around the rollout's values."""
    entropy_coef: float = 0.0
    """Entropy bonus; the authors use none."""
    max_grad_norm: float = 1.0
    """Gradient norm clip, applied to actor and critic separately."""
    actor_hidden_dims: tuple[int, ...] = (512, 256, 128)
    """Hidden layer widths of the policy MLP."""
    critic_hidden_dims: tuple[int, ...] = (512, 256, 128)
    """Hidden layer widths of the value MLP."""
    activation: Activation = "elu"
    """Hidden activation: ELU as in the authors' code (the paper says ReLU)."""
    init_noise_std: float = 1.0
    """Initial std of the Gaussian policy, in action units ([-1, 1] spans a joint's range)."""
    obs_normalization: bool = True
    """Normalise observations by running mean and std (actor and critic each keep one)."""
    reward_scale: float = 0.01
    """Factor on the env's rewards before PPO sees them (success 250 -> 2.5)."""
    bootstrap_time_outs: bool = True
    """Treat time-outs as truncation (bootstrap with V) rather than as terminal states."""
    save_interval: int = 250
    """Write a checkpoint every this many iterations (and after the first and the last); ~5 MB each."""
    seed: int = 0
    """Seed of torch, numpy and Python's global RNGs; the env's own stream is the env config's seed."""
    init_from: str = ""
    """A checkpoint whose actor and critic (with their normalisers) start this run, e.g. a
    ground-truth policy to fine-tune with perceived ball positions; '' = random init.
    Fine-tuning wants a small step: with a fresh Adam, one iteration at a fixed 3e-4 takes
    the ground-truth Hard policy from 98.6 % to 58.2 % on Simple, at 1e-4 it keeps 98.6 %
    (experiments/finetune_lr.sh)."""
    privileged_critic: bool = False
    """The critic reads the ground-truth observation (true ball positions) while the actor reads
    the env's own (perceived, noisy or none); only training uses the critic, so the policy stays
    blind. Off by default, as in the paper; it keeps the value estimates sound when a
    ground-truth policy is fine-tuned on perceived positions."""
    torch_threads: int = 1
    """CPU threads for torch; 1 leaves the other core to the physics."""
    log_dir: str = "runs"
    """Parent directory of runs, used when train() is given no run_dir."""
    experiment_name: str = "baoding"
    """Name of the run: its directory under log_dir, and the run name rsl_rl prints."""

    def __post_init__(self) -> None:
        for key in ("num_envs", "num_steps_per_env", "num_learning_epochs", "num_mini_batches",
                    "save_interval", "torch_threads"):
            check(getattr(self, key) >= 1, key, f"must be >= 1, got {getattr(self, key)}")
        check(self.max_iterations >= 0, "max_iterations", "must be >= 0")
        check(self.num_envs * self.num_steps_per_env >= self.num_mini_batches, "num_mini_batches",
              "more mini-batches than samples per iteration")
        check(self.learning_rate > 0, "learning_rate", "must be positive")
        check(self.desired_kl > 0, "desired_kl", "must be positive")
        check(0 < self.gamma <= 1 and 0 <= self.lam <= 1, "gamma", "needs 0 < gamma <= 1 and 0 <= lam <= 1")
        check(self.clip_param > 0, "clip_param", "must be positive")
        check(self.init_noise_std > 0, "init_noise_std", "must be positive")
        check(self.max_grad_norm > 0, "max_grad_norm", "must be positive")
        check(self.reward_scale > 0, "reward_scale", "must be positive")
        check(self.value_loss_coef >= 0 and self.entropy_coef >= 0, "entropy_coef", "loss weights must be >= 0")
        for key in ("actor_hidden_dims", "critic_hidden_dims"):
            dims = getattr(self, key)
            check(len(dims) >= 1 and all(d >= 1 for d in dims), key, f"needs positive widths, got {list(dims)}")

    def rsl_rl_cfg(self) -> dict[str, Any]:
        """The train_cfg dict of rsl_rl 5.5.1's OnPolicyRunner."""

        def model(dims: tuple[int, ...], stochastic: bool) -> dict[str, Any]:
            cfg = {"class_name": "rsl_rl.models:MLPModel", "hidden_dims": list(dims),
                   "activation": self.activation, "obs_normalization": self.obs_normalization}
            if stochastic:
                cfg["distribution_cfg"] = {"class_name": "rsl_rl.modules:GaussianDistribution",
                                           "init_std": self.init_noise_std, "std_type": "scalar"}
            return cfg

        return {
            "run_name": self.experiment_name,
            "num_steps_per_env": self.num_steps_per_env,
            "save_interval": self.save_interval,
            "obs_groups": {"actor": ["policy"], "critic": ["critic" if self.privileged_critic else "policy"]},
            "logger": "tensorboard",
            "check_for_nan": True,
            "algorithm": {
                "class_name": "rsl_rl.algorithms:PPO",
                "num_learning_epochs": self.num_learning_epochs,
                "num_mini_batches": self.num_mini_batches,
                "clip_param": self.clip_param,
                "gamma": self.gamma,
                "lam": self.lam,
                "value_loss_coef": self.value_loss_coef,
                "entropy_coef": self.entropy_coef,
                "learning_rate": self.learning_rate,
                "max_grad_norm": self.max_grad_norm,
                "use_clipped_value_loss": self.use_clipped_value_loss,
                "schedule": self.schedule,
                "desired_kl": self.desired_kl,
            },
            "actor": model(self.actor_hidden_dims, stochastic=True),
            "critic": model(self.critic_hidden_dims, stochastic=False),
        }


# --- the runner ------------------------------------------------------------------------
class _Runner(OnPolicyRunner):
    """rsl_rl's runner, saving our checkpoints instead of its own.

    rsl_rl numbers iterations from 0 and saves after iteration ``it`` with
    ``current_learning_iteration == it``; we count completed iterations instead, so
    ``model_000004.pt`` holds the state after 4 updates, and resuming from it sets
    ``current_learning_iteration = 4``, the index of the next one. rsl_rl is told to call
    `save` after every iteration; it writes when the count is a multiple of save_interval,
    after the first iteration, and after the last.
    """

    def __init__(self, env: RslBaodingEnv, env_cfg: BaodingConfig, ppo_cfg: PPOConfig, log_dir: Path | None,
                 perception: OnlinePerception | None = None):
        train_cfg = {**ppo_cfg.rsl_rl_cfg(), "save_interval": 1}
        self.perception = perception
        self.run_end: int | None = None  # the run's last iteration when learn() is called in chunks
        super().__init__(env, train_cfg, log_dir=None if log_dir is None else str(log_dir), device="cpu")
        self.env_cfg, self.ppo_cfg = env_cfg, ppo_cfg
        self.logger.git_status_repos = []  # else rsl_rl runs `git status`/`git diff` on the enclosing repo
        self.last_checkpoint: Path | None = None
        self._saved_iteration = -1
        self._final_iteration = -1
        self._next_update = 1
        self._unguarded_update = self.alg.update
        self.alg.update = self._guarded_update

    def _guarded_update(self) -> dict[str, float]:
        """rsl_rl's PPO update, undone and reported if it leaves a loss or a weight NaN or Inf.

        rsl_rl clips the gradient norm, but an infinite norm scales every gradient by 0 * inf
        = NaN, and the optimiser then writes NaN into all weights, which the next rollout
        would act on and the next checkpoint would keep. Here the update is rolled back
        (models, optimiser, learning rate) and the run stops naming what went wrong; the
        last checkpoint on disk is the one to resume from.
        """
        before = copy.deepcopy(self.alg.save())
        losses, failure = {}, None
        try:
            losses = self._unguarded_update()
        except RuntimeError as err:  # e.g. torch refusing a NaN action std in a later mini-batch
            failure = err
        bad = [f"loss {k}" for k, v in losses.items() if not math.isfinite(float(v))]
        for name, model in (("actor", self.alg.actor), ("critic", self.alg.critic)):
            bad += [f"{name} {p}" for p, t in model.named_parameters() if not torch.isfinite(t).all()]
        if bad or failure:
            self.alg.load(before, load_cfg=None, strict=True)
            what = f"gave non-finite values ({', '.join(bad[:6])}{', ...' if len(bad) > 6 else ''})" if bad \
                else f"failed ({failure})"
            raise FloatingPointError(
                f"PPO update {self._next_update} {what}; weights rolled back to before it. "
                f"Last checkpoint: {self.last_checkpoint or 'none yet'}") from failure
        self._next_update += 1
        return losses

    def learn(self, num_learning_iterations: int, init_at_random_ep_len: bool = False) -> None:
        self._final_iteration = self.current_learning_iteration + num_learning_iterations
        self._next_update = self.current_learning_iteration + 1  # counted from 1, as checkpoints are
        super().learn(num_learning_iterations, init_at_random_ep_len)
        # rsl_rl leaves the index of the last iteration; count completed ones, so that the
        # next learn() (perception in the loop calls it in chunks) starts at the next index
        self.current_learning_iteration = self._final_iteration

    def save(self, path: str, infos: dict | None = None) -> None:
        iteration = self.current_learning_iteration + 1
        end = self.run_end if self.run_end is not None else self._final_iteration
        due = iteration == 1 or iteration % self.ppo_cfg.save_interval == 0 or iteration == end
        if not due or iteration == self._saved_iteration:  # rsl_rl saves the last iteration twice
            return
        self.write_checkpoint(Path(path).parent, iteration)

    def write_checkpoint(self, run_dir: Path, iteration: int) -> None:
        """Write model_<iteration>.pt: everything needed to continue exactly from here."""
        target = Path(run_dir) / f"model_{iteration:06d}.pt"
        checkpoint = {
            "format_version": FORMAT_VERSION,
            "iteration": iteration,
            "env_config": to_dict(self.env_cfg),
            "ppo_config": to_dict(self.ppo_cfg),
            "obs_dim": self.env.num_obs,
            "num_actions": self.env.num_actions,
            **self.alg.save(),  # actor, critic and optimizer state dicts (normalisers are actor/critic buffers)
            # rsl_rl draws actions and mini-batch permutations from torch's global RNG only.
            "rng": {"torch": torch.get_rng_state()},
            "env_state": self.env.state_dict(),
        }
        if self.perception is not None:
            checkpoint["perception"] = self.perception.state_dict()
        _atomic_write(target, lambda fh: torch.save(checkpoint, fh))
        self.last_checkpoint, self._saved_iteration = target, iteration

    def restore(self, checkpoint: dict[str, Any]) -> None:
        """Continue from `checkpoint` (read by `load_checkpoint`): models, optimiser, RNG, env."""
        self.alg.load(checkpoint, load_cfg=None, strict=True)  # also restores the adaptive learning rate
        self.current_learning_iteration = checkpoint["iteration"]
        self.env.load_state_dict(checkpoint["env_state"])
        torch.set_rng_state(checkpoint["rng"]["torch"])
        if self.perception is not None:
            if "perception" not in checkpoint:
                raise CheckpointError("checkpoint has no perception state, but this run trains one")
            self.perception.load_state_dict(checkpoint["perception"])


def make_runner(env, ppo_cfg: PPOConfig, log_dir: Path | None = None) -> OnPolicyRunner:
    """A plain rsl_rl runner for any VecEnv from `ppo_cfg` (tests, other tasks); no checkpoints of ours."""
    runner = OnPolicyRunner(env, ppo_cfg.rsl_rl_cfg(), log_dir=None if log_dir is None else str(log_dir),
                            device="cpu")
    runner.logger.git_status_repos = []
    return runner


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


# --- training --------------------------------------------------------------------------
def train(env_cfg: BaodingConfig, ppo_cfg: PPOConfig, run_dir: Path | None = None,
          resume: bool = False, perception_cfg: OnlinePerceptionConfig | None = None) -> Path | None:
    """Train until ``ppo_cfg.max_iterations`` iterations are done; return the last checkpoint.

    run_dir (default ``log_dir/experiment_name``) receives config.yaml, TensorBoard events
    and ``model_<iterations>.pt`` checkpoints. A fresh run refuses a run_dir that already
    holds checkpoints; ``resume=True`` continues from the newest one, whose env config must
    equal `env_cfg` (else CheckpointError, a ValueError, naming the differing keys).
    """
    run_dir = Path(run_dir) if run_dir is not None else Path(ppo_cfg.log_dir) / ppo_cfg.experiment_name
    env_cfg = replace(env_cfg, num_envs=ppo_cfg.num_envs)
    torch.set_num_threads(ppo_cfg.torch_threads)
    checkpoint = None
    existing = list_checkpoints(run_dir)
    if resume:
        if not existing:
            raise FileNotFoundError(f"nothing to resume: no model_*.pt checkpoint in {run_dir}")
        path = existing[-1]
        checkpoint = load_checkpoint(path)
        check_compatible(checkpoint, env_cfg, ppo_cfg, path)
    elif existing:
        raise FileExistsError(f"{run_dir} already holds checkpoints ({existing[-1].name}); "
                              "resume=True to continue that run, or choose another run_dir")

    if (env_cfg.obs_mode == "perceived") != (perception_cfg is not None):
        raise ConfigError("obs_mode 'perceived' and a perception config go together "
                          f"(obs_mode={env_cfg.obs_mode!r}, perception config {'given' if perception_cfg else 'missing'})")
    seed_everything(ppo_cfg.seed)
    perception = None if perception_cfg is None else OnlinePerception(perception_cfg, to_dict(env_cfg.skin), ppo_cfg.seed)
    env = RslBaodingEnv(env_cfg, ppo_cfg.reward_scale, ppo_cfg.bootstrap_time_outs, perception=perception,
                        privileged_critic=ppo_cfg.privileged_critic)
    if perception is not None:
        env.on_step = perception.record
    if checkpoint is not None and checkpoint["obs_dim"] != env.num_obs:
        raise CheckpointError(f"checkpoint {existing[-1]}: obs_dim {checkpoint['obs_dim']} != this env's {env.num_obs}")
    run_dir.mkdir(parents=True, exist_ok=True)
    stored = {"env": to_dict(env_cfg), "ppo": to_dict(ppo_cfg)}
    if perception_cfg is not None:
        stored["perception"] = to_dict(perception_cfg)
    text = yaml.safe_dump(stored, sort_keys=False)
    _atomic_write(run_dir / "config.yaml", lambda fh: fh.write(text.encode()))

    runner = _Runner(env, env_cfg, ppo_cfg, run_dir, perception)
    if checkpoint is None and ppo_cfg.init_from:
        start = load_checkpoint(ppo_cfg.init_from)
        if start["obs_dim"] != env.num_obs:
            raise CheckpointError(f"init_from {ppo_cfg.init_from}: obs_dim {start['obs_dim']} != {env.num_obs}")
        runner.alg.load(start, load_cfg={"actor": True, "critic": True}, strict=True)
        _set_action_std(runner, ppo_cfg.init_noise_std)  # explore afresh around the loaded policy
        print(f"actor and critic initialised from {ppo_cfg.init_from}")
    if checkpoint is not None:
        runner.restore(checkpoint)
        runner.last_checkpoint = existing[-1]
        print(f"resuming {existing[-1]} at iteration {checkpoint['iteration']}")
    remaining = ppo_cfg.max_iterations - runner.current_learning_iteration
    if remaining > 0:
        try:
            if perception is None:
                runner.learn(remaining)
            else:
                _learn_with_perception(runner, perception, ppo_cfg)
        finally:
            if runner.logger.writer is not None:
                runner.logger.writer.close()  # rsl_rl leaves a TensorBoard writer open
    return runner.last_checkpoint


def _set_action_std(runner: _Runner, std: float) -> None:
    """Reset the policy's (learned, state-independent) action std to `std`."""
    with torch.no_grad():
        for name, param in runner.alg.actor.named_parameters():
            if name.endswith("std_param"):
                param.fill_(std)
            elif name.endswith("log_std_param"):
                param.fill_(math.log(std))


def _metrics_line(metrics: dict[str, float]) -> str:
    """'rmse_cm_before 0.8, rmse_cm_after 0.7, ...' from {'perception/rmse_cm_before': 0.8, ...}."""
    return ", ".join(f"{k.split('/')[1]} {v:.4g}" for k, v in metrics.items())


def _warm_up_perception(runner: _Runner, perception: OnlinePerception) -> None:
    """Train the perception on the starting policy's own states before PPO moves the policy.

    A blind run starts from a ground-truth teacher and a perception trained on the teacher's
    rollouts. Acting on perceived balls, the teacher reaches states that dataset lacks, the
    perception errs there, episodes fail, and PPO can settle on holding the balls still
    (Table III, TacGNN seed 1 without warm-up: 0 % success from iteration 50 on). So, DAgger
    style: the policy acts (sampled actions, as in PPO's rollouts; normalisers frozen), its
    frames and the true balls train the perception; repeat.
    """
    cfg = perception.cfg
    actor = runner.alg.get_policy()
    runner.alg.eval_mode()  # the observation normaliser must not learn from these steps
    obs = runner.env.get_observations()
    for round_ in range(1, cfg.warmup_rounds + 1):
        with torch.inference_mode():
            for _ in range(cfg.update_every_steps):
                obs, *_ = runner.env.step(actor(obs, stochastic_output=True))
        metrics = perception.update()
        print(f"[perception warm-up] round {round_}/{cfg.warmup_rounds}: {_metrics_line(metrics)}", flush=True)
    runner.alg.train_mode()


def _learn_with_perception(runner: _Runner, perception: OnlinePerception, ppo_cfg: PPOConfig) -> None:
    """Alternate: PPO for `update_every_steps` env steps, then a perception update."""
    if runner.current_learning_iteration == 0 and perception.updates == 0:
        _warm_up_perception(runner, perception)
    chunk = max(1, math.ceil(perception.cfg.update_every_steps / ppo_cfg.num_steps_per_env))
    runner.run_end = ppo_cfg.max_iterations
    while runner.current_learning_iteration < ppo_cfg.max_iterations:
        runner.learn(min(chunk, ppo_cfg.max_iterations - runner.current_learning_iteration))
        # rsl_rl opens a new TensorBoard writer at every learn(): keep the first one
        runner.logger.init_logging_writer = lambda: None
        start = time.perf_counter()
        metrics = perception.update()
        metrics["perception/update_seconds"] = time.perf_counter() - start
        it = runner.current_learning_iteration
        if runner.logger.writer is not None:
            for key, value in metrics.items():
                runner.logger.writer.add_scalar(key, value, it)
        if runner._saved_iteration == it and runner.last_checkpoint is not None:
            runner.write_checkpoint(runner.last_checkpoint.parent, it)  # now with the updated perception
        print(f"[perception] iteration {it}: {_metrics_line(metrics)}", flush=True)


# --- checkpoints -----------------------------------------------------------------------
def list_checkpoints(run_dir: Path) -> list[Path]:
    """Complete checkpoints in run_dir, oldest first (temp files of interrupted writes are skipped)."""
    found = [(int(m.group(1)), p) for p in Path(run_dir).glob("model_*.pt")
             if (m := re.fullmatch(r"model_(\d+)\.pt", p.name))]
    return [p for _, p in sorted(found)]


def _read_weights(path: str | Path, what: str) -> Any:
    """torch.load with weights_only=True (no code runs from the file); clear errors."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # truncated zip, bad pickle, foreign objects...
        first_line = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise CheckpointError(f"cannot read {what} {path} (truncated or corrupt?): {first_line}") from err


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Read and sanity-check a checkpoint (weights only: no code runs from the file)."""
    checkpoint = _read_weights(path, "checkpoint")
    if not isinstance(checkpoint, dict) or "format_version" not in checkpoint:
        raise CheckpointError(f"{path} is not a tacgnn PPO checkpoint (no format_version)")
    if checkpoint["format_version"] != FORMAT_VERSION:
        raise CheckpointError(f"checkpoint {path} has format version {checkpoint['format_version']}, "
                              f"this code reads {FORMAT_VERSION}")
    missing = [k for k in CHECKPOINT_KEYS if k not in checkpoint]
    if missing:
        raise CheckpointError(f"checkpoint {path} lacks {missing}")
    return checkpoint


def check_compatible(checkpoint: dict[str, Any], env_cfg: BaodingConfig, ppo_cfg: PPOConfig,
                     path: str | Path = "<checkpoint>") -> None:
    """Raise CheckpointError naming every env key (and network-shape key) that differs.

    The whole env config must match: besides what changes the observation (obs_mode,
    skin, ...), the saved env state only fits the same envs, physics and task.
    """
    try:  # keys added to the code since the checkpoint was written read as their defaults
        stored_env = to_dict(from_dict(BaodingConfig, checkpoint["env_config"]))
    except ConfigError as err:
        raise CheckpointError(f"checkpoint {path}: its env config does not fit this code: {err}") from None
    diffs = _differences(stored_env, to_dict(env_cfg))
    stored_ppo, wanted_ppo = checkpoint["ppo_config"], to_dict(ppo_cfg)
    diffs += [(f"ppo.{k}", stored_ppo.get(k), wanted_ppo[k]) for k in ARCHITECTURE_KEYS
              if stored_ppo.get(k) != wanted_ppo[k]]
    if diffs:
        shown = "; ".join(f"{key}: checkpoint {old!r}, requested {new!r}" for key, old, new in diffs[:8])
        more = f"; and {len(diffs) - 8} more" if len(diffs) > 8 else ""
        raise CheckpointError(f"checkpoint {path} does not match the requested config: differing keys "
                              f"{[d[0] for d in diffs]} ({shown}{more})")


def _differences(old: Any, new: Any, prefix: str = "") -> list[tuple[str, Any, Any]]:
    """(dotted key, old, new) for every leaf of two plain config trees that differs."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for key in list(old) + [k for k in new if k not in old]:
            name = f"{prefix}.{key}" if prefix else str(key)
            if key not in old or key not in new:
                out.append((name, old.get(key, "<absent>"), new.get(key, "<absent>")))
            else:
                out += _differences(old[key], new[key], name)
        return out
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        return [d for i, (a, b) in enumerate(zip(old, new)) for d in _differences(a, b, f"{prefix}[{i}]")]
    return [] if old == new else [(prefix, old, new)]


def _atomic_write(path: Path, write: Callable[[Any], Any]) -> None:
    """Write `path` through a temp file in the same directory, fsync it, then rename over."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


# --- inference -------------------------------------------------------------------------
def load_policy(checkpoint_path: str | Path) -> tuple[Callable[[np.ndarray], np.ndarray], BaodingConfig]:
    """The deterministic policy (mean action) of a checkpoint, and the env config it was trained on.

    The policy maps (N, obs_dim) observations to (N, 16) float32 actions, normaliser included.
    """
    checkpoint = _load_policy_file(checkpoint_path)
    env_cfg = from_dict(BaodingConfig, checkpoint["env_config"])
    ppo_cfg = from_dict(PPOConfig, checkpoint["ppo_config"])
    actor_cfg = dict(ppo_cfg.rsl_rl_cfg()["actor"])
    actor_cfg.pop("class_name")
    example = TensorDict({"policy": torch.zeros(1, checkpoint["obs_dim"])}, batch_size=[1])
    actor = MLPModel(example, {"actor": ["policy"]}, "actor", checkpoint["num_actions"], **actor_cfg)
    actor.load_state_dict(checkpoint["actor_state_dict"])
    actor.eval()

    def policy(obs: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            x = torch.as_tensor(np.asarray(obs), dtype=torch.float32)
            return actor(TensorDict({"policy": x}, batch_size=[x.shape[0]])).numpy()

    return policy, env_cfg


def load_perception(checkpoint_path: str | Path) -> OnlinePerception | None:
    """The perception a 'perceived' policy was trained with (None for other observation modes)."""
    checkpoint = _load_policy_file(checkpoint_path)
    if "perception" not in checkpoint:
        return None
    state = checkpoint["perception"]
    cfg = from_dict(OnlinePerceptionConfig, {**state["config"], "pretrained": ""})
    perception = OnlinePerception(replace(cfg, buffer_size=cfg.batch_size), checkpoint["env_config"]["skin"])
    perception.model.load_state_dict(state["model"])
    perception.updates = state["updates"]
    return perception


POLICY_KEYS = ("env_config", "ppo_config", "obs_dim", "num_actions", "actor_state_dict")


def export_policy(checkpoint_path: str | Path, out: str | Path) -> Path:
    """Write a small file with what acting needs (actor, configs, perception), not training state.

    A training checkpoint holds the critic, the optimiser and the env state (~5 MB); the
    exported policy is what the demo ships (well under 1 MB) and `load_policy` reads both.
    """
    checkpoint = load_checkpoint(checkpoint_path)
    slim = {"format_version": FORMAT_VERSION, "kind": "policy", "iteration": checkpoint["iteration"],
            **{k: checkpoint[k] for k in POLICY_KEYS}}
    if "perception" in checkpoint:
        perception = dict(checkpoint["perception"])
        perception.pop("optimizer", None)
        slim["perception"] = perception
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    _atomic_write(out, lambda fh: torch.save(slim, fh))
    return out


def _load_policy_file(path: str | Path) -> dict[str, Any]:
    """A training checkpoint or an exported policy (weights only either way)."""
    data = _read_weights(path, "policy file")
    if isinstance(data, dict) and data.get("kind") == "policy":
        missing = [k for k in POLICY_KEYS if k not in data]
        if missing or data.get("format_version") != FORMAT_VERSION:
            raise CheckpointError(f"{path}: exported policy of another version or lacking {missing}")
        return data
    return load_checkpoint(path)


# --- command line ----------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Train PPO on the Baoding env.")
    parser.add_argument("--run-dir", type=Path, help="default: <log_dir>/<experiment_name>")
    parser.add_argument("--resume", action="store_true", help="continue from the newest checkpoint")
    parser.add_argument("--env", nargs="*", default=[], metavar="KEY=VALUE", help="Baoding config overrides")
    parser.add_argument("--ppo", nargs="*", default=[], metavar="KEY=VALUE", help="PPOConfig overrides")
    parser.add_argument("--perception", nargs="*", default=[], metavar="KEY=VALUE",
                        help="OnlinePerceptionConfig overrides (with --env obs_mode=perceived), "
                             "e.g. model.name=tacgnn pretrained=runs/p/checkpoint.pt")
    args = parser.parse_args(argv)
    try:
        env_cfg, ppo_cfg, perception_cfg = BaodingConfig(), PPOConfig(), None
        stored = args.run_dir / "config.yaml" if args.run_dir else None
        if args.resume and stored is not None and stored.is_file():  # resume the run as configured
            tree = yaml.safe_load(stored.read_text())
            env_cfg, ppo_cfg = from_dict(BaodingConfig, tree["env"]), from_dict(PPOConfig, tree["ppo"])
            if "perception" in tree:
                perception_cfg = from_dict(OnlinePerceptionConfig, tree["perception"])
        env_cfg = override(env_cfg, parse_overrides(args.env))
        ppo_cfg = override(ppo_cfg, parse_overrides(args.ppo))
        if env_cfg.obs_mode == "perceived":
            perception_cfg = override(perception_cfg or OnlinePerceptionConfig(), parse_overrides(args.perception))
        elif args.perception:
            raise ConfigError("--perception needs --env obs_mode=perceived")
        train(env_cfg, ppo_cfg, args.run_dir, resume=args.resume, perception_cfg=perception_cfg)
    except (ConfigError, CheckpointError, FileExistsError, FileNotFoundError) as err:
        print(f"tacgnn.learning.ppo: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
