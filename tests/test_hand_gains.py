"""Per-joint stiffness and damping in HandConfig: validated, used by the model, scalars unchanged."""

import numpy as np
import pytest

from tacgnn.config import ConfigError, from_dict, override, to_dict
from tacgnn.envs.baoding import BaodingConfig
from tacgnn.hand.allegro import HandConfig
from tacgnn.sim.scene import SimConfig, hand_scene

KP = tuple(1.0 + 0.25 * i for i in range(16))
DAMP = tuple(0.01 * i for i in range(16))


def compiled(hand):
    model = hand_scene(hand, SimConfig()).compile()
    return model.actuator_gainprm[:16, 0], -model.actuator_biasprm[:16, 1], model.dof_damping[model.jnt_dofadr[:16]]


def test_per_joint_values_reach_the_model():
    kp, bias, damping = compiled(HandConfig(stiffness=KP, damping=DAMP))
    np.testing.assert_array_equal(kp, KP)
    np.testing.assert_array_equal(bias, KP)
    np.testing.assert_array_equal(damping, DAMP)


def test_scalar_values_are_unchanged():
    assert HandConfig().stiffness == 3.0 and HandConfig().damping == 0.1
    assert to_dict(HandConfig())["stiffness"] == 3.0  # stored configs of old runs compare equal
    kp, _, damping = compiled(HandConfig())
    assert np.all(kp == 3.0) and np.all(damping == 0.1)


def test_per_joint_values_from_yaml_and_overrides():
    cfg = override(BaodingConfig(), {"hand.stiffness": list(KP), "hand.damping": 0.2})
    assert cfg.hand.stiffness == KP and cfg.hand.joint_damping() == (0.2,) * 16
    assert from_dict(BaodingConfig, to_dict(cfg)) == cfg
    assert HandConfig(stiffness=list(KP)) == HandConfig(stiffness=KP)


@pytest.mark.parametrize("key,value,message", [
    ("stiffness", (1.0,) * 15, "needs one value or 16"),
    ("stiffness", (1.0,) * 15 + (0.0,), "joint thumb_j3: must be a finite number in \\(0, 1000\\]"),
    ("damping", (0.1,) * 15 + (-0.1,), "joint thumb_j3: must be a finite number in \\[0, 100\\]"),
    ("damping", float("nan"), "hand.damping"),
])
def test_bad_per_joint_values_are_named(key, value, message):
    with pytest.raises(ConfigError, match=message):
        HandConfig(**{key: value})


def test_domain_randomisation_scales_per_joint_gains():
    from tacgnn.envs.baoding import BaodingEnv

    cfg = override(BaodingConfig(num_envs=2, tactile=False), {"hand.stiffness": list(KP),
                                                             "randomization.enabled": True})
    env = BaodingEnv(cfg)
    kp = env.sim.expand("actuator_gainprm")[:, :16, 0]
    ratio = kp / np.asarray(KP)
    lo, hi = cfg.randomization.stiffness_scale
    assert np.all((ratio >= lo) & (ratio <= hi)) and not np.allclose(ratio, 1.0)
