"""Sequence data: episode order, the split by episode, windows that never cross an episode."""

import numpy as np
import pytest
import torch

from tacgnn.config import ConfigError
from tacgnn.datasets.store import DatasetError
from tacgnn.perception.sequences import (
    SequenceData,
    burn_in_rows,
    check_windows,
    join_episodes,
    load_sequences,
    split_by_episode,
    steps_since_touch,
    touched,
    window_starts,
)
from tests.perception.sequence_helpers import episodes, to_sequence_data, write_dataset


@pytest.fixture(scope="module")
def arrays():
    return episodes(8, (10, 30), seed=1)


def test_loading_sorts_shuffled_shards_back_into_episodes(tmp_path, arrays):
    n = len(arrays["episode"]) - len(arrays["episode"]) % 2
    keep = {k: v[:n] for k, v in arrays.items()}  # the last episode may lose its last frame: still consecutive
    data = load_sequences(write_dataset(tmp_path / "ds", keep))
    key = data.episode * 10_000 + data.step
    assert (key[1:] > key[:-1]).all()  # sorted by (episode, step)
    expected = to_sequence_data(keep)
    order = np.lexsort((keep["step"], keep["episode"]))
    assert torch.equal(data.frames.readings, expected.frames.readings[order])
    assert torch.allclose(data.frames.targets, expected.frames.targets[order])
    # max_frames keeps whole episodes
    part = load_sequences(tmp_path / "ds", max_frames=25)
    assert len(part) >= 25 and part.episode[-1] != data.episode[len(part)]


def test_a_dataset_without_episode_indices_is_named(tmp_path, arrays):
    from tacgnn.datasets.baoding_data import schema
    from tacgnn.datasets.store import ShardedWriter

    old = {k: f for k, f in schema(96).items() if k not in ("episode", "step", "action")}
    writer = ShardedWriter(tmp_path / "old", old, {"kind": "baoding", "num_taxels": 96}, num_shards=1, shard_size=10)
    writer.generate_missing(lambda i: {k: arrays[k][:10] for k in old})
    with pytest.raises(DatasetError, match=r"old.*no episode, step, action.*--keep-every 1"):
        load_sequences(tmp_path / "old")


def test_split_by_episode_keeps_every_episode_on_one_side(arrays):
    data = to_sequence_data(arrays)
    train, test = split_by_episode(data, 0.75, seed=3)
    assert len(train) + len(test) == len(data)
    assert not set(train.episode.tolist()) & set(test.episode.tolist())
    assert len(test.episodes()) == 2
    again, _ = split_by_episode(data, 0.75, seed=3)
    assert torch.equal(again.episode, train.episode)
    other, _ = split_by_episode(data, 0.75, seed=4)
    assert not torch.equal(other.episode, train.episode) or len(data.episodes()) < 3


def test_windows_stay_inside_one_episode(arrays):
    data = to_sequence_data(arrays)
    lengths = torch.unique_consecutive(data.episode, return_counts=True)[1]
    for length in (1, 5, int(lengths.max())):
        starts = window_starts(data, length)
        rows = starts.unsqueeze(1) + torch.arange(length)
        check_windows(data, rows)  # raises on a window across episodes
        assert len(starts) == int((lengths - length + 1).clamp_min(0).sum())
    with pytest.raises(ConfigError, match=rf"window.*{int(lengths.max()) + 1} frames is longer than every episode"):
        window_starts(data, int(lengths.max()) + 1)


def test_windows_across_episodes_or_gaps_are_refused(arrays):
    data = to_sequence_data(arrays)
    end = int((data.episode != data.episode[0]).nonzero()[0])  # first frame of the second episode
    with pytest.raises(ValueError, match="two episodes"):
        check_windows(data, torch.arange(end - 2, end + 2).unsqueeze(0))
    with pytest.raises(ValueError, match="consecutive steps"):
        check_windows(data, torch.tensor([[0, 2, 3]]))
    gappy = data.subset(torch.arange(0, len(data), 2))  # every 2nd step, as keep_every=2 records
    with pytest.raises(ConfigError, match="longest run of consecutive steps: 1 frames"):
        window_starts(gappy, 2)


def test_burn_in_stops_at_the_episode_start(arrays):
    data = to_sequence_data(arrays)
    starts = torch.tensor([0, 2, 9])
    rows, valid = burn_in_rows(data, starts, 4)
    assert valid.tolist() == [[False] * 4, [False, False, True, True], [True] * 4]
    assert rows[2].tolist() == [5, 6, 7, 8]


def test_touch_and_steps_since_touch():
    pos = torch.tensor([[[0.0, 0, 0], [10.0, 0, 0]]]).repeat(6, 1, 1)  # two taxels
    readings = torch.tensor([[1.0, 0], [0, 0], [0, 0], [1, 0], [0, 0], [0, 0]])
    targets = torch.tensor([[0.0, 0, 2.5, 10, 0, 5]]).repeat(6, 1)  # ball 0 on taxel 0; ball 1 3 cm+ off taxel 1
    from tacgnn.perception.data import TactileData

    frames = TactileData(readings, pos, targets, torch.zeros(6, 16))
    data = SequenceData(frames, torch.zeros(6, 16), torch.tensor([0, 0, 0, 0, 1, 1]), torch.tensor([1, 2, 3, 4, 1, 2]))
    touch = touched(frames, within_cm=3.0)
    assert touch[:, 0].tolist() == [True, False, False, True, False, False] and not touch[:, 1].any()
    since = steps_since_touch(data, touch)
    assert since[:, 0].tolist() == [0, 1, 2, 0, 1, 2]  # a new episode counts from its first frame
    assert since[:, 1].tolist() == [1, 2, 3, 4, 1, 2]


def test_joined_episodes_get_ids_of_their_own_and_keep_their_frames(arrays):
    a = to_sequence_data(arrays)
    b = to_sequence_data(episodes(3, 12, seed=1))  # the same ids as a's first three episodes
    joined = join_episodes([a, b])
    assert len(joined) == len(a) + len(b)
    assert torch.equal(joined.episode[:len(a)], a.episode)  # the first part keeps its ids
    assert len(torch.unique(joined.episode)) == len(a.episodes()) + len(b.episodes())
    assert torch.equal(joined.frames.readings[len(a):], b.frames.readings)
    assert torch.equal(joined.step[len(a):], b.step) and torch.equal(joined.actions[len(a):], b.actions)
    # windows of the joined data stay inside one episode of one part
    starts = window_starts(joined, 10)
    check_windows(joined, starts.unsqueeze(1) + torch.arange(10))
    assert len(starts) == len(window_starts(a, 10)) + len(window_starts(b, 10))
    narrow = SequenceData(b.frames.subset(torch.arange(len(b))), b.actions, b.episode, b.step)
    narrow.frames.readings = narrow.frames.readings[:, :50]
    with pytest.raises(ValueError, match="different numbers of taxels"):
        join_episodes([a, narrow])
