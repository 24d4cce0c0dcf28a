"""experiments/real_hand/inloop_error_parts.py: a blind policy's in-loop error, split by its sources."""

import numpy as np

from tacgnn.learning.evaluate import matched_ball_errors
from tacgnn.learning.policy import SHIPPED_POLICY


def test_ball_order_and_touch_are_read_as_the_evaluation_reads_them(experiment_script):
    parts = experiment_script("real_hand/inloop_error_parts")
    true = np.array([[0.0, 0.0, 0.0, 0.05, 0.0, 0.0]])
    assert matched_ball_errors(true[:, [3, 4, 5, 0, 1, 2]], true).sum() == 0.0  # the balls swapped: no error
    np.testing.assert_allclose(matched_ball_errors(true + 0.001, true), [[3e-6, 3e-6]])
    taxels = np.array([[[0.0, 0.0, 0.02], [0.05, 0.0, 0.04]]])  # 2 cm from ball 0, 4 cm from ball 1
    assert parts.touched(np.array([[0.3, 0.3]]), taxels, true).tolist() == [[True, False]]
    assert parts.touched(np.array([[0.0, 0.3]]), taxels, true).tolist() == [[False, False]]


def test_the_parts_add_up_and_a_skin_without_latency_has_no_latency_floor(experiment_script):
    parts = experiment_script("real_hand/inloop_error_parts")
    late = parts.run(str(SHIPPED_POLICY), {}, episodes=4, num_envs=4, seed=1)
    prompt = parts.run(str(SHIPPED_POLICY), parts.VARIANTS["no skin latency"], episodes=4, num_envs=4, seed=1)
    assert late["latency floor cm"] > 0.0 and prompt["latency floor cm"] == 0.0
    for r in (late, prompt):
        share = r["touched share"]
        mixed = share * r["touched cm"] ** 2 + (1 - share) * r["untouched cm"] ** 2
        assert abs(mixed - r["all cm"] ** 2) < 1e-9
        assert 0.05 < r["all cm"] < 2.0 and r["episodes"] >= 4
