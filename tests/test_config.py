"""Configs: generated configs either build or are rejected at load time, naming the key."""

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from tacgnn.config import ConfigError, from_dict, override, to_dict
from tacgnn.envs.baoding import BaodingConfig

KEYS = ["num_envs", "task", "obs_mode", "ball_mass", "ball_radius", "control_dt", "max_episode_steps",
        "success_angle_deg", "direction", "disturbance_std", "hold_steps", "sim.timestep",
        "sim.contacts_per_patch", "hand.stiffness", "hand.damping", "randomization.gravity",
        "reward.success", "tactile", "no_such_key", "sim.no_such_key"]
VALUES = st.one_of(st.integers(-5, 300), st.floats(-1.0, 2.0), st.just(float("nan")), st.booleans(),
                   st.sampled_from(["simple", "hard", "tactile", "bogus", ""]),
                   st.lists(st.floats(-1, 20), min_size=0, max_size=3), st.none())


@settings(max_examples=150, deadline=None)
@given(st.dictionaries(st.sampled_from(KEYS), VALUES, max_size=4))
@example({"control_dt": 0.75})  # valid itself, but 10 s episodes are then no whole number of steps
def test_generated_configs_build_or_name_the_bad_key(updates):
    try:
        cfg = override(BaodingConfig(), updates)
    except ConfigError as err:
        assert any(key.split(".")[-1] in str(err) or key.split(".")[0] in str(err) for key in updates)
        return
    assert isinstance(cfg, BaodingConfig)
    assert from_dict(BaodingConfig, to_dict(cfg)) == cfg  # round trip


def test_unknown_nested_key_is_named_with_a_suggestion():
    with pytest.raises(ConfigError, match="sim.timestpe.*did you mean 'sim.timestep'"):
        from_dict(BaodingConfig, {"sim": {"timestpe": 0.01}})


def test_type_errors_name_the_key():
    with pytest.raises(ConfigError, match="num_envs"):
        from_dict(BaodingConfig, {"num_envs": "many"})
    with pytest.raises(ConfigError, match="task"):
        from_dict(BaodingConfig, {"task": "impossible"})
