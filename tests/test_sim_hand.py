"""The simulated hand behind ROS is one hand with one skin: its skin carries over episode ends."""

import numpy as np

from tacgnn.learning.policy import SHIPPED_POLICY, load_policy
from tacgnn.real.ros_config import RosConfig
from tacgnn.real.sim_hand import SimHand, SimHandConfig
from tacgnn.sim.skin_signal import SkinSignal


def test_the_skin_is_the_same_skin_after_an_episode_ends():
    _, env_config = load_policy(SHIPPED_POLICY)
    hand = SimHand(env_config, SimHandConfig(), RosConfig())
    assert hand.cfg.skin == "real" and hand.cfg.latency_s == 0.02  # the defaults a real hand asks for
    env = hand.env
    env.reset(seed=0)
    skin = env.skin_signal.state_dict()
    ended = False
    for _ in range(env.episode_limit + 1):  # a bad action drops the balls or times out
        *_, terminated, truncated, _ = hand.step(np.ones((1, 16)))
        if terminated[0] or truncated[0]:
            ended = True
            break
    assert ended
    for name in ("gain", "offset", "threshold", "calibration_gain", "dead", "stuck"):  # the baseline tracks
        np.testing.assert_array_equal(getattr(env.skin_signal, name), skin[name])
    # the env itself draws a new skin at a reset (training's randomisation)
    env.reset(seed=1)
    assert not np.array_equal(env.skin_signal.offset, skin["offset"])
    assert set(SkinSignal.STATE) >= {"gain", "offset", "dead"}
