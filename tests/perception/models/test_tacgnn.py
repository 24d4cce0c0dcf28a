"""TacGNN: blind-area frames, order and dtype invariance, graph paths, readouts, learning."""

import pytest
import torch
import torch.nn.functional as F

from tacgnn.perception import graph_numba
from tacgnn.perception.models import PerceptionModelConfig, TacGNN, build_model

T = 653


def make(**kw):
    return build_model(PerceptionModelConfig(**kw))


@pytest.fixture(scope="module")
def real_frames(dataset):
    """64 touched frames of the simulated hand: regular taxel grids, where kNN distances tie."""
    from tacgnn.perception.data import load_tactile

    data = load_tactile(dataset, "baoding")
    touched = (data.readings > 0).any(1)
    return data.readings[touched][:64], data.positions[touched][:64]


def test_empty_frame_is_head_of_zero(rest):
    model = make()
    y = model(torch.zeros(1, T), rest.unsqueeze(0))
    torch.testing.assert_close(y, model.head(torch.zeros(1, 32)))


def test_single_taxel_sees_its_position(rest):
    """A lone taxel is its own neighbour, so the output depends on where it is."""
    torch.manual_seed(0)
    model = make()
    readings = torch.zeros(2, T)
    readings[0, 5] = readings[1, 600] = 1.0
    y = model(readings, rest.expand(2, T, 3))
    assert not torch.allclose(y[0], y[1])


def test_bad_shapes_and_nan_positions_raise(rest, blobs):
    model = make()
    readings, positions, _ = blobs(rest, 2, seed=2)
    with pytest.raises(ValueError, match="readings"):
        model(readings[:, :10], positions)
    with pytest.raises(ValueError, match="positions"):
        model(readings, positions[:, :10])
    active = int(readings[0].nonzero()[0])
    positions = positions.clone()
    positions[0, active, 1] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        model(readings, positions)


@pytest.mark.parametrize(
    "kw",
    [
        dict(),  # defaults: FPS after every layer, centroid start, compiled graphs
        dict(use_force=True, force_feature="log", pool="jk"),  # offline training's defaults
        dict(exact_graph=True),
        dict(downsample_layers=(0, 1), k=(6, 4, 3), use_force=True, fps_start="first"),
        dict(downsample_layers=(), self_loop=True),
    ],
)
@pytest.mark.parametrize("compiled", [True, False])
def test_taxel_order_does_not_change_the_output_on_real_frames(real_frames, kw, compiled):
    """Listing the taxels in another order (readings and positions alike) leaves the output as
    it was, on frames where many neighbours lie at exactly the same distance."""
    torch.manual_seed(0)
    model = make(**kw).eval()
    model.use_compiled_graphs = compiled
    readings, positions = real_frames
    with torch.no_grad():
        y = model(readings, positions)
        for seed in range(2):
            perm = torch.randperm(T, generator=torch.Generator().manual_seed(seed))
            torch.testing.assert_close(model(readings[:, perm], positions[:, perm]), y, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("kw", [dict(use_force=True, force_feature="log", pool="jk"),
                                dict(downsample_layers=(0, 1), k=(6, 4, 3), use_force=True, fps_start="first")])
def test_one_frame_on_the_serial_kernels_gives_the_parallel_kernels_output(real_frames, kw, monkeypatch):
    """A frame on its own (a control tick) runs serially compiled graph kernels: the same output, bit for bit."""
    if not graph_numba.available():
        pytest.skip("numba is not installed")
    torch.manual_seed(0)
    model = make(**kw).eval()
    readings, positions = real_frames
    with torch.no_grad():
        serial = [model(readings[i:i + 1], positions[i:i + 1]) for i in range(0, 64, 4)]
        monkeypatch.setattr(graph_numba, "_kernels_for", lambda num_graphs: graph_numba._compile(parallel=True))
        parallel = [model(readings[i:i + 1], positions[i:i + 1]) for i in range(0, 64, 4)]
    for i, (a, b) in enumerate(zip(serial, parallel)):
        assert torch.equal(a, b), f"frame {4 * i}"


def test_taxel_order_does_not_change_the_output_on_the_rest_grid(skin_rest, blobs):
    """The skin's grids at rest, untouched by the rounding of a hand pose: exact ties everywhere."""
    torch.manual_seed(0)
    model = make(use_force=True, force_feature="log", pool="jk").eval()
    readings, _, _ = blobs(skin_rest, 32, seed=3, sizes=(3, 60))
    positions = skin_rest.expand(32, T, 3)
    perm = torch.randperm(T, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        torch.testing.assert_close(model(readings[:, perm], positions[:, perm]), model(readings, positions),
                                   atol=1e-5, rtol=1e-5)


def test_float64_and_non_contiguous_inputs(real_frames):
    """Inputs are cast to the model's dtype: a float64 batch, or a strided view of one, gives the
    float32 model's float32 output."""
    torch.manual_seed(0)
    model = make(use_force=True, force_feature="log", pool="jk").eval()
    readings, positions = real_frames
    with torch.no_grad():
        expected = model(readings, positions)
        y64 = model(readings.double(), positions.double())
        strided_r = readings.t().contiguous().t()  # (B, T) with column-major strides
        strided_p = positions.permute(2, 0, 1).contiguous().permute(1, 2, 0)
        assert not strided_r.is_contiguous() and not strided_p.is_contiguous()
        y_strided = model(strided_r, strided_p)
        every_other = model(torch.stack([readings, readings], 2)[..., 0], positions)  # a sliced view
    assert y64.dtype == torch.float32
    torch.testing.assert_close(y64, expected)
    torch.testing.assert_close(y_strided, expected)
    torch.testing.assert_close(every_other, expected)


def test_double_precision_model(rest, blobs):
    """A float64 model runs the exact torch graphs (the int32 keys and numba need float32)."""
    torch.manual_seed(0)
    model = make().double()
    readings, positions, _ = blobs(rest, 4, seed=14)
    y = model(readings, positions)
    assert y.dtype == torch.float64 and torch.isfinite(y).all()


def test_fast_graph_path_matches_exact(rest, blobs):
    torch.manual_seed(0)
    fast = make(k=(6, 4, 3))
    exact = make(k=(6, 4, 3), exact_graph=True)
    exact.load_state_dict(fast.state_dict())
    readings, positions, _ = blobs(rest, 16, seed=4, sizes=(1, 80))
    with torch.no_grad():
        torch.testing.assert_close(fast(readings, positions), exact(readings, positions), atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("kw", [{}, {"use_force": True, "force_feature": "log", "pool": "jk", "residual": True},
                                {"k": (6, 4, 3), "downsample_layers": (0, 2), "fps_start": "first"}])
def test_compiled_graphs_match_the_torch_graphs(rest, blobs, kw):
    """The numba graph builder gives the network the same graphs as the torch one: same output,
    same gradients, also with blind and one-taxel frames and graphs smaller than k."""
    if not graph_numba.available():
        pytest.skip("numba is not installed")
    torch.manual_seed(0)
    model = make(**kw)
    readings, positions, _ = blobs(rest, 24, seed=5, sizes=(1, 40))
    readings[3] = 0.0  # blind frame
    outputs, grads = [], []
    for compiled in (True, False):
        model.use_compiled_graphs = compiled
        model.zero_grad()
        y = model(readings, positions)
        y.square().sum().backward()
        outputs.append(y.detach())
        grads.append(torch.cat([p.grad.flatten() for p in model.parameters() if p.grad is not None]))
    torch.testing.assert_close(outputs[0], outputs[1], rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(grads[0], grads[1], rtol=1e-4, atol=1e-5)


def test_forward_pyg_matches_forward(rest, blobs):
    from torch_geometric.data import Batch, Data

    torch.manual_seed(0)
    model = make(use_force=True)
    readings, positions, _ = blobs(rest, 3, seed=6)
    readings[1] = 0.0  # an empty graph in the middle
    graphs = [Data(pos=positions[i][readings[i] > 0], x=readings[i][readings[i] > 0]) for i in range(3)]
    with torch.no_grad():
        expected = model(readings, positions)
        torch.testing.assert_close(model.forward_pyg(Batch.from_data_list(graphs)), expected)
        torch.testing.assert_close(model.forward_pyg(graphs[0]), model(readings[:1], positions[:1]))


@pytest.mark.parametrize("pool", ["last", "all", "jk", "sum"])
@pytest.mark.parametrize("extra", [dict(), dict(use_force=True, force_feature="log", residual=True, message_layers=3)])
def test_readouts_are_blind_safe(rest, blobs, pool, extra):
    """Every readout gives finite outputs on empty and barely pressed frames."""
    torch.manual_seed(0)
    model = make(pool=pool, **extra)
    readings, positions, _ = blobs(rest, 6, seed=5)
    readings[0] = 0.0
    readings[1] = 0.0
    readings[1, 17] = 1e-9  # a barely-pressed taxel: log force must stay finite
    with torch.no_grad():
        y = model(readings, positions)
    assert y.shape == (6, 6) and torch.isfinite(y).all()
    # an empty frame reads the head at a zero pooled feature, whatever the readout
    torch.testing.assert_close(y[0], model.head(torch.zeros(model.head[0].in_features)))


def test_readout_widths():
    """'all' concatenates the L pooled layers; 'jk' maps them back to C; 'last' is the paper's C."""
    assert make(pool="last").head[0].in_features == 32
    assert make(pool="all").head[0].in_features == 96
    jk = make(pool="jk")
    assert jk.head[0].in_features == 32 and jk.jk.in_features == 96 and jk.jk.bias is None
    assert len(make(head_layers=3).head) == 5  # Linear ReLU Linear ReLU Linear


def test_log_force_feature_changes_the_input(rest, blobs):
    """The same weights read log(f) instead of f: different outputs, both finite."""
    torch.manual_seed(0)
    raw = make(use_force=True, force_feature="raw")
    log = make(use_force=True, force_feature="log")
    log.load_state_dict(raw.state_dict())
    readings, positions, _ = blobs(rest, 3, seed=6)
    with torch.no_grad():
        a, b = raw(readings, positions), log(readings, positions)
    assert torch.isfinite(b).all() and not torch.allclose(a, b)


def test_built_from_its_config():
    cfg = PerceptionModelConfig(channels=16, k=(4, 3), downsample_layers=(0,))
    model = TacGNN(cfg)
    assert model.cfg is cfg and len(model.convs) == 2 and model.convs[1].in_channels == 16


def test_learns_blob_centroid(rest, blobs):
    """TacGNN-32 learns 'centroid of the touched taxels' in 300 Adam steps."""
    torch.manual_seed(0)
    train = blobs(rest, 4096, seed=10)
    test = blobs(rest, 512, seed=11)
    model = make(out_dim=3)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)

    def test_loss():
        with torch.no_grad():
            return F.mse_loss(model(test[0], test[1]), test[2]).item()

    initial = test_loss()
    g = torch.Generator().manual_seed(12)
    for _ in range(300):
        idx = torch.randint(0, 4096, (64,), generator=g)
        loss = F.mse_loss(model(train[0][idx], train[1][idx]), train[2][idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
    final = test_loss()
    mean_predictor = F.mse_loss(train[2].mean(0).expand_as(test[2]), test[2]).item()
    assert final < initial / 5, (initial, final)
    assert final < mean_predictor / 5, (mean_predictor, final)
