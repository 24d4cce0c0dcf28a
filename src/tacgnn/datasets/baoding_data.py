"""The Baoding ball-position dataset: skin frames of balls moving in the hand, with labels.

Per sample: the 653 taxel readings (N), the taxels' world positions (m), the joint
positions and velocities, and both ball centres (m, world axes, hand origin at 0).
Balls keep their identity: ``ball_pos[:, 0]`` is always ball 0. The two balls look the
same to the skin, so a model cannot know which is which; training uses a
permutation-invariant loss (`tacgnn.perception.objectives`), and the order stored here is
only the simulator's.

Samples come from rollouts of a controller that keeps the balls moving (a trained
ground-truth policy, a blind policy acting on its own perception, or a scripted controller:
`FingerWave`, `RandomMotion`). Frames of the first
`settle_steps` steps of an episode (balls still dropping from the spawn) and the last frame of an episode that
ended (a ball falling away) are left out; with `min_episode_steps` so are the episodes that
end before that step.

Every frame also carries what a temporal model needs to put frames back in order: its
``episode`` (an id unique in the dataset) and ``step`` (control steps since the episode's
reset), and the ``action`` the hand was commanded in that step (the previous action, as
the real hand knows it). With ``keep_every=1`` an episode's frames are consecutive steps,
so windows of consecutive frames can be drawn (`tacgnn.perception.sequences`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from tacgnn.config import ConfigError, check, check_seed, to_dict
from tacgnn.datasets.store import Field, ShardedWriter
from tacgnn.envs.baoding import BaodingConfig, BaodingEnv
from tacgnn.envs.observation import PROPRIO_COLUMNS
from tacgnn.envs.scripted import FingerWave, RandomMotion

SCRIPTED: dict[str, Callable[..., Callable[..., np.ndarray]]] = {"wave": FingerWave, "random": RandomMotion}


@dataclass(frozen=True)
class BaodingDataConfig:
    samples: int = 25_000
    shard_size: int = 5_000
    num_envs: int = 64
    seed: int = 0
    settle_steps: int = 5
    keep_every: int = 2
    """Record every k-th step of each env (consecutive frames are nearly identical); 1 keeps every
    frame, which sequence models need."""
    policy_checkpoint: str = ""
    """A PPO checkpoint to drive the balls ('' = the `scripted` controller): a ground-truth policy
    (the env's obs_mode 'tactile'), or a blind one acting on its perception's ball positions (the
    env's obs_mode 'perceived': the frames its own grip makes, for its perception to learn)."""
    scripted: Literal["wave", "random"] = "wave"
    """Without a policy: the finger wave (`FingerWave`) or smooth random joint motion (`RandomMotion`)."""
    action_noise: float = 0.1
    """Gaussian noise (action units) on the policy's actions, for more varied contacts."""
    min_episode_steps: int = 0
    """Keep only the episodes still running at this step (0: all), every frame of them from
    their start: data from the long holds that a good policy rarely reaches."""
    env: BaodingConfig = field(default_factory=lambda: BaodingConfig(obs_mode="tactile"))

    def __post_init__(self) -> None:
        check_seed(self.seed)
        check(self.shard_size > 0, "shard_size", f"must be >= 1, got {self.shard_size}")
        check(self.samples > 0 and self.samples % self.shard_size == 0, "samples",
              f"must be a positive multiple of shard_size ({self.shard_size}), got {self.samples}")
        check(1 <= self.num_envs <= 65_536, "num_envs", f"must be in 1..65536, got {self.num_envs}")
        check(self.keep_every >= 1, "keep_every", "must be >= 1")
        check(self.scripted in SCRIPTED, "scripted", f"must be one of {list(SCRIPTED)}, got {self.scripted!r}")
        check(self.settle_steps >= 0, "settle_steps", f"must be >= 0, got {self.settle_steps}")
        check(self.action_noise >= 0, "action_noise", f"must be >= 0, got {self.action_noise}")
        check(self.min_episode_steps >= 0, "min_episode_steps", f"must be >= 0, got {self.min_episode_steps}")
        # an episode ends by this step at the latest: skipping or requiring more steps records nothing, ever
        limit = (round(self.env.continuous_seconds / self.env.control_dt) if self.env.task == "continuous"
                 else self.env.max_episode_steps)
        for key in ("settle_steps", "min_episode_steps"):
            value = getattr(self, key)
            check(value < limit, key, f"must be below the episode's {limit} steps, got {value}")
        check(self.keep_every <= limit, "keep_every", f"must be at most the episode's {limit} steps")
        check(self.env.obs_mode in ("tactile", "perceived"), "env.obs_mode",
              "the dataset records the skin: 'tactile' (or 'perceived' for a blind policy's own frames)")


def schema(num_taxels: int) -> dict[str, Field]:
    return {
        "tactile": Field((num_taxels,)),
        "taxel_pos": Field((num_taxels, 3)),
        "joint_pos": Field((16,)),
        "joint_vel": Field((16,)),
        "ball_pos": Field((2, 3)),
        "action": Field((16,)),
        "episode": Field((), "int64"),
        "step": Field((), "int64"),
    }


#: Episode ids: the k-th episode of env e in shard i is ``(i * num_envs + e) * EPISODES_PER_ENV + k``.
EPISODES_PER_ENV = 100_000


def metadata(cfg: BaodingDataConfig) -> dict:
    from tacgnn import __version__

    return {"kind": "baoding", "num_taxels": cfg.env.skin.num_taxels, "seed": cfg.seed,
            "skin": to_dict(cfg.env.skin), "controller": cfg.policy_checkpoint or SCRIPTED[cfg.scripted].__name__,
            "code_version": __version__,
            "config": to_dict(cfg)}


Policy = Callable[[np.ndarray], np.ndarray]
"""A policy: (N, 54) observations (60 with `ball_velocity`) -> (N, 16) actions
(`tacgnn.learning.policy.load_policy`)."""
Perception = Callable[[], Callable[[np.ndarray, np.ndarray], np.ndarray]]
"""Makes a fresh perception for one shard's env (a blind policy's: `BaodingEnv(perception=...)`)."""


def shard_seed(cfg: BaodingDataConfig, index: int) -> int:
    """The seed of shard `index`'s envs and rollout: each shard is deterministic on its own."""
    return cfg.seed * 100_003 + index


def record_shard(cfg: BaodingDataConfig, index: int, policy: Policy | None = None,
                 controller: Callable[[BaodingEnv, int], Callable] | None = None,
                 perception: Perception | None = None) -> dict[str, np.ndarray]:
    """Roll out until one shard's worth of samples is collected; deterministic in (seed, index).

    The balls are driven by `controller`, else by `policy` (the policy named by
    `cfg.policy_checkpoint`, loaded by the caller), else by the `scripted` controller. A blind
    policy (`cfg.env.obs_mode` 'perceived') acts on the ball positions of `perception()`, made
    fresh for this shard, so each shard starts its memory from nothing.
    """
    seed = shard_seed(cfg, index)
    blind = cfg.env.obs_mode == "perceived"
    if blind != (perception is not None):
        raise ConfigError("env.obs_mode: 'perceived' records a blind policy and needs its perception, "
                          "and only it does")
    env = BaodingEnv(replace(cfg.env, num_envs=cfg.num_envs, seed=seed),
                     perception=perception() if perception is not None else None)
    obs, _ = env.reset(seed=seed)
    if controller is None:
        if cfg.policy_checkpoint and policy is None:
            raise ConfigError(f"policy_checkpoint {cfg.policy_checkpoint}: "
                              "the caller must load it and pass it as `policy`")
        controller = policy_controller(policy, cfg.action_noise) if policy is not None else \
            (lambda e, s: SCRIPTED[cfg.scripted](e.last_action[0], cfg.num_envs, seed=s))
    act = controller(env, seed)
    out: dict[str, list] = {k: [] for k in schema(env.tactile.num_taxels)}
    held = EpisodeFilter(cfg.num_envs, cfg.min_episode_steps)
    count, step = 0, 0
    episode_of_env = (index * cfg.num_envs + np.arange(cfg.num_envs)) * EPISODES_PER_ENV  # unique in the dataset
    while count < cfg.shard_size:
        obs, _, terminated, truncated, info = env.step(act(obs))
        step += 1
        episode = episode_of_env.copy()  # of this step's frame; an env that ended starts its next one
        ended = terminated | truncated
        episode_of_env += ended
        # joints of the recorded instant: the pre-reset observation of this step
        joints = proprio_of(info["final_obs"] if "final_obs" in info else obs)
        keep = ~ended & (info["episode_steps"] > cfg.settle_steps)
        keep &= (np.arange(cfg.num_envs) + step) % cfg.keep_every == 0
        if keep.any():
            frame = {
                "tactile": env.skin_to_host(info["tactile"])[keep],
                "taxel_pos": env.skin_to_host(info["taxel_pos"])[keep],
                "joint_pos": env.joint_low + (joints[keep, :16] + 1) * 0.5 * (env.joint_high - env.joint_low),
                "joint_vel": joints[keep, 16:32] / 0.2,
                "ball_pos": info["ball_pos"][keep],
                "action": env.last_action[keep],  # the command of this step (clipped), before any reset
                "episode": episode[keep],
                "step": info["episode_steps"][keep],
            }
            for part in held.add(frame, keep, info["episode_steps"]):
                for k, v in part.items():
                    out[k].append(v)
                count += len(part["step"])
        held.end(ended)
    return {k: np.concatenate(v)[:cfg.shard_size] for k, v in out.items()}


def proprio_of(obs: dict | np.ndarray) -> np.ndarray:
    """(N, 32) scaled joint angles and velocities of an observation, 'tactile' (a dict) or a vector."""
    return obs["proprio"][:, PROPRIO_COLUMNS] if isinstance(obs, dict) else obs[:, PROPRIO_COLUMNS]


class EpisodeFilter:
    """Holds back each env's frames until its episode reaches `min_steps` steps, then lets the
    held frames and all later ones through; an episode that ends sooner is dropped."""

    def __init__(self, num_envs: int, min_steps: int) -> None:
        self.min_steps = min_steps
        self.held: list[list[dict[str, np.ndarray]]] = [[] for _ in range(num_envs)]

    def add(self, frame: dict[str, np.ndarray], envs: np.ndarray, steps: np.ndarray) -> list[dict[str, np.ndarray]]:
        """The frames to record now, from this step's `frame` (rows: the envs where `envs` is True)
        and the envs' episode steps."""
        if self.min_steps == 0:
            return [frame]
        out = []
        for row, e in enumerate(np.flatnonzero(envs)):
            self.held[e].append({k: v[row:row + 1] for k, v in frame.items()})
            if steps[e] >= self.min_steps:
                out.extend(self.held[e])
                self.held[e] = []
        return out

    def end(self, ended: np.ndarray) -> None:
        """Drop the held frames of the envs whose episode ended (and did not reach `min_steps`)."""
        for e in np.flatnonzero(ended):
            self.held[e] = []


def policy_controller(policy: Policy, action_noise: float):
    """Drive the balls with a policy, plus action noise: a ground-truth policy sees the true ball
    positions (in the env config's ball order, with their velocities if it shows them), a blind
    one the env's own observation (its perception's positions)."""

    def make(env: BaodingEnv, seed: int):
        rng = np.random.default_rng(seed)

        def act(obs: dict | np.ndarray) -> np.ndarray:
            # a 'tactile' recording env shows the skin: a ground-truth policy reads its own observation
            full = obs if isinstance(obs, np.ndarray) else env.groundtruth_obs()
            return np.clip(policy(full) + action_noise * rng.standard_normal((len(full), 16)), -1, 1)

        return act

    return make


def generate(cfg: BaodingDataConfig, root: str | Path, progress=None, policy: Policy | None = None,
             perception: Perception | None = None) -> Path:
    """Generate (or finish generating) the dataset in folder `root` (`policy`, `perception`: see
    `record_shard`)."""
    writer = ShardedWriter(root, schema(cfg.env.skin.num_taxels), metadata(cfg),
                           num_shards=cfg.samples // cfg.shard_size, shard_size=cfg.shard_size)
    writer.generate_missing(lambda i: record_shard(cfg, i, policy, perception=perception), progress=progress)
    return Path(root)
