"""rsl_rl's PPO, refusing an update that would write NaN or Inf into the weights.

rsl_rl clips the gradient norm, but an infinite norm scales every gradient by
0 x inf = NaN, and Adam then writes NaN into all weights, which the next rollout would
act on and the next checkpoint would keep. `GuardedPPO` checks every gradient before the
optimiser steps (a step pre-hook, torch's documented extension point), and when one is
not finite, or a loss is not, or the update fails, puts models, optimiser and learning
rate back as they were before the update and raises `NonFiniteUpdate`.
"""

from __future__ import annotations

import copy
import math
from typing import Any

import torch
from rsl_rl.algorithms import PPO


class NonFiniteUpdate(FloatingPointError):
    """A PPO update met NaN or Inf; the weights are those from before it."""


class GuardedPPO(PPO):
    """`rsl_rl.algorithms.PPO` whose `update` is all or nothing: finite, or rolled back and raised."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._param_names = {id(p): f"{name} {n}" for name, model in (("actor", self._raw_actor),
                                                                     ("critic", self._raw_critic))
                             for n, p in model.named_parameters()}
        self._mini_batch = 0
        self.optimizer.register_step_pre_hook(self._refuse_non_finite_gradients)

    def _refuse_non_finite_gradients(self, optimizer: torch.optim.Optimizer, args: Any, kwargs: Any) -> None:
        """Step pre-hook: raise before Adam writes a gradient that is NaN or Inf (after clipping)."""
        self._mini_batch += 1
        params = [p for group in optimizer.param_groups for p in group["params"] if p.grad is not None]
        finite = (torch.stack([torch.isfinite(p.grad).all() for p in params]) if params
                  else torch.ones(0, dtype=torch.bool))
        if not bool(finite.all()):
            bad = [self._param_names.get(id(p), "?") for p, ok in zip(params, finite.tolist()) if not ok]
            raise NonFiniteUpdate(f"non-finite gradient in mini-batch {self._mini_batch} "
                                  f"({', '.join(bad[:6])}{', ...' if len(bad) > 6 else ''})")

    def update(self) -> dict[str, float]:
        """rsl_rl's update; on NaN or Inf in a gradient or a loss, undone and `NonFiniteUpdate` raised."""
        before = copy.deepcopy(self.save())
        self._mini_batch = 0
        try:
            losses = super().update()
        except NonFiniteUpdate as err:
            self._roll_back(before)
            raise NonFiniteUpdate(f"{err}; weights rolled back to before the update") from None
        except RuntimeError as err:  # e.g. torch refusing a NaN action std in a later mini-batch
            self._roll_back(before)
            raise NonFiniteUpdate(f"failed ({err}); weights rolled back to before the update") from err
        bad = [f"loss {k}" for k, v in losses.items() if not math.isfinite(float(v))]
        if bad:
            self._roll_back(before)
            raise NonFiniteUpdate(f"non-finite {', '.join(bad)}; weights rolled back to before the update")
        return losses

    def _roll_back(self, state: dict) -> None:
        self.load(state, load_cfg=None, strict=True)  # models, optimiser, learning rate
        self.storage.clear()
