"""A blind policy file for the real-hand tests, whatever policy the package ships.

The tests exercise the controller's plumbing, not a policy's skill: they take the shipped
blind policy's networks and, if it was trained on an older hand model that the loader
refuses, mark its config as this hand's, so the plumbing can be tested with it.
"""

from pathlib import Path

import torch

from tacgnn.config import to_dict
from tacgnn.envs.baoding import BaodingConfig
from tacgnn.envs.observation import BALL_COLUMNS, BALL_VALUES
from tacgnn.real.controller import SHIPPED_POLICY


def blind_policy(folder: Path) -> Path:
    data = torch.load(SHIPPED_POLICY, weights_only=True)
    defaults = to_dict(BaodingConfig())
    for section in ("hand", "sim"):
        for key, value in defaults[section].items():
            data["env_config"][section].setdefault(key, value)
    path = Path(folder) / "blind_policy.pt"
    torch.save(data, path)
    return path


def with_ball_velocity(policy: Path, folder: Path) -> Path:
    """`policy` made into one that also observes the balls' velocities (`ball_velocity`): its
    first layer gets six more inputs, after the ball positions, with small random weights (so
    the velocities move its actions), and its normaliser passes them through unscaled."""
    data = torch.load(policy, weights_only=True)
    data["env_config"]["ball_velocity"] = True
    at, extra = BALL_COLUMNS.stop, BALL_VALUES
    actor = data["actor_state_dict"]
    generator = torch.Generator().manual_seed(0)
    for key, fill in (("obs_normalizer._mean", 0.0), ("obs_normalizer._var", 1.0), ("obs_normalizer._std", 1.0),
                      ("mlp.0.weight", None)):
        value = actor[key]
        inserted = (torch.full((value.shape[0], extra), fill) if fill is not None
                    else 0.05 * torch.randn(value.shape[0], extra, generator=generator))
        actor[key] = torch.cat([value[:, :at], inserted.to(value.dtype), value[:, at:]], dim=1)
    data["obs_dim"] += extra
    path = Path(folder) / "blind_velocity_policy.pt"
    torch.save(data, path)
    return path
