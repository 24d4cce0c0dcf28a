"""experiments/continuous_pace.py: a policy's speed bound comes from its own hand."""

import json

import torch

from tacgnn.learning.policy import SHIPPED_GROUND_TRUTH


def test_each_policy_is_bounded_by_the_top_speed_of_its_own_hand(experiment_script, tmp_path):
    """A policy trained under 1.0 N m is measured against the 10 rad/s that 1.0 N m allows over
    the joint damping of 0.1 N m s/rad, not the 5 rad/s of the bare-hand test's 0.5 N m."""
    pace = experiment_script("continuous_pace")
    data = torch.load(SHIPPED_GROUND_TRUTH, weights_only=True)
    data["env_config"]["hand"]["torque_limit"] = 1.0
    stronger = tmp_path / "stronger.pt"
    torch.save(data, stronger)
    out = tmp_path / "pace.json"
    assert pace.main([str(out), f"as shipped={SHIPPED_GROUND_TRUTH}", f"1.0 N m={stronger}", "--episodes", "2",
                      "--limits", "0.5"]) == 0
    record = json.loads(out.read_text())
    assert abs(record["hand"]["0.5 N m"]["top_speed_min_over_joints_rad_s"] - 5.0) < 0.25
    assert abs(record["policies"]["as shipped"]["hand_top_speed_rad_s"] - 5.0) < 0.25
    assert abs(record["policies"]["1.0 N m"]["hand_top_speed_rad_s"] - 10.0) < 0.5
