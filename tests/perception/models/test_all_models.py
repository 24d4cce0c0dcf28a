"""Every model: shapes, gradients, blind-area frames, input checks, dtypes, joints, build_model."""

import math

import pytest
import torch

from tacgnn.perception.models import (
    MODEL_NAMES,
    PerceptionModelConfig,
    TacGNN,
    TactileCNN,
    TactileGCN,
    TactileMLP,
    build_model,
    reading_input,
)

T = 653


def make(name, rest, **kw):
    return build_model(PerceptionModelConfig(name=name, **kw), rest_positions=rest)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_output_shape_and_backward(name, rest, blobs):
    torch.manual_seed(0)
    model = make(name, rest, out_dim=5)
    readings, positions, _ = blobs(rest, 4, seed=1)
    y = model(readings, positions)
    assert y.shape == (4, 5) and torch.isfinite(y).all()
    y.square().sum().backward()
    grads = [p.grad for p in model.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_blind_area_frames_are_finite(name, rest):
    """Empty, one-taxel and two-taxel frames, mixed with a normal one and alone."""
    torch.manual_seed(0)
    model = make(name, rest)
    readings = torch.zeros(4, T)
    readings[1, 10] = 1.0
    readings[2, [3, 400]] = 0.5
    readings[3, :40] = 1.0
    positions = rest.expand(4, T, 3)
    y = model(readings, positions)
    assert y.shape == (4, 6) and torch.isfinite(y).all()
    y_empty = model(torch.zeros(2, T), positions[:2])
    assert torch.isfinite(y_empty).all()
    torch.testing.assert_close(y_empty[0], y[0])  # an empty frame does not depend on the batch
    y.sum().backward()


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_nan_readings_raise(name, rest, blobs):
    model = make(name, rest)
    readings, positions, _ = blobs(rest, 2, seed=2)
    readings[1, 7] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        model(readings, positions)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_inputs_take_the_models_dtype(name, rest, blobs):
    """float64 and strided inputs give the float32 model's output, in float32."""
    torch.manual_seed(0)
    model = make(name, rest).eval()
    readings, positions, _ = blobs(rest, 3, seed=4)
    with torch.no_grad():
        expected = model(readings, positions)
        y = model(readings.double().t().contiguous().t(), positions.double())
    assert y.dtype == torch.float32
    torch.testing.assert_close(y, expected)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_reset_parameters(name, rest):
    model = make(name, rest)
    weights = [p for p in model.parameters() if p.dim() > 1]  # biases may reset to 0
    before = [w.detach().clone() for w in weights]
    model.reset_parameters()
    assert all(not torch.equal(a, b) for a, b in zip(before, weights))


@pytest.mark.parametrize("name", ["tacgnn", "mlp"])
def test_joint_inputs(name, rest, blobs):
    """A model that reads the hand's joint angles needs them, uses them, and stays finite on empty frames."""
    torch.manual_seed(0)
    model = make(name, rest, joint_inputs=16)
    readings, positions, _ = blobs(rest, 4, seed=7)
    readings[0] = 0.0
    joints = torch.rand(4, 16)
    y = model(readings, positions, joints)
    assert y.shape == (4, 6) and torch.isfinite(y).all()
    assert not torch.allclose(model(readings, positions, joints + 0.5)[0], y[0])  # even a blind frame
    torch.testing.assert_close(model(readings, positions, joints.double()), y)
    with pytest.raises(ValueError, match="joint"):
        model(readings, positions)
    with pytest.raises(ValueError, match="joints"):
        model(readings, positions, joints[:, :3])
    with pytest.raises(ValueError, match="without joint inputs"):
        make(name, rest)(readings, positions, joints)


@pytest.mark.parametrize("name", ["mlp", "cnn", "gcn"])
def test_log1p_reading_feature_is_the_same_network_on_log1p_readings(name, rest, blobs):
    """reading_feature=log1p feeds log(1 + f / 0.01 N) to the unchanged network: a force scaled by a
    constant moves the input of the taxels a contact presses hard by nearly the same shift."""
    torch.manual_seed(0)
    raw = make(name, rest)
    log = make(name, rest, reading_feature="log1p")
    log.load_state_dict(raw.state_dict())
    readings, positions, _ = blobs(rest, 3, seed=8)
    with torch.no_grad():
        expected = raw(torch.log1p(readings / 0.01), positions)
        assert torch.allclose(log(readings, positions), expected, atol=1e-5)
        assert not torch.allclose(raw(readings, positions), expected)
    strong = readings[readings > 0.2]
    assert strong.numel() > 10
    shift = reading_input(1.7 * strong, "log1p") - reading_input(strong, "log1p")
    assert torch.allclose(shift, torch.full_like(shift, math.log(1.7)), atol=0.04)
    assert reading_input(torch.zeros(4), "log1p").eq(0).all()  # nothing pressed reads 0, as in raw


def test_build_model_takes_a_config(rest):
    classes = {"tacgnn": TacGNN, "mlp": TactileMLP, "cnn": TactileCNN, "gcn": TactileGCN}
    for name, cls in classes.items():
        assert type(build_model(PerceptionModelConfig(name=name), rest_positions=rest)) is cls
    with pytest.raises(TypeError, match="PerceptionModelConfig"):
        build_model("mlp")
    with pytest.raises(ValueError, match="rest_positions"):
        build_model(PerceptionModelConfig(name="gcn"))
    with pytest.raises(ValueError, match="rest_positions"):
        build_model(PerceptionModelConfig(name="gcn"), rest_positions=rest[:10])
