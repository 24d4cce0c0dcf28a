"""Commands that show the simulation: the default config, the demo, a rendered episode, the viewer."""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from tacgnn.cli.common import add_config_options, baoding_config, config_updates, count, seed
from tacgnn.config import ConfigError, override, to_dict


def shipped_policy() -> Path:
    from tacgnn.learning.policy import SHIPPED_POLICY

    return SHIPPED_POLICY


def cmd_config(args) -> int:
    import yaml

    print(yaml.safe_dump(to_dict(baoding_config(args)), sort_keys=False))
    return 0


def _make_env(args, num_envs: int | None = None):
    from tacgnn.envs.baoding import BaodingEnv

    cfg = baoding_config(args)
    return BaodingEnv(replace(cfg, num_envs=num_envs) if num_envs else cfg)


def _policy_setup(policy_file: Path, args) -> tuple[Any, Any, Any, dict[str, Any]]:
    """(policy, the env config it acts in with --config/--set applied, its perception, the updates).

    The env is the policy's own (observation, hand, task) with the given keys changed; an unknown
    key, a bad value, or a change the policy cannot act under is refused before anything runs.
    """
    from tacgnn.envs.baoding import BaodingConfig
    from tacgnn.learning import checkpoint as ckpt
    from tacgnn.learning.policy import perception_from_checkpoint, policy_from_checkpoint

    updates = config_updates(BaodingConfig, args)
    if "num_envs" in updates:
        raise ConfigError("config key 'num_envs': with a policy the number of envs is --envs")
    data = ckpt.load_policy_file(policy_file)
    stored = ckpt.stored_env_config(data, policy_file)
    env_cfg = override(replace(stored, task="simple", seed=args.seed if args.seed is not None else stored.seed),
                       updates)
    ckpt.check_policy_fits(data, env_cfg, policy_file)
    return policy_from_checkpoint(data, policy_file), env_cfg, perception_from_checkpoint(data), updates


def cmd_demo(args) -> int:
    """Run the shipped policy (or the scripted controller) on Simple; print results; write a video."""
    policy_file = None if args.scripted else Path(args.policy) if args.policy else shipped_policy()
    if policy_file is not None and not args.policy and not policy_file.is_file():
        print(f"(no shipped policy at {policy_file}: running the scripted controller)")
        policy_file = None
    if policy_file is None:
        return _demo_scripted(args)
    from tacgnn.learning.evaluate import evaluate

    policy, env_cfg, perception, updates = _policy_setup(policy_file, args)
    task = updates.pop("task", "simple")
    start = time.perf_counter()
    result = evaluate(policy_file, task, episodes=args.episodes, num_envs=min(args.envs, args.episodes),
                      seed=env_cfg.seed, env_overrides=updates)
    seconds = time.perf_counter() - start
    seen = "perceived by the skin (TacGNN)" if perception is not None else f"from '{env_cfg.obs_mode}'"
    changed = f" ({' '.join(args.set)})" if args.set else ""
    hand = "hands drawn as real ones differ" if env_cfg.randomization.enabled else "the nominal hand"
    print(f"Baoding, {task.capitalize()} task{changed}, policy {policy_file.name}: ball positions {seen}, "
          f"on {hand}, {env_cfg.skin_signal.preset} skin")
    print(f"  success rate:          {100 * result['success_rate']:.1f} % of {result['episodes']} episodes "
          f"(95 % CI {100 * result['ci95'][0]:.1f}-{100 * result['ci95'][1]:.1f})")
    print(f"  mean steps to success: {result['mean_steps_to_success']:.1f} (control at 50 Hz)")
    print(f"  falls:                 {100 * result['fall_rate']:.1f} %   ({seconds:.1f} s)")
    if args.video:
        _film(args, lambda env: policy, replace(env_cfg, num_envs=1, tactile=True), perception,
              f"policy {policy_file.stem}, ball positions {seen}")
    return 0


def _film(args, make_policy, env_cfg, perception, who: str) -> None:
    """Write the demo video of one env of `env_cfg` acted on by `make_policy(env)`."""
    from tacgnn.envs.baoding import BaodingEnv
    from tacgnn.tools.demo_video import render_demo

    env = BaodingEnv(env_cfg, perception=perception)
    obs, _ = env.reset(seed=env_cfg.seed)
    summary = render_demo(env, make_policy(env), args.video, seconds=args.video_seconds, obs=obs,
                          title=f"Baoding balls, {env_cfg.task.capitalize()} task: {who}")
    print(f"  video: {args.video} ({summary['seconds']:.0f} s, {summary['width']}x{summary['height']}, "
          f"{summary['episodes_ended']} episodes ended, {summary['successes']} successes, "
          f"{summary['mean_active_taxels']:.1f} activated taxels/frame; rendered in {summary['wall_seconds']:.0f} s)")


def _demo_scripted(args) -> int:
    from tacgnn.envs.scripted import FingerWave

    env = _make_env(args)
    obs, _ = env.reset(seed=env.config.seed)
    controller = FingerWave(env.last_action[0], env.num_envs, seed=env.config.seed)
    active, angles, falls, episodes = [], [], 0, 0
    start = time.perf_counter()
    for _ in range(args.steps):
        obs, _, terminated, truncated, info = env.step(controller(obs))
        active.append((env.skin_to_host(info["tactile"]) > 0).sum(1).mean())
        done = terminated | truncated
        episodes += int(done.sum())
        falls += int(info["fall"].sum())
        angles.extend(np.abs(info["angle_deg"][done]))
    seconds = time.perf_counter() - start
    print(f"Baoding, scripted finger wave, {env.config.task} task, {env.num_envs} envs x {args.steps} steps "
          f"({env.substeps} physics substeps each)")
    print(f"  env steps/s:              {args.steps * env.num_envs / seconds:,.0f}")
    print(f"  activated taxels / step:  {np.mean(active):.1f} of {env.tactile.num_taxels}")
    print(f"  episodes ended:           {episodes} (falls {falls})")
    if angles:
        print(f"  |rotation| at episode end: mean {np.mean(angles):.1f} deg, max {np.max(angles):.1f} deg")
    if args.video:
        cfg = replace(baoding_config(args), num_envs=1)
        _film(args, lambda env: FingerWave(env.last_action[0], 1, seed=cfg.seed), cfg, None,
              "scripted finger wave (no policy)")
    return 0


def cmd_render(args) -> int:
    from tacgnn.envs.baoding import BaodingEnv
    from tacgnn.envs.scripted import FingerWave
    from tacgnn.tools.render import render_episode, save_skin_picture

    if args.policy:
        policy, env_cfg, perception, _ = _policy_setup(Path(args.policy), args)
        env = BaodingEnv(replace(env_cfg, num_envs=1, tactile=True), perception=perception)
    else:
        env = _make_env(args, num_envs=1)
    obs, _ = env.reset(seed=env.config.seed)
    controller = policy if args.policy else FingerWave(env.last_action[0], 1, seed=env.config.seed)
    summary = render_episode(env, controller, args.out, steps=args.steps, obs=obs)
    print(f"wrote {args.out}: {summary['frames']} frames, final angle {summary['final_angle_deg']:.1f} deg, "
          f"{summary['mean_active_taxels']:.1f} activated taxels/frame")
    if args.skin_picture:
        moment = summary["busiest"]
        save_skin_picture(env, args.skin_picture, moment=moment)
        print(f"wrote {args.skin_picture}: the skin at step {moment['step']}, "
              f"{int(np.count_nonzero(moment['readings']))} of {env.tactile.num_taxels} taxels touched")
    return 0


def cmd_view(args) -> int:
    from tacgnn.envs.scripted import FingerWave
    from tacgnn.tools.render import RenderingUnavailable, launch_viewer

    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise RenderingUnavailable("the interactive viewer needs a display (DISPLAY is not set); "
                                   "`tacgnn render` writes a video instead")
    env = _make_env(args, num_envs=1)
    env.reset(seed=env.config.seed)
    launch_viewer(env, FingerWave(env.last_action[0], 1, seed=env.config.seed))
    return 0


def _seed_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seed", type=seed, help="the env's seed (default: the config's, 0)")


def register(sub) -> None:
    """The sub-commands of this module, with their options."""
    p = sub.add_parser("demo", help="run the shipped Baoding policy (TacGNN perception) and write a video")
    add_config_options(p, note=", applied over the policy's own config (its task: simple)")
    _seed_option(p)
    p.add_argument("--policy", help="policy or checkpoint file (default: the shipped baoding_policy.pt)")
    p.add_argument("--scripted", action="store_true", help="the scripted finger wave instead of a policy")
    p.add_argument("--episodes", type=count(1), default=64, help="episodes for the success rate")
    p.add_argument("--envs", type=count(1), default=64, help="envs stepped together")
    p.add_argument("--steps", type=count(1), default=200, help="scripted: control steps")
    p.add_argument("--video", default="outputs/demo.mp4", help="video file (.mp4 or .gif); '' to skip it")
    p.add_argument("--video-seconds", type=count(1, 600), default=16, help="length of the video (s)")
    p.set_defaults(fn=cmd_demo)

    p = sub.add_parser("render", help="write a video of one env and a picture of its skin")
    add_config_options(p, note=", with --policy applied over the policy's own config")
    _seed_option(p)
    p.add_argument("--policy", help="policy or checkpoint file (default: the scripted finger wave)")
    p.add_argument("--out", default="outputs/episode.mp4", help="video file (.mp4 or .gif)")
    p.add_argument("--steps", type=count(1), default=100, help="control steps (50 per second)")
    p.add_argument("--skin-picture", default="outputs/skin.png", help="PNG of the skin at the end; '' to skip it")
    p.set_defaults(fn=cmd_render)

    p = sub.add_parser("view", help="interactive viewer (needs a display)")
    add_config_options(p)
    _seed_option(p)
    p.set_defaults(fn=cmd_view)

    p = sub.add_parser("config", help="print the Baoding config (defaults, --config and --set applied) as YAML")
    add_config_options(p)
    _seed_option(p)
    p.set_defaults(fn=cmd_config)
