"""Train PPO on the Baoding env: a fresh run or the exact continuation of a stopped one.

    tacgnn train-policy --run-dir runs/gt --env task=simple --ppo max_iterations=5000
    tacgnn train-policy --run-dir runs/gt --resume
    torchrun --standalone --nproc-per-node 4 -m tacgnn.cli train-policy --device cuda --run-dir runs/gt ...

A run folder holds config.yaml, train.log (the full report of every iteration; the console
shows one line each), TensorBoard events and ``model_<iterations>.pt`` checkpoints
(`tacgnn.learning.checkpoint`). Ctrl-C or SIGTERM saves a checkpoint of the iteration under way
before the run stops. Resuming
continues from the newest checkpoint, bit for bit as if the run had never stopped; temp
files left by a killed write are removed first. Under torchrun the ranks train one policy
on their own envs (`tacgnn.learning.distributed`); rank 0 writes the run folder.
"""

from __future__ import annotations

import argparse
import logging
import math
import random
import signal
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import yaml

from tacgnn.config import ConfigError, from_dict, override, parse_overrides, to_dict, yaml_load
from tacgnn.envs.baoding import BaodingConfig, training_env_config
from tacgnn.files import FileProblem, atomic_write_text, remove_stale_temp_files
from tacgnn.learning import checkpoint as ckpt
from tacgnn.learning import distributed
from tacgnn.learning.config import PPOConfig, architecture_differences
from tacgnn.learning.online_perception import OnlinePerception, OnlinePerceptionConfig
from tacgnn.learning.rsl_env import RslBaodingEnv
from tacgnn.learning.runner import LOG_FILE, Runner

log = logging.getLogger(__name__)


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def train(env_cfg: BaodingConfig, ppo_cfg: PPOConfig, run_dir: str | Path | None = None,
          resume: bool = False, perception_cfg: OnlinePerceptionConfig | None = None,
          dist: distributed.Distributed | None = None) -> Path | None:
    """Train until ``ppo_cfg.max_iterations`` iterations are done; return the last checkpoint.

    `dist` places this process in a multi-process run (`distributed.from_environment`; default
    one process on the CPU): the process group is joined here, this rank's envs and random
    draws are seeded apart from the others', and only rank 0 writes (and returns a path).

    run_dir (default ``log_dir/experiment_name``) receives config.yaml, TensorBoard events
    and checkpoints. A fresh run refuses a run_dir that already holds checkpoints;
    ``resume=True`` continues from the newest one, whose env config must equal `env_cfg`
    (else CheckpointError, a ValueError, naming the differing keys). Files that cannot be
    written raise `FileProblem` naming them.
    """
    run_dir = Path(run_dir) if run_dir is not None else Path(ppo_cfg.log_dir) / ppo_cfg.experiment_name
    env_cfg = replace(env_cfg, num_envs=ppo_cfg.num_envs)
    if (env_cfg.obs_mode == "perceived") != (perception_cfg is not None):
        raise ConfigError("obs_mode 'perceived' and a perception config go together "
                          f"(obs_mode={env_cfg.obs_mode!r}, "
                          f"perception config {'given' if perception_cfg else 'missing'})")
    if env_cfg.obs_mode == "tactile":
        raise ConfigError("config key 'obs_mode': 'tactile' gives the raw skin arrays, which the MLP policy cannot "
                          "read; use 'perceived' (a perception reads them) or another mode")
    dist = dist or distributed.Distributed()
    if dist.enabled and perception_cfg is not None:
        raise ConfigError(f"obs_mode 'perceived' trains its perception on one process's frames: run it in one "
                          f"process, not {dist.world_size}")
    torch.set_num_threads(ppo_cfg.torch_threads)
    if run_dir.is_dir() and dist.is_main:
        for tmp in remove_stale_temp_files(run_dir):
            log.info("removed %s, left by a write that was killed", tmp)
    checkpoint, path = _checkpoint_to_resume(run_dir, env_cfg, ppo_cfg, resume)
    start = _initial_weights(ppo_cfg) if checkpoint is None and ppo_cfg.init_from else None
    distributed.init(dist)  # after the checks, which every rank makes alike: a bad run fails on all
    distributed.check_same(None if path is None else path.name, "the checkpoint to resume (the run folder "
                           "must be one folder shared by all ranks)", dist)

    seed_everything(distributed.rank_seed(ppo_cfg.seed, dist))
    perception = (None if perception_cfg is None
                  else OnlinePerception(perception_cfg, to_dict(env_cfg.skin), ppo_cfg.seed))
    env = RslBaodingEnv(_rank_env_config(env_cfg, dist), ppo_cfg.reward_scale, ppo_cfg.bootstrap_time_outs,
                        perception=perception, privileged_critic=ppo_cfg.privileged_critic)
    if perception is not None:
        env.on_step = perception.record
    for given, where in ((checkpoint, path), (start, ppo_cfg.init_from)):
        if given is not None and given["obs_dim"] != env.num_obs:
            raise ckpt.CheckpointError(f"checkpoint {where}: obs_dim {given['obs_dim']} != this env's {env.num_obs}")
    if dist.is_main:
        _write_run_config(run_dir, env_cfg, ppo_cfg, perception_cfg)

    runner = Runner(env, env_cfg, ppo_cfg, run_dir, perception, dist)
    if start is not None:
        runner.alg.load(start, load_cfg={"actor": True, "critic": True}, strict=True)
        _set_action_std(runner, ppo_cfg.init_noise_std)  # explore afresh around the loaded policy
        print(f"actor and critic initialised from {ppo_cfg.init_from}")
    if checkpoint is not None:
        frames = ckpt.load_frames(run_dir, checkpoint["iteration"]) if perception is not None else None
        if perception is not None and frames is None:
            log.warning("%s is missing: the perception's frame buffer refills from empty, so this run will "
                        "not match an uninterrupted one bit for bit",
                        ckpt.frames_path(run_dir, checkpoint["iteration"]))
        runner.restore(checkpoint, frames)
        runner.last_checkpoint = path if dist.is_main else None
        if dist.is_main:
            print(f"resuming {path} at iteration {checkpoint['iteration']}")
    try:
        runner.learn(ppo_cfg.max_iterations)
    finally:
        runner.close()
    if dist.is_main:
        _closing_line(runner, run_dir)
    if runner.stopped_by == "SIGINT":
        raise KeyboardInterrupt
    if runner.stopped_by:
        raise SystemExit(128 + signal.Signals[runner.stopped_by].value)
    return runner.last_checkpoint


def _closing_line(runner: Runner, run_dir: Path) -> None:
    """What the run left behind, and how to go on from it."""
    saved = runner.last_checkpoint
    where = f"{saved}" if saved else "no checkpoint"
    if runner.stopped_by:
        print(f"stopped by {runner.stopped_by} after iteration {runner.iteration}: saved {where}; continue with "
              f"tacgnn train-policy --run-dir {run_dir} --resume", flush=True)
    else:
        print(f"done: {runner.iteration} iterations, last checkpoint {where} (log: {run_dir / LOG_FILE}; curves: "
              f"tensorboard --logdir {run_dir})", flush=True)


def _rank_env_config(env_cfg: BaodingConfig, dist: distributed.Distributed) -> BaodingConfig:
    """This rank's envs: their own seed, and under torchrun a Warp 'cuda' on this rank's GPU.

    The run's config (stored, compared on resume) stays the one given.
    """
    sim = env_cfg.sim
    if dist.enabled and sim.backend == "warp" and sim.device == "cuda" and dist.device.startswith("cuda"):
        sim = replace(sim, device=dist.device)
    return replace(env_cfg, seed=distributed.rank_seed(env_cfg.seed, dist), sim=sim)


def _checkpoint_to_resume(run_dir: Path, env_cfg: BaodingConfig, ppo_cfg: PPOConfig,
                          resume: bool) -> tuple[dict | None, Path | None]:
    """The newest checkpoint, checked against the configs, when resuming; (None, None) for a fresh run."""
    existing = ckpt.list_checkpoints(run_dir) if run_dir.is_dir() else []
    if not resume:
        if existing:
            raise FileExistsError(f"{run_dir} already holds checkpoints ({existing[-1].name}); "
                                  "resume=True to continue that run, or choose another run_dir")
        return None, None
    if not existing:
        raise FileNotFoundError(f"nothing to resume: no model_*.pt checkpoint in {run_dir}")
    checkpoint = ckpt.load_checkpoint(existing[-1])
    ckpt.check_compatible(checkpoint, env_cfg, ppo_cfg, existing[-1])
    return checkpoint, existing[-1]


def _initial_weights(ppo_cfg: PPOConfig) -> dict:
    """The checkpoint named by init_from, if its networks have this run's shape."""
    start = ckpt.load_checkpoint(ppo_cfg.init_from)
    differing = architecture_differences(start["ppo_config"], ppo_cfg)
    if differing:
        keys = [k for k, *_ in differing]
        raise ckpt.CheckpointError(f"init_from {ppo_cfg.init_from}: its networks differ in {keys} "
                                   f"({', '.join(f'{k} {old} != {new}' for k, old, new in differing)})")
    return start


def _write_run_config(run_dir: Path, env_cfg: BaodingConfig, ppo_cfg: PPOConfig,
                      perception_cfg: OnlinePerceptionConfig | None) -> None:
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise FileProblem(f"cannot create the run folder {run_dir}: {err.strerror or err}") from err
    stored = {"env": to_dict(env_cfg), "ppo": to_dict(ppo_cfg)}
    if perception_cfg is not None:
        stored["perception"] = to_dict(perception_cfg)
    atomic_write_text(run_dir / "config.yaml", yaml.safe_dump(stored, sort_keys=False))


def _set_action_std(runner: Runner, std: float) -> None:
    """Reset the policy's (learned, state-independent) action std to `std`."""
    with torch.no_grad():
        for name, param in runner.alg.actor.named_parameters():
            if name.endswith("log_std_param"):
                param.fill_(math.log(std))
            elif name.endswith("std_param"):
                param.fill_(std)


def _stored_configs(run_dir: Path) -> tuple[BaodingConfig, PPOConfig, OnlinePerceptionConfig | None]:
    """The configs a run was started with (its config.yaml), to resume it as configured."""
    path = run_dir / "config.yaml"
    try:
        tree = yaml_load(path.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise ConfigError(f"cannot read {path}: {err}") from None
    if not isinstance(tree, dict) or not {"env", "ppo"} <= tree.keys():
        raise ConfigError(f"{path}: expected 'env' and 'ppo' sections")
    env_cfg, ppo_cfg = from_dict(BaodingConfig, tree["env"]), from_dict(PPOConfig, tree["ppo"])
    perception_cfg = from_dict(OnlinePerceptionConfig, tree["perception"]) if "perception" in tree else None
    return env_cfg, ppo_cfg, perception_cfg


def main(argv: list[str] | None = None, parser_class: type[argparse.ArgumentParser] = argparse.ArgumentParser) -> int:
    """`tacgnn train-policy`; user errors raise (ConfigError, CheckpointError, OSError), for the CLI to report."""
    parser = parser_class(prog="tacgnn train-policy", description="Train PPO on the Baoding env.")
    parser.add_argument("--run-dir", type=Path, help="default: <log_dir>/<experiment_name>")
    parser.add_argument("--resume", action="store_true", help="continue from the newest checkpoint")
    parser.add_argument("--device", default="cpu",
                        help="torch device of the policy and PPO: cpu, cuda or cuda:N; under torchrun "
                             "'cuda' is cuda:LOCAL_RANK (nccl) and 'cpu' runs the ranks on the CPU (gloo)")
    parser.add_argument("--env", nargs="*", default=[], metavar="KEY=VALUE", help="Baoding config overrides")
    parser.add_argument("--ppo", nargs="*", default=[], metavar="KEY=VALUE", help="PPOConfig overrides")
    parser.add_argument("--perception", nargs="*", default=[], metavar="KEY=VALUE",
                        help="OnlinePerceptionConfig overrides (with --env obs_mode=perceived), "
                             "e.g. model.name=tacgnn pretrained=runs/p/checkpoint.pt")
    args = parser.parse_args(argv)
    dist = distributed.from_environment(args.device)  # a device that is not here: ConfigError, at once
    env_cfg, ppo_cfg, perception_cfg = training_env_config(), PPOConfig(), None
    if args.resume and args.run_dir is not None and (args.run_dir / "config.yaml").is_file():
        env_cfg, ppo_cfg, perception_cfg = _stored_configs(args.run_dir)  # resume the run as configured
    env_cfg = override(env_cfg, parse_overrides(args.env))
    ppo_cfg = override(ppo_cfg, parse_overrides(args.ppo))
    if env_cfg.obs_mode == "perceived":
        perception_cfg = override(perception_cfg or OnlinePerceptionConfig(), parse_overrides(args.perception))
    elif args.perception:
        raise ConfigError("--perception needs --env obs_mode=perceived")
    else:
        perception_cfg = None  # a stored one goes with the stored obs_mode, which --env changed
    try:
        train(env_cfg, ppo_cfg, args.run_dir, resume=args.resume, perception_cfg=perception_cfg, dist=dist)
    finally:
        distributed.shutdown(dist)
    return 0
