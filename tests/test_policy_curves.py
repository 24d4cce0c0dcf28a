"""experiments/policy_curves.py: learning curves read from TensorBoard, seeds averaged on shared iterations."""

import numpy as np
import pytest


@pytest.fixture(scope="module")
def curves(experiment_script):
    return experiment_script("policy_curves")


def test_a_resumed_run_merges_its_event_files(curves, tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    for first, last, value in ((0, 6, 0.1), (4, 10, 0.5)):  # resumed at iteration 4: the later file wins
        writer = SummaryWriter(str(tmp_path))
        for step in range(first, last):
            writer.add_scalar("Episode/success_rate", value, step)
        writer.close()
    scalars = curves.run_scalars(tmp_path)
    it, values, _ = curves.success_curve(scalars)
    assert it.tolist() == list(range(10))
    assert np.allclose(values, [0.1] * 4 + [0.5] * 6)
    assert curves.final_perception_error(scalars) is None  # a run without perception in the loop


def test_the_perception_error_is_read_at_the_last_update(curves, tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(tmp_path))
    for step, value in ((8, 0.9), (24, 0.7), (16, 0.8)):  # written out of order: the last iteration counts
        writer.add_scalar("perception/rmse_cm_before", value, step)
    writer.close()
    scalars = curves.run_scalars(tmp_path)
    assert curves.final_perception_error(scalars) == pytest.approx(0.7)
    # a seed run longer than the others is read where the shared curve ends: after iteration 15
    assert curves.final_perception_error(scalars, last_iteration=15) == pytest.approx(0.8)
    assert curves.final_perception_error(scalars, last_iteration=6) is None  # no update yet


def test_seeds_average_over_the_iterations_all_of_them_logged(curves):
    a = (np.arange(0, 10), np.full(10, 0.2), np.arange(10.0))
    b = (np.arange(2, 6), np.full(4, 0.6), 2 * np.arange(4.0))  # a shorter seed, starting later
    it, values, wall = curves.common_iterations([a, b])
    assert it.tolist() == [2, 3, 4, 5]
    assert np.allclose(values.mean(axis=0), 0.4) and values.shape == (2, 4)
    assert wall.tolist() == [2.0, 3.0, 4.0, 6.0]  # the slower seed at each iteration
    with pytest.raises(ValueError, match="share no logged iteration"):
        curves.common_iterations([a, (np.arange(20, 22), np.zeros(2), np.zeros(2))])
    # cut at a length: the iterations 0 .. N - 1 only, the perception error then read inside them
    it, values, _ = curves.common_iterations([a, b], iterations=4)
    assert it.tolist() == [2, 3] and values.shape == (2, 2)
