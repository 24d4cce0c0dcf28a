"""Shared fixtures of the perception tests: one torch thread, taxel clouds, blob frames, a dataset."""

import pytest
import torch

T = 653


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """The test machine's 2 cores are shared: 2 busy threads would wait on each other."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def rest():
    """A fixed random taxel cloud in a 10 x 6 x 3 cm box (no distance ties)."""
    return torch.rand(T, 3, generator=torch.Generator().manual_seed(0)) * torch.tensor([10.0, 6.0, 3.0])


@pytest.fixture(scope="session")
def skin_rest():
    """The default skin's taxels at rest (cm): regular grids, where many neighbours tie."""
    from tacgnn.hand.skin_layout import default_skin
    from tacgnn.perception.rest_positions import rest_positions_cm

    return rest_positions_cm(default_skin())


def blob_frames(rest, n, seed, sizes=(5, 31)):
    """n frames, each touching the taxels nearest to a random taxel; target = their centroid.

    The whole hand is shifted by a random offset per frame (positions move).
    """
    g = torch.Generator().manual_seed(seed)
    T = rest.shape[0]
    centre = torch.randint(0, T, (n,), generator=g)
    size = torch.randint(*sizes, (n,), generator=g)
    order = torch.cdist(rest, rest)[centre].argsort(1)
    hit = (torch.arange(T) < size.unsqueeze(1)).float()
    w = torch.zeros(n, T).scatter_(1, order, hit)
    readings = w * (torch.rand(n, T, generator=g) + 0.1)
    offset = torch.randn(n, 1, 3, generator=g)
    target = (w @ rest) / size.unsqueeze(1) + offset[:, 0]
    return readings, rest + offset, target


@pytest.fixture(scope="session")
def blobs():
    """blobs(rest, n, seed, sizes=(5, 31)) -> readings (n, T), positions (n, T, 3), target (n, 3)."""
    return blob_frames


@pytest.fixture(scope="session")
def dataset(tmp_path_factory):
    """A small Baoding dataset (800 frames, two shards), generated once for every test."""
    from tacgnn.datasets.baoding_data import BaodingDataConfig, generate

    root = tmp_path_factory.mktemp("data") / "baoding"
    generate(BaodingDataConfig(samples=800, shard_size=400, num_envs=32), root)
    return root
