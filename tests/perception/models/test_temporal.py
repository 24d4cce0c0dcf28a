"""The temporal model: step by step equals whole windows, the state carries what the frame lacks,
the output ignores the taxel order, bad inputs are named."""

import dataclasses

import pytest
import torch

from tacgnn.config import ConfigError
from tacgnn.perception.models.config import PerceptionModelConfig
from tacgnn.perception.models.temporal import TemporalModelConfig, TemporalPerception
from tacgnn.perception.objectives import Objective
from tacgnn.perception.sequences import split_by_episode, window_starts
from tests.perception.sequence_helpers import T, episodes, to_sequence_data


def small(name="tacgnn", **kw):
    frame = PerceptionModelConfig(name=name, num_taxels=T, channels=16, use_force=True, force_feature="log",
                                  pool="jk", mlp_hidden=(64,))
    return TemporalModelConfig(frame=frame, feature=32, hidden=32, **kw)


def model_of(cfg):
    """A temporal model whose start estimate has two distinct balls (as after training: at y0 = 0
    both ball orders tie, and rounding would pick one)."""
    model = TemporalPerception(cfg)
    model.init_output(torch.tensor([3.0, 4.0, 1.0, 10.0, 4.0, 1.0]))
    return model


def inputs(B, L, seed=0):
    g = torch.Generator().manual_seed(seed)
    readings = (torch.rand(B, L, T, generator=g) > 0.9) * torch.rand(B, L, T, generator=g)
    positions = torch.rand(B, L, T, 3, generator=g) * 10
    return readings, positions, torch.randn(B, L, 16, generator=g), torch.rand(B, L, 16, generator=g) * 2 - 1


@pytest.mark.parametrize("name", ["tacgnn", "mlp", "cnn"])
def test_step_by_step_equals_windows_and_padding_holds_the_state(name):
    torch.manual_seed(0)
    model = model_of(small(name)).eval()
    r, p, j, a = inputs(3, 6)
    with torch.no_grad():
        out, last = model(r, p, j, a)
        state = model.initial_state(3)
        for t in range(6):
            o, state = model.step(r[:, t], p[:, t], j[:, t], a[:, t], state)
            assert torch.allclose(o, out[:, t], atol=1e-5)
        assert torch.allclose(state, last, atol=1e-5)
        # two padded frames before row 1's first frame: its state starts fresh at frame 2
        valid = torch.ones(3, 6, dtype=torch.bool)
        valid[1, :2] = False
        padded, _ = model(r, p, j, a, valid=valid)
        alone, _ = model(r[1:2, 2:], p[1:2, 2:], j[1:2, 2:], a[1:2, 2:])
    assert torch.allclose(padded[1, 2:], alone[0], atol=1e-5) and (padded[1, :2] == 0).all()
    assert torch.allclose(padded[0], out[0], atol=1e-5)


def test_output_does_not_depend_on_the_taxel_order():
    torch.manual_seed(0)
    model = model_of(small("tacgnn")).eval()
    r, p, j, a = inputs(2, 5, seed=1)
    perm = torch.randperm(T, generator=torch.Generator().manual_seed(7))
    with torch.no_grad():
        out, state = model(r, p, j, a)
        shuffled, state2 = model(r[:, :, perm], p[:, :, perm], j, a)
    assert torch.allclose(out, shuffled, atol=1e-5) and torch.allclose(state, state2, atol=1e-5)


def test_the_state_carries_balls_through_frames_without_contact():
    """On episodes where untouched balls stand still, the filter over the MLP's features places
    untouched balls far better than the same MLP reading one frame (same steps, same data)."""
    from tacgnn.perception.evaluation import ball_errors
    from tacgnn.perception.models.build import build_model
    from tacgnn.perception.training import init_output_bias

    data = to_sequence_data(episodes(40, 24, seed=2, blind=0.4))
    train, test = split_by_episode(data, 0.8, seed=0)
    objective = Objective("baoding")
    untouched = {}
    for temporal in (False, True):
        torch.manual_seed(0)
        cfg = small("mlp")
        model = TemporalPerception(cfg) if temporal else build_model(dataclasses.replace(cfg.frame, out_dim=6))
        init_output_bias(model, train.frames.targets.mean(0))
        optim = torch.optim.Adam(model.parameters(), lr=3e-3)
        starts = window_starts(train, 12)
        g = torch.Generator().manual_seed(0)
        f = train.frames
        for _ in range(800):
            rows = starts[torch.randint(len(starts), (8,), generator=g)].unsqueeze(1) + torch.arange(12)
            if temporal:
                pred, _ = model(f.readings[rows], f.positions[rows], f.joints[rows], train.actions[rows])
            else:
                pred = model(f.readings[rows].flatten(0, 1), f.positions[rows].flatten(0, 1))
            loss = objective.loss(pred.reshape(-1, 6), f.targets[rows].reshape(-1, 6))
            optim.zero_grad()
            loss.backward()
            optim.step()
        with torch.no_grad():  # whole test episodes (24 frames each) from a fresh state
            t = test.frames
            rows = window_starts(test, 24).unsqueeze(1) + torch.arange(24)
            if temporal:
                pred, _ = model(t.readings[rows], t.positions[rows], t.joints[rows], test.actions[rows])
            else:
                pred = model(t.readings[rows].flatten(0, 1), t.positions[rows].flatten(0, 1))
        se, touch, _ = ball_errors(pred.reshape(-1, 6), test.subset(rows.reshape(-1)).frames)
        assert 0.2 < float((~touch).float().mean()) < 0.8  # both kinds of balls are there
        untouched[temporal] = float(se[~touch].mean().sqrt())
    assert untouched[True] < 0.8 * untouched[False], untouched


def test_bad_inputs_and_configs_are_named():
    model = TemporalPerception(small("mlp"))
    r, p, j, a = inputs(2, 3)
    with pytest.raises(ValueError, match="reads 16 joints"):
        model(r, p, None, a)
    with pytest.raises(ValueError, match=r"actions must be \(2, 3, 16\)"):
        model(r, p, j, a[:, :2])
    with pytest.raises(ValueError, match="state must be"):
        model.step(r[:, 0], p[:, 0], j[:, 0], a[:, 0], torch.zeros(2, 5))
    no_joints = TemporalPerception(dataclasses.replace(small("mlp"), joints=0))
    with pytest.raises(ValueError, match="reads no joints"):
        no_joints(r, p, j, a)
    with pytest.raises(ConfigError, match="model.frame.name"):
        TemporalModelConfig(frame=PerceptionModelConfig(name="gcn"))
    with pytest.raises(ConfigError, match="model.frame.joint_inputs"):
        TemporalModelConfig(frame=PerceptionModelConfig(name="mlp", joint_inputs=16))
    with pytest.raises(ConfigError, match="model.hidden"):
        TemporalModelConfig(hidden=0)
