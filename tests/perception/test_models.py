"""Perception models: shapes, invariances, blind-area frames, input checks, config, learning."""

import dataclasses
import math

import pytest
import torch
import torch.nn.functional as F

from tacgnn.perception import graph_numba
from tacgnn.perception.graph_ops import dense_fps, to_dense
from tacgnn.perception.models import (
    MODEL_NAMES,
    PerceptionModelConfig,
    TacGNN,
    TactileCNN,
    TactileGCN,
    build_model,
    reading_input,
)

T = 653


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """The test machine's 2 cores are shared: 2 busy threads would wait on each other."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def rest():
    """A fixed random taxel cloud in a 10 x 6 x 3 cm box."""
    return torch.rand(T, 3, generator=torch.Generator().manual_seed(0)) * torch.tensor([10.0, 6.0, 3.0])


def blob_frames(rest, n, seed, sizes=(5, 31)):
    """n frames, each touching the taxels nearest to a random taxel; target = their centroid.

    The whole hand is shifted by a random offset per frame (positions move).
    """
    g = torch.Generator().manual_seed(seed)
    centre = torch.randint(0, T, (n,), generator=g)
    size = torch.randint(*sizes, (n,), generator=g)
    order = torch.cdist(rest, rest)[centre].argsort(1)
    hit = (torch.arange(T) < size.unsqueeze(1)).float()
    w = torch.zeros(n, T).scatter_(1, order, hit)
    readings = w * (torch.rand(n, T, generator=g) + 0.1)
    offset = torch.randn(n, 1, 3, generator=g)
    target = (w @ rest) / size.unsqueeze(1) + offset[:, 0]
    return readings, rest + offset, target


def make(name, rest, **kw):
    return build_model(PerceptionModelConfig(name=name, **kw), rest_positions=rest)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_output_shape_and_backward(name, rest):
    torch.manual_seed(0)
    model = make(name, rest, out_dim=5)
    readings, positions, _ = blob_frames(rest, 4, seed=1)
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


def test_tacgnn_empty_frame_is_head_of_zero(rest):
    model = make("tacgnn", rest)
    y = model(torch.zeros(1, T), rest.unsqueeze(0))
    torch.testing.assert_close(y, model.head(torch.zeros(1, 32)))


def test_tacgnn_single_taxel_sees_its_position(rest):
    """A lone taxel is its own neighbour, so the output depends on where it is."""
    torch.manual_seed(0)
    model = make("tacgnn", rest)
    readings = torch.zeros(2, T)
    readings[0, 5] = readings[1, 600] = 1.0
    y = model(readings, rest.expand(2, T, 3))
    assert not torch.allclose(y[0], y[1])


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_nan_readings_raise(name, rest):
    model = make(name, rest)
    readings, positions, _ = blob_frames(rest, 2, seed=2)
    readings[1, 7] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        model(readings, positions)


def test_bad_shapes_and_nan_positions_raise(rest):
    model = make("tacgnn", rest)
    readings, positions, _ = blob_frames(rest, 2, seed=2)
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
        dict(),  # defaults: FPS after every layer, centroid start, fast graph path
        dict(exact_graph=True),
        dict(downsample_layers=(0, 1), k=(6, 4, 3), use_force=True),
        dict(downsample_layers=(), self_loop=True),
    ],
)
def test_tacgnn_permutation_invariance(rest, kw):
    """Reordering the taxels (readings and positions alike) does not change the output."""
    torch.manual_seed(0)
    model = make("tacgnn", rest, **kw)
    readings, positions, _ = blob_frames(rest, 8, seed=3)
    perm = torch.randperm(T)
    with torch.no_grad():
        y = model(readings, positions)
        y_perm = model(readings[:, perm], positions[:, perm])
    torch.testing.assert_close(y_perm, y, atol=1e-5, rtol=1e-5)


def test_fast_graph_path_matches_exact(rest):
    torch.manual_seed(0)
    fast = make("tacgnn", rest, k=(6, 4, 3))
    exact = make("tacgnn", rest, k=(6, 4, 3), exact_graph=True)
    exact.load_state_dict(fast.state_dict())
    readings, positions, _ = blob_frames(rest, 16, seed=4, sizes=(1, 80))
    with torch.no_grad():
        expected = exact(readings, positions)
        torch.testing.assert_close(fast(readings, positions), expected, atol=1e-5, rtol=1e-5)


def test_hierarchical_fps_is_a_prefix(rest):
    """The model samples once and keeps prefixes; that equals FPS rerun on each level."""
    readings, positions, _ = blob_frames(rest, 6, seed=5, sizes=(1, 60))
    b, t = (readings > 0).nonzero(as_tuple=True)
    pos, mask = to_dense(positions[b, t], b, batch_size=6)
    idx, keep = dense_fps(pos, mask, 0.5, start="centroid")
    level = pos.gather(1, idx.unsqueeze(-1).expand(-1, -1, 3))
    for _ in range(2):
        idx2, keep2 = dense_fps(level, keep, 0.5, start="first")
        M = idx2.shape[1]
        assert torch.equal(idx2[keep2], torch.arange(M).expand_as(idx2)[keep2])
        level, keep = level[:, :M], keep2


def test_forward_pyg_matches_forward(rest):
    from torch_geometric.data import Batch, Data

    torch.manual_seed(0)
    model = make("tacgnn", rest, use_force=True)
    readings, positions, _ = blob_frames(rest, 3, seed=6)
    readings[1] = 0.0  # an empty graph in the middle
    graphs = [Data(pos=positions[i][readings[i] > 0], x=readings[i][readings[i] > 0]) for i in range(3)]
    with torch.no_grad():
        expected = model(readings, positions)
        torch.testing.assert_close(model.forward_pyg(Batch.from_data_list(graphs)), expected)
        torch.testing.assert_close(model.forward_pyg(graphs[0]), model(readings[:1], positions[:1]))


def test_gcn_matches_pyg_gcnconv_with_normalisation(rest):
    """The precomputed normalised adjacency equals GCNConv(normalize=True) on a batched graph,
    outputs and gradients (the model's backward pass reuses the symmetric adjacency)."""
    from torch_geometric.nn import GCNConv
    from torch_geometric.utils import to_undirected

    from tacgnn.perception.graph_ops import knn_graph

    torch.manual_seed(0)
    model = make("gcn", rest)
    readings, positions, _ = blob_frames(rest, 3, seed=7)
    edge_index = to_undirected(knn_graph(rest, k=6), num_nodes=T)
    assert edge_index.shape[1] >= 6 * T
    batched = torch.cat([edge_index + g * T for g in range(3)], 1)
    x = torch.cat([readings.unsqueeze(-1), positions], -1).reshape(3 * T, 4)
    refs = []
    for conv in model.convs:
        refs.append(ref := GCNConv(conv.in_channels, conv.out_channels))
        ref.lin.weight.data.copy_(conv.lin.weight)
        ref.bias.data.copy_(conv.bias)
        x = torch.relu(ref(x, batched))
    expected = model.head(x.view(3, T, -1).amax(1))
    out = model(readings, positions)
    torch.testing.assert_close(out, expected, atol=1e-5, rtol=1e-5)
    target = torch.randn_like(out)
    ((out - target) ** 2).sum().backward()
    head_grads = [p.grad.clone() for p in model.head.parameters()]
    model.head.zero_grad()
    ((expected - target) ** 2).sum().backward()
    for conv, ref in zip(model.convs, refs):
        torch.testing.assert_close(conv.lin.weight.grad, ref.lin.weight.grad, atol=1e-4, rtol=1e-4)
        torch.testing.assert_close(conv.bias.grad, ref.bias.grad, atol=1e-4, rtol=1e-4)
    for got, p in zip(head_grads, model.head.parameters()):
        torch.testing.assert_close(got, p.grad, atol=1e-4, rtol=1e-4)


def test_cnn_matches_relu_before_pool(rest):
    """Max-pooling before the ReLU on channels-last images computes the CNN of the old layer
    order (conv, ReLU, pool), so checkpoints written before the change mean the same."""
    import torch.nn.functional as F

    torch.manual_seed(0)
    model = make("cnn", rest)
    readings, positions, _ = blob_frames(rest, 4, seed=3)
    img = torch.zeros(4, 36 * 36)
    img[:, model.pixel] = readings
    conv1, conv2 = model.features[0], model.features[3]
    x = F.max_pool2d(torch.relu(F.conv2d(img.view(4, 1, 36, 36), conv1.weight.contiguous(), conv1.bias)), 2)
    x = F.max_pool2d(torch.relu(F.conv2d(x, conv2.weight.contiguous(), conv2.bias)), 2)
    with torch.no_grad():
        torch.testing.assert_close(model(readings, positions), model.head(x.flatten(1)))


def test_cnn_layout_packing(rest):
    layout = torch.stack([torch.arange(T) % 36, torch.arange(T) // 36], 1)  # column-major
    model = TactileCNN(layout=layout)
    readings = torch.zeros(1, T)
    readings[0, 40] = 1.0  # taxel 40 -> row 4, col 1
    img = torch.zeros(1, 36 * 36)
    img[:, model.pixel] = readings
    assert img.view(36, 36)[4, 1] == 1.0 and img.sum() == 1.0
    assert model(readings, rest.unsqueeze(0)).shape == (1, 6)
    with pytest.raises(ValueError, match="same pixel"):
        TactileCNN(layout=torch.zeros(T, 2, dtype=torch.long))
    with pytest.raises(ValueError, match="layout"):
        TactileCNN(layout=layout + 36)


@pytest.mark.parametrize(
    "field, value",
    [
        ("name", "transformer"),
        ("channels", 0),
        ("channels", 32.0),
        ("k", (3, 0, 3)),
        ("k", ()),
        ("sample_ratio", 0.0),
        ("sample_ratio", 1.5),
        ("downsample_layers", (0, 3)),
        ("downsample_layers", (1, 1)),
        ("use_force", 1),
        ("exact_graph", "yes"),
        ("out_dim", -1),
        ("num_taxels", 0),
        ("fps_start", "middle"),
        ("image_size", 10),
        ("gcn_k", 0),
        ("gcn_channels", (32, 0)),
        ("mlp_hidden", 64),
    ],
)
def test_config_validation_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        PerceptionModelConfig(**{field: value})


def test_config_accepts_lists_and_build_model_forms(rest):
    cfg = PerceptionModelConfig(k=[6, 4, 3], downsample_layers=[0, 1])
    assert cfg.k == (6, 4, 3) and cfg.downsample_layers == (0, 1)
    assert isinstance(build_model(cfg), TacGNN)
    assert isinstance(build_model("gcn", cfg, rest_positions=rest), TactileGCN)
    assert isinstance(build_model("cnn"), TactileCNN)
    with pytest.raises(ValueError, match="rest_positions"):
        build_model("gcn")
    with pytest.raises(ValueError, match="rest_positions"):
        build_model("gcn", rest_positions=rest[:10])


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_reset_parameters(name, rest):
    model = make(name, rest)
    weights = [p for p in model.parameters() if p.dim() > 1]  # biases may reset to 0
    before = [w.detach().clone() for w in weights]
    model.reset_parameters()
    assert all(not torch.equal(a, b) for a, b in zip(before, weights))


def test_tacgnn_learns_blob_centroid(rest):
    """TacGNN-32 learns 'centroid of the touched taxels' in 300 Adam steps."""
    torch.manual_seed(0)
    train = blob_frames(rest, 4096, seed=10)
    test = blob_frames(rest, 512, seed=11)
    model = make("tacgnn", rest, out_dim=3)
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


def test_config_is_frozen():
    cfg = PerceptionModelConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.channels = 64


def test_conv_chunking_does_not_change_results(rest):
    torch.manual_seed(0)
    model = make("tacgnn", rest)
    readings, positions, _ = blob_frames(rest, 8, seed=13)
    with torch.no_grad():
        y = model(readings, positions)
        for conv in model.convs:
            conv.chunk_size = 7
        torch.testing.assert_close(model(readings, positions), y)


def test_tacgnn_in_double_precision(rest):
    """float64 falls back to the exact graph path (the int32 keys need float32)."""
    torch.manual_seed(0)
    model = make("tacgnn", rest).double()
    readings, positions, _ = blob_frames(rest, 4, seed=14)
    y = model(readings.double(), positions.double())
    assert y.dtype == torch.float64 and torch.isfinite(y).all()


@pytest.mark.parametrize("pool", ["last", "all", "jk", "sum"])
@pytest.mark.parametrize("extra", [dict(), dict(use_force=True, force_feature="log", residual=True, message_layers=3)])
def test_tacgnn_readouts_are_invariant_and_blind_safe(rest, pool, extra):
    """Every readout keeps node-order invariance and gives finite outputs on empty/one-taxel frames."""
    torch.manual_seed(0)
    model = make("tacgnn", rest, pool=pool, **extra)
    readings, positions, _ = blob_frames(rest, 6, seed=5)
    readings[0] = 0.0
    readings[1] = 0.0
    readings[1, 17] = 1e-9  # a barely-pressed taxel: log force must stay finite
    perm = torch.randperm(T)
    with torch.no_grad():
        y = model(readings, positions)
        y_perm = model(readings[:, perm], positions[:, perm])
    assert y.shape == (6, 6) and torch.isfinite(y).all()
    torch.testing.assert_close(y_perm, y, atol=1e-5, rtol=1e-5)
    # an empty frame reads the head at a zero pooled feature, whatever the readout
    torch.testing.assert_close(y[0], model.head(torch.zeros(model.head[0].in_features)))


def test_tacgnn_readout_widths(rest):
    """'all' concatenates the L pooled layers; 'jk' maps them back to C; 'last' is the paper's C."""
    assert make("tacgnn", rest, pool="last").head[0].in_features == 32
    assert make("tacgnn", rest, pool="all").head[0].in_features == 96
    jk = make("tacgnn", rest, pool="jk")
    assert jk.head[0].in_features == 32 and jk.jk.in_features == 96 and jk.jk.bias is None
    assert len(make("tacgnn", rest, head_layers=3).head) == 5  # Linear ReLU Linear ReLU Linear


def test_log_force_feature_changes_the_input(rest):
    """The same weights read log(f) instead of f: different outputs, both finite."""
    torch.manual_seed(0)
    raw = make("tacgnn", rest, use_force=True, force_feature="raw")
    log = make("tacgnn", rest, use_force=True, force_feature="log")
    log.load_state_dict(raw.state_dict())
    readings, positions, _ = blob_frames(rest, 3, seed=6)
    with torch.no_grad():
        a, b = raw(readings, positions), log(readings, positions)
    assert torch.isfinite(b).all() and not torch.allclose(a, b)


@pytest.mark.parametrize("name", ["mlp", "cnn", "gcn"])
def test_log1p_reading_feature_is_the_same_network_on_log1p_readings(name, rest):
    """reading_feature=log1p feeds log(1 + f / 0.01 N) to the unchanged network: a force scaled by a
    constant moves the input of the taxels a contact presses hard by nearly the same shift."""
    torch.manual_seed(0)
    raw = make(name, rest)
    log = make(name, rest, reading_feature="log1p")
    log.load_state_dict(raw.state_dict())
    readings, positions, _ = blob_frames(rest, 3, seed=8)
    with torch.no_grad():
        expected = raw(torch.log1p(readings / 0.01), positions)
        assert torch.allclose(log(readings, positions), expected, atol=1e-5)
        assert not torch.allclose(raw(readings, positions), expected)
    strong = readings[readings > 0.2]
    assert strong.numel() > 10
    shift = reading_input(1.7 * strong, "log1p") - reading_input(strong, "log1p")
    assert torch.allclose(shift, torch.full_like(shift, math.log(1.7)), atol=0.04)
    assert reading_input(torch.zeros(4), "log1p").eq(0).all()  # nothing pressed reads 0, as in raw


def test_gcn_on_rest_positions_does_not_see_the_pose(rest):
    """gcn_node_positions=rest: moving the taxels (the hand's pose) leaves the output unchanged."""
    torch.manual_seed(0)
    current = make("gcn", rest)
    fixed = make("gcn", rest, gcn_node_positions="rest")
    fixed.load_state_dict(current.state_dict())
    readings, positions, _ = blob_frames(rest, 3, seed=9)
    moved = positions + 0.5 * torch.randn_like(positions)
    with torch.no_grad():
        assert torch.allclose(fixed(readings, positions), fixed(readings, moved))
        assert torch.allclose(fixed(readings, positions), current(readings, rest.expand(3, -1, -1)), atol=1e-6)
        assert not torch.allclose(current(readings, positions), current(readings, moved))
    with pytest.raises(ValueError, match="gcn_node_positions"):
        PerceptionModelConfig(name="gcn", gcn_node_positions="mean")


def test_reading_feature_is_not_tacgnns_input():
    with pytest.raises(ValueError, match="force_feature"):
        PerceptionModelConfig(name="tacgnn", reading_feature="log1p")
    assert PerceptionModelConfig(name="mlp", reading_feature="log1p").reading_feature == "log1p"


@pytest.mark.parametrize("field,value", [("pool", "mean"), ("force_feature", "sqrt"), ("message_layers", 1),
                                         ("head_hidden", -1), ("pos_scale", 0.0), ("residual", "yes"),
                                         ("reading_feature", "log")])
def test_new_config_fields_are_validated(field, value):
    with pytest.raises(ValueError, match=field):
        PerceptionModelConfig(**{field: value})


@pytest.mark.parametrize("name", ["tacgnn", "mlp"])
def test_joint_inputs(name, rest):
    """A model that reads the hand's joint angles needs them, uses them, and stays finite on empty frames."""
    torch.manual_seed(0)
    model = make(name, rest, joint_inputs=16)
    readings, positions, _ = blob_frames(rest, 4, seed=7)
    readings[0] = 0.0
    joints = torch.rand(4, 16)
    y = model(readings, positions, joints)
    assert y.shape == (4, 6) and torch.isfinite(y).all()
    assert not torch.allclose(model(readings, positions, joints + 0.5)[0], y[0])  # even a blind frame
    with pytest.raises(ValueError, match="joint"):
        model(readings, positions)
    with pytest.raises(ValueError, match="joints"):
        model(readings, positions, joints[:, :3])
    with pytest.raises(ValueError, match="without joint inputs"):
        make(name, rest)(readings, positions, joints)
    with pytest.raises(ValueError, match="joint_inputs"):
        PerceptionModelConfig(name="gcn", joint_inputs=16)


@pytest.mark.parametrize("kw", [{}, {"use_force": True, "force_feature": "log", "pool": "jk", "residual": True},
                                {"k": (6, 4, 3), "downsample_layers": (0, 2), "fps_start": "first"}])
def test_tacgnn_compiled_graphs_match_the_torch_graphs(rest, kw):
    """The numba graph builder gives the network the same graphs as the torch one: same output,
    same gradients, also with blind and one-taxel frames and graphs smaller than k."""
    if not graph_numba.available():
        pytest.skip("numba is not installed")
    torch.manual_seed(0)
    model = make("tacgnn", rest, **kw)
    readings, positions, _ = blob_frames(rest, 24, seed=5, sizes=(1, 40))
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
