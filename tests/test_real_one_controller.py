"""The env's perceived mode and the real-hand controller are one controller.

One episode runs in `BaodingEnv` (obs_mode 'perceived'); the controller is fed, step by
step, what a hand would measure in it (joint angles and velocities, the skin frame) and
must give the same observation and the same action at every step, ball-identity
tracking included.
"""

from dataclasses import replace

import numpy as np
import pytest
import torch
from real_policy import blind_policy, with_ball_velocity

from tacgnn.envs.baoding import BaodingEnv, ordered_balls
from tacgnn.envs.observation import BALL_COLUMNS, action_to_target, assemble, target_to_action, track_ball_identities
from tacgnn.envs.randomization import RandomizationConfig
from tacgnn.learning.policy import load_perception
from tacgnn.real import BlindController, BlindControllerConfig
from tacgnn.sim.skin_signal import SkinSignalConfig

torch.set_num_threads(1)


class FlippingPerception:
    """The policy's perception, with its two balls given in swapped order on some frames.

    A skin model cannot tell the balls apart; this one flips the order on frames picked
    by a hash of the skin frame, so both paths see the same flips and must undo them.
    """

    def __init__(self, inner):
        self.inner = inner
        self.joint_inputs = getattr(inner, "joint_inputs", 0)
        self.flips = 0

    def bind_env(self, env):  # a perception with memory keeps its state per env of `env`
        getattr(self.inner, "bind_env", lambda env: None)(env)

    def __call__(self, readings, taxel_pos, *joints):
        pred = np.asarray(self.inner(readings, taxel_pos, *joints), np.float64)
        flip = int(np.float64(readings.sum()) * 1e4) % 3 == 0
        self.flips += flip
        return pred[:, [3, 4, 5, 0, 1, 2]] if flip else pred


@pytest.fixture(scope="module")
def policy_file(tmp_path_factory):
    return blind_policy(tmp_path_factory.mktemp("policy"))


@pytest.mark.parametrize(("ball_order", "ball_velocity"), [("as_simulated", False), ("canonical", False),
                                                          ("canonical", True)])
def test_env_and_controller_give_the_same_observations_and_actions(policy_file, ball_order, ball_velocity, tmp_path):
    if ball_velocity:  # a policy that also sees the balls' velocities
        policy_file = with_ball_velocity(policy_file, tmp_path)
    controller = BlindController(BlindControllerConfig(policy=str(policy_file)))
    controller.env_config = replace(controller.env_config, ball_order=ball_order)
    cfg = replace(controller.env_config, num_envs=1, seed=5, max_episode_steps=120,
                  # all substeps in one call (the skin-instant hook below); the physics is the same
                  reward=replace(controller.env_config.reward, squeeze_peak=False),
                  # the controller is fed the contact model's frames and the true joints: the skin's
                  # signal chain and the encoders' effects are the calibration's and the hand's business
                  # (tests/test_skin_signal.py, tests/test_randomization.py), not this test's
                  skin_signal=SkinSignalConfig(preset="ideal"), randomization=RandomizationConfig())
    env = BaodingEnv(cfg, perception=FlippingPerception(load_perception(policy_file)))  # its own memory, if any
    controller.perception = FlippingPerception(controller.perception)
    frames = []  # every skin frame the env computes, and the joint angles at its instant
    readings = env.tactile.readings

    def recorded_readings(*args, **kwargs):
        frames.append(readings(*args, **kwargs).copy())
        return frames[-1]

    env.tactile.readings = recorded_readings
    skin_q = []
    physics_step = env.sim.step

    def step_recording_the_skin_instant(n):  # the skin is taken at the start of the last substep
        bad = physics_step(n - 1)
        skin_q.append(env.joint_pos[0].copy())
        return bad | physics_step(1)

    env.sim.step = step_recording_the_skin_instant

    obs, _ = env.reset(seed=5)
    compared = episodes = reordered = 0
    fastest = 0.0  # the largest ball velocity shown (m/s), with ball_velocity
    while compared < 40:  # whole episodes, at least 40 steps in all
        q = env.joint_pos[0].copy()
        controller.reset(q)
        steps, done = 0, False
        while not done:
            skin_at = q if steps == 0 else skin_q[-1]  # at reset the skin is of the reset state
            obs_c = controller.observation(q, env.joint_vel[0], frames[-1][0], skin_joint_pos=skin_at)
            np.testing.assert_array_equal(obs_c, obs[0], err_msg=f"observation at step {steps}")
            reordered += not np.array_equal(ordered_balls(controller.balls, cfg), controller.balls)
            if ball_velocity:
                fastest = max(fastest, float(np.abs(obs_c[BALL_COLUMNS.stop:BALL_COLUMNS.stop + 6]).max()))
            action = controller.policy(obs)
            action_c = controller.act(obs_c)
            np.testing.assert_array_equal(action_c, np.clip(action[0], -1, 1), err_msg=f"action at step {steps}")
            target_c = controller.limit(controller.action_to_target(action_c), q)
            obs, _, terminated, truncated, _ = env.step(action)
            done = bool(terminated[0] or truncated[0])
            if not done:  # (an env that ended has reset its targets)
                np.testing.assert_allclose(target_c, env.sim.ctrl[0], rtol=0, atol=1e-12)
            q = env.joint_pos[0].copy()
            steps += 1
        compared += steps
        episodes += 1
    if ball_velocity:
        assert obs.shape[1] == 60 and fastest > 0.01  # the velocities were shown, and matched
    if ball_order == "canonical":  # the order was in play: on some steps it swapped the tracked balls
        assert reordered > 0
    assert controller.perception.flips > 3  # tracking had swaps to undo (the env also perceives each last frame)


def test_the_observation_layout():
    lo, hi = np.full(16, -1.0), np.full(16, 3.0)
    q = np.linspace(-1, 3, 16)[None]
    qd = np.arange(16.0)[None]
    balls = np.arange(6.0)[None]
    last = np.full((1, 16), 0.5)
    obs = assemble(q, qd, balls, last, lo, hi)
    assert obs.shape == (1, 54) and obs.dtype == np.float32
    np.testing.assert_allclose(obs[0, :16], np.linspace(-1, 1, 16), atol=1e-6)
    np.testing.assert_allclose(obs[0, 16:32], 0.2 * qd[0], atol=1e-6)
    np.testing.assert_array_equal(obs[0, BALL_COLUMNS], balls[0])
    np.testing.assert_array_equal(obs[0, 38:], last[0])
    np.testing.assert_array_equal(action_to_target(np.array([-2.0, -1.0, 0.0, 1.0, 2.0]), lo[:5], hi[:5]),
                                  [-1.0, -1.0, 1.0, 3.0, 3.0])
    np.testing.assert_allclose(target_to_action(action_to_target(last, lo, hi), lo, hi), last)


def test_tracking_undoes_a_swap():
    previous = np.array([[0.03, 0.0, 0.05, -0.03, 0.0, 0.05]])
    moved = previous + 0.002
    np.testing.assert_array_equal(track_ball_identities(moved[:, [3, 4, 5, 0, 1, 2]], previous), moved)
    np.testing.assert_array_equal(track_ball_identities(moved, previous), moved)
