"""A blind policy file for the real-hand tests, whatever policy the package ships.

The tests exercise the controller's plumbing, not a policy's skill: they take the shipped
blind policy's networks and, if it was trained on an older hand model that the loader
refuses, mark its config as this hand's, so the plumbing can be tested with it.
"""

from pathlib import Path

import torch

from tacgnn.config import to_dict
from tacgnn.envs.baoding import BaodingConfig
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
