"""PPO's hyperparameters, and the dict rsl_rl's runner reads from them.

`PPOConfig` holds the TacGNN authors' settings (their rl_games config) as defaults; its
`rsl_rl_cfg` is the train_cfg of rsl_rl 5.5.1, with `GuardedPPO` as the algorithm.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from tacgnn.config import check, check_seed, to_dict

Activation = Literal["elu", "selu", "relu", "crelu", "lrelu", "tanh", "sigmoid", "softplus", "gelu", "swish", "mish"]

# PPO settings that fix the network's shape: a checkpoint cannot be resumed under others.
ARCHITECTURE_KEYS = ("actor_hidden_dims", "critic_hidden_dims", "activation", "obs_normalization",
                     "action_distribution")
# Bounds that turn a typo (an extra zero or three) into an error at load time, not a crash mid-run.
MAX_ENVS = 65_536
MAX_THREADS = 1024
MAX_COEF = 1e3  # the largest loss coefficient or reward scale taken


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
    action_distribution: Literal["gaussian", "beta"] = "gaussian"
    """The policy's action distribution. 'gaussian' (the authors'): samples are clipped to [-1, 1],
    so a mean pushed past a bound acts at the bound whatever the costs say (no sample moves, no
    gradient): the bang-bang drive. 'beta' (Chou et al. 2017, rsl_rl's `BetaDistribution`): bounded
    by construction, its mean always inside the range, so the action-rate and effort costs keep a
    gradient at the ends; `init_noise_std` does not apply (it starts near uniform)."""
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
        check_seed(self.seed)
        for key in ("num_envs", "num_steps_per_env", "num_learning_epochs", "num_mini_batches",
                    "save_interval", "torch_threads"):
            check(getattr(self, key) >= 1, key, f"must be >= 1, got {getattr(self, key)}")
        check(self.num_envs <= MAX_ENVS, "num_envs", f"must be <= {MAX_ENVS}, got {self.num_envs}")
        check(self.torch_threads <= MAX_THREADS, "torch_threads", f"must be <= {MAX_THREADS}, got {self.torch_threads}")
        check(self.max_iterations >= 0, "max_iterations", "must be >= 0")
        check(self.num_envs * self.num_steps_per_env <= 1 << 22, "num_steps_per_env",  # rollout storage ~2.5 GB
              f"num_envs x num_steps_per_env must be <= {1 << 22}, got {self.num_envs * self.num_steps_per_env}")
        check(self.num_envs * self.num_steps_per_env >= self.num_mini_batches, "num_mini_batches",
              f"{self.num_mini_batches} mini-batches, more than the samples per iteration "
              f"(num_envs x num_steps_per_env = {self.num_envs * self.num_steps_per_env})")
        check(0 < self.learning_rate <= 1, "learning_rate", f"needs 0 < learning_rate <= 1, got {self.learning_rate}")
        check(self.desired_kl > 0, "desired_kl", "must be positive")
        check(0 < self.gamma <= 1, "gamma", f"needs 0 < gamma <= 1, got {self.gamma}")
        check(0 <= self.lam <= 1, "lam", f"needs 0 <= lam <= 1, got {self.lam}")
        check(0 < self.clip_param <= 1, "clip_param",  # the ratio is clamped to [1 - clip, 1 + clip]
              f"needs 0 < clip_param <= 1, got {self.clip_param}")
        # upper bounds far above any use, below what overflows the float32 losses (1e300 made them inf)
        check(0 < self.init_noise_std <= 100, "init_noise_std", f"must be in (0, 100], got {self.init_noise_std}")
        check(self.max_grad_norm > 0, "max_grad_norm", "must be positive")
        check(0 < self.reward_scale <= MAX_COEF, "reward_scale",
              f"must be in (0, {MAX_COEF:g}], got {self.reward_scale}")
        for key in ("value_loss_coef", "entropy_coef"):
            check(0 <= getattr(self, key) <= MAX_COEF, key, f"must be in [0, {MAX_COEF:g}], got {getattr(self, key)}")
        for key in ("actor_hidden_dims", "critic_hidden_dims"):
            dims = getattr(self, key)
            check(1 <= len(dims) <= 16 and all(1 <= d <= 8192 for d in dims), key,
                  f"needs 1..16 layers of widths in 1..8192, got {list(dims)}")

    def rsl_rl_cfg(self) -> dict[str, Any]:
        """The train_cfg dict of rsl_rl 5.5.1's OnPolicyRunner (algorithm: `GuardedPPO`)."""

        def model(dims: tuple[int, ...], stochastic: bool) -> dict[str, Any]:
            cfg = {"class_name": "rsl_rl.models:MLPModel", "hidden_dims": list(dims),
                   "activation": self.activation, "obs_normalization": self.obs_normalization}
            if stochastic and self.action_distribution == "beta":
                cfg["distribution_cfg"] = {"class_name": "rsl_rl.modules:BetaDistribution"}
            elif stochastic:
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
                "class_name": "tacgnn.learning.guarded_ppo:GuardedPPO",
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


def architecture_differences(stored: Mapping[str, Any], cfg: PPOConfig) -> list[tuple[str, Any, Any]]:
    """(key, stored, wanted) for each of `ARCHITECTURE_KEYS` where a stored PPO config (a
    checkpoint's) and `cfg` differ; a key the stored config's version did not have yet has the
    default it ran with."""
    old, new = {k: stored.get(k, getattr(PPOConfig, k)) for k in ARCHITECTURE_KEYS}, to_dict(cfg)
    return [(k, old[k], new[k]) for k in ARCHITECTURE_KEYS if old[k] != new[k]]
