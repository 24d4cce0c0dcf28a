"""Temporal perception: a recurrent state over a per-frame encoder, for the tactile blind area.

A ball that touches no taxel leaves no trace in the frame; where it is follows from where
it was last felt and how the hand moved since. The model keeps its running estimate of the
balls and a GRU state, fed every step with what a real hand has: the frame's skin features
(from a single-frame model, e.g. TacGNN or the MLP), the joint angles and the previous action.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

from tacgnn.config import check
from tacgnn.perception.models.base import PerceptionModel, mlp
from tacgnn.perception.models.build import build_model
from tacgnn.perception.models.config import PerceptionModelConfig

#: Frame encoders a temporal model can use (the GCN needs fixed rest positions; not wired here).
FRAME_MODELS = ("tacgnn", "mlp", "cnn")


def _check_width(owner: str, key: str, value: object, least: int) -> None:
    check(isinstance(value, int) and not isinstance(value, bool) and value >= least, f"{owner}.{key}",
          f"must be an int >= {least}, got {value!r}")


@dataclass(frozen=True)
class MemoryConfig:
    """The recurrent part of a temporal model, as training configs hold it beside the frame model."""

    feature: int = 64
    """Width of the per-frame feature the encoder gives the GRU."""
    hidden: int = 128
    """Width of the GRU state."""
    joints: int = 16
    """Joint angles (rad) read every frame; 0 = none."""
    actions: int = 16
    """Previous actions (the step's command, [-1, 1]) read every frame; 0 = none."""

    def __post_init__(self) -> None:
        for key, least in (("feature", 1), ("hidden", 1), ("joints", 0), ("actions", 0)):
            _check_width("memory", key, getattr(self, key), least)


@dataclass(frozen=True)
class TemporalModelConfig:
    """A per-frame model (its ``out_dim`` replaced by `feature`) under a GRU of width `hidden`."""

    frame: PerceptionModelConfig = field(default_factory=PerceptionModelConfig)
    """The per-frame encoder: one of FRAME_MODELS, without joint inputs (the GRU reads the joints)."""
    feature: int = 64
    """Width of the per-frame feature the encoder gives the GRU."""
    hidden: int = 128
    """Width of the GRU state."""
    joints: int = 16
    """Joint angles (rad) read every frame; 0 = none."""
    actions: int = 16
    """Previous actions (the step's command, [-1, 1]) read every frame; 0 = none."""
    out_dim: int = 6

    def __post_init__(self) -> None:
        check(isinstance(self.frame, PerceptionModelConfig), "model.frame", "must be a perception model config")
        check(self.frame.name in FRAME_MODELS, "model.frame.name",
              f"a temporal model's frame encoder must be one of {FRAME_MODELS}, got {self.frame.name!r}")
        check(self.frame.joint_inputs == 0, "model.frame.joint_inputs",
              "must be 0: the temporal model feeds the joint angles to its GRU (model.joints)")
        check(self.out_dim == 6, "model.out_dim", f"a temporal model tracks two balls (6 values), got {self.out_dim}")
        for key, least in (("feature", 1), ("hidden", 1), ("joints", 0), ("actions", 0)):
            _check_width("model", key, getattr(self, key), least)

    @classmethod
    def of(cls, frame: PerceptionModelConfig, memory: MemoryConfig) -> TemporalModelConfig:
        """The temporal model of a frame model and a memory (the training configs' two parts)."""
        return cls(frame=frame, feature=memory.feature, hidden=memory.hidden, joints=memory.joints,
                   actions=memory.actions)


class TemporalPerception(nn.Module):
    r"""A learned filter over a per-frame encoder: a GRU decides, ball by ball, how far to trust
    the frame and how the last estimate moves.

    Every step :math:`t`, with :math:`e` a single-frame model (TacGNN, MLP or CNN) with a
    `feature`-wide output, :math:`x_t` the frame's readings and taxel positions,
    :math:`q_t` the joint angles and :math:`a_t` the action commanded in the step that
    led to the frame:

    .. math::
        f_t &= e(x_t), \qquad \hat y_t = \mathrm{MLP}(f_t)
            \quad\text{(the frame's own estimate, balls ordered as in } y_{t-1})\\
        s_t &= \mathrm{GRU}(s_{t-1}, [f_t, q_t, a_t, y_{t-1} - y_0])\\
        g_t &= \sigma(W_g [s_t, f_t]) \quad\text{(one gate per ball)}, \qquad
            d_t = W_d [s_t, f_t]\\
        y_t &= g_t \odot \hat y_t + (1 - g_t) \odot (y_{t-1} + d_t)

    with :math:`s_0 = 0` and :math:`y_0` a learned start (the mean ball positions) at an
    episode's start. A ball the skin touches is placed from the frame (:math:`g \to 1`);
    one in the blind area keeps its last estimate, moved by what the GRU makes of the
    hand's motion. A plain GRU has to learn to hold a position in centimetres in a state
    bounded by 1; the gate makes holding the default. With TacGNN as :math:`e` the output
    does not depend on the order of the taxels. The state is ``[s_t, y_t]``.

    Args:
        cfg: the model's :class:`TemporalModelConfig`.

    Shapes:
        - **step:** ``readings (B, T)``, ``positions (B, T, 3)``, ``joints (B, J)``,
          ``actions (B, A)``, ``state (B, hidden + 6)`` -> ``(B, 6)``, ``(B, hidden + 6)``
        - **forward:** the same with a time axis after the batch axis, ``valid (B, L)``
          -> ``(B, L, 6)``, ``(B, hidden + 6)``
    """

    def __init__(self, cfg: TemporalModelConfig | None = None) -> None:
        super().__init__()
        cfg = cfg or TemporalModelConfig()
        self.cfg = cfg
        self.encoder: PerceptionModel = build_model(dataclasses.replace(cfg.frame, out_dim=cfg.feature))
        self.num_taxels, self.out_dim = cfg.frame.num_taxels, cfg.out_dim
        self.state_dim = cfg.hidden + cfg.out_dim
        self.frame_head = mlp([cfg.feature, cfg.feature, cfg.out_dim])
        self.gru = nn.GRUCell(cfg.feature + cfg.joints + cfg.actions + cfg.out_dim, cfg.hidden)
        self.gate = nn.Linear(cfg.hidden + cfg.feature, cfg.out_dim // 3)
        self.delta = nn.Linear(cfg.hidden + cfg.feature, cfg.out_dim)
        self.y0 = nn.Parameter(torch.zeros(cfg.out_dim))
        with torch.no_grad():
            self.gate.bias.fill_(2.0)  # start by trusting the frame, as a single-frame model does
            self.delta.weight.mul_(0.1)
            self.delta.bias.zero_()

    @property
    def dtype(self) -> torch.dtype:
        return self.y0.dtype

    def init_output(self, mean: Tensor) -> None:
        """Start the frame's estimate and the episode's first estimate at the mean label (cm)."""
        with torch.no_grad():
            self.frame_head[-1].get_parameter("bias").copy_(mean)
            self.y0.copy_(mean)

    def initial_state(self, batch: int) -> Tensor:
        """The state at an episode's start: GRU state 0, estimate y0; (batch, hidden + 6)."""
        state = torch.zeros(batch, self.state_dim, dtype=self.dtype, device=self.y0.device)
        state[:, self.cfg.hidden:] = self.y0.detach()
        return state

    def _side_inputs(self, joints: Tensor | None, actions: Tensor | None, batch: tuple[int, ...]) -> list[Tensor]:
        out = []
        for name, value, width in (("joints", joints, self.cfg.joints), ("actions", actions, self.cfg.actions)):
            if width == 0:
                if value is not None:
                    raise ValueError(f"this temporal model reads no {name} ({name}=0) but was given them")
                continue
            if value is None:
                raise ValueError(f"this temporal model reads {width} {name} per frame: pass {name} {(*batch, width)}")
            if tuple(value.shape) != (*batch, width):
                raise ValueError(f"{name} must be {(*batch, width)}, got {tuple(value.shape)}")
            value = value.to(self.dtype)
            if not torch.isfinite(value.sum()):
                raise ValueError(f"{name} contain NaN or inf")
            out.append(value)
        return out

    def _check_state(self, state: Tensor, B: int) -> Tensor:
        if tuple(state.shape) != (B, self.state_dim):
            raise ValueError(f"state must be ({B}, {self.state_dim}) (hidden {self.cfg.hidden} + "
                             f"{self.out_dim} ball values), got {tuple(state.shape)}")
        return state.to(self.dtype)

    def _recur(self, feature: Tensor, side: list[Tensor], state: Tensor) -> tuple[Tensor, Tensor]:
        """One filter step from the frame's feature; returns the estimate and the next state."""
        H = self.cfg.hidden
        h, y = state[:, :H], state[:, H:]
        estimate = align_balls(self.frame_head(feature), y)
        h = self.gru(torch.cat([feature, *side, y - self.y0], 1), h)
        z = torch.cat([h, feature], 1)
        gate = torch.sigmoid(self.gate(z)).repeat_interleave(3, 1)
        y = gate * estimate + (1 - gate) * (y + self.delta(z))
        return y, torch.cat([h, y], 1)

    def step(self, readings: Tensor, positions: Tensor, joints: Tensor | None, actions: Tensor | None,
             state: Tensor) -> tuple[Tensor, Tensor]:
        """One frame of every sequence in the batch: the outputs and the next state."""
        B = readings.shape[0]
        state = self._check_state(state, B)
        side = self._side_inputs(joints, actions, (B,))
        return self._recur(self.encoder(readings, positions), side, state)

    def forward(self, readings: Tensor, positions: Tensor, joints: Tensor | None = None,
                actions: Tensor | None = None, state: Tensor | None = None,
                valid: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Whole windows: the encoder on every valid frame at once, then the filter frame by frame.

        Frames where ``valid`` is False (padding before an episode's first frame or after its
        last) leave the state as it is and output 0.
        """
        if readings.dim() != 3:
            raise ValueError(f"readings must be (B, L, T), got {tuple(readings.shape)}")
        B, L, T = readings.shape
        if tuple(positions.shape) != (B, L, T, 3):
            raise ValueError(f"positions must be {(B, L, T, 3)}, got {tuple(positions.shape)}")
        side = self._side_inputs(joints, actions, (B, L))
        if valid is None:
            valid = torch.ones(B, L, dtype=torch.bool, device=readings.device)
        elif tuple(valid.shape) != (B, L):
            raise ValueError(f"valid must be {(B, L)}, got {tuple(valid.shape)}")
        rows = valid.reshape(-1).nonzero().squeeze(1)
        feature = self.encoder(readings.reshape(B * L, T).index_select(0, rows),
                               positions.reshape(B * L, T, 3).index_select(0, rows))
        features = feature.new_zeros(B * L, self.cfg.feature).index_copy(0, rows, feature).view(B, L, -1)
        state = self.initial_state(B) if state is None else self._check_state(state, B)
        outputs = []
        for t in range(L):
            y, new_state = self._recur(features[:, t], [s[:, t] for s in side], state)
            keep = valid[:, t, None]
            state = torch.where(keep, new_state, state)
            outputs.append(y * keep)
        return torch.stack(outputs, 1), state


def align_balls(pred: Tensor, previous: Tensor) -> Tensor:
    """(B, 6) ball pairs, swapped where that puts each ball nearer its previous estimate.

    The two balls look alike to the skin; the frame's estimate may list them in either
    order, the filter needs them in the order of its running estimate. A tie (e.g. a previous
    estimate with both balls at one point) keeps the order: rounding, which differs with the
    batch's size, must not decide it.
    """
    swapped = pred[:, [3, 4, 5, 0, 1, 2]]
    straight = ((pred - previous) ** 2).sum(1)
    swap = ((swapped - previous) ** 2).sum(1) < straight - 1e-5 * (1.0 + straight)
    return torch.where(swap[:, None], swapped, pred)


__all__ = ["FRAME_MODELS", "MemoryConfig", "TemporalModelConfig", "TemporalPerception", "align_balls"]
