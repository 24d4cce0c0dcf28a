"""The control tick's single-frame networks give exactly what the loaded networks give."""

import numpy as np
import pytest
import torch
from real_policy import blind_policy

from tacgnn.learning.policy import load_perception, load_policy
from tacgnn.real import BlindController, BlindControllerConfig
from tacgnn.real.tick_networks import TickPerception, TickPolicy

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def policy_file(tmp_path_factory):
    return blind_policy(tmp_path_factory.mktemp("policy"))


def frames(num_taxels, rng):
    """One-frame inputs: empty, lone and few contacts, many, and taxels sharing a position (ties)."""
    for n in (0, 1, 2, 3, 5, 12, 40, 150, num_taxels):
        for ties in (False, True):
            readings = np.zeros((1, num_taxels), np.float32)
            active = rng.choice(num_taxels, n, replace=False)
            readings[0, active] = rng.exponential(0.5, n).astype(np.float32) + 1e-7
            positions = rng.uniform(-0.08, 0.08, (1, num_taxels, 3)).astype(np.float32)
            if ties and n > 4:
                positions[0, active[:3]] = positions[0, active[3]]
                readings[0, active[1]] = readings[0, active[0]]
            yield n, readings, positions


def test_tick_perception_is_bit_identical_to_the_model(policy_file):
    perception = load_perception(policy_file)
    tick = TickPerception.wrap(perception)
    assert isinstance(tick, TickPerception)  # the shipped TacGNN takes the fast path
    rng = np.random.default_rng(3)
    for n, readings, positions in frames(tick.num_taxels, rng):
        np.testing.assert_array_equal(tick(readings, positions), perception(readings, positions),
                                      err_msg=f"{n} active taxels")
    batch = np.concatenate([f[1] for f in list(frames(tick.num_taxels, rng))[:3]])
    pos = np.concatenate([f[2] for f in list(frames(tick.num_taxels, rng))[:3]])
    np.testing.assert_array_equal(tick(batch, pos), perception(batch, pos))  # batches: the model itself


def test_tick_perception_leaves_other_models_alone(policy_file):
    perception = load_perception(policy_file)
    perception.model.cfg = perception.model.cfg.__class__(**{**vars(perception.model.cfg), "exact_graph": True})
    assert TickPerception.wrap(perception) is perception  # the torch graph builder: not covered


def test_tick_policy_gives_the_loaded_policys_actions(policy_file):
    policy, _ = load_policy(policy_file)
    tick = TickPolicy.wrap(policy, str(policy_file))
    assert isinstance(tick, TickPolicy)
    obs = np.random.default_rng(4).normal(0, 2, (64, tick.obs_dim)).astype(np.float32)
    np.testing.assert_array_equal(tick(obs), policy(obs))
    for row in obs[:8]:
        np.testing.assert_array_equal(tick(row[None]), policy(row[None]))
    with pytest.raises(ValueError, match="observations"):
        tick(obs[:, :5])


def test_controller_commands_are_unchanged_by_the_tick_networks(policy_file):
    fast = BlindController(BlindControllerConfig(policy=str(policy_file)))
    slow = BlindController(BlindControllerConfig(policy=str(policy_file), tick_networks=False))
    assert isinstance(fast.perception, TickPerception) and not isinstance(slow.perception, TickPerception)
    rng = np.random.default_rng(5)
    q = (fast.joint_low + fast.joint_high) / 2
    for step, (_, readings, _) in enumerate(frames(fast.num_taxels, rng)):
        pose = q + rng.normal(0, 0.05, q.shape)
        vel = rng.normal(0, 0.5, q.shape)
        np.testing.assert_array_equal(fast.step(pose, vel, readings[0]), slow.step(pose, vel, readings[0]),
                                      err_msg=f"step {step}")


def test_tick_networks_give_the_same_outputs_on_a_fresh_thread(policy_file):
    """The ROS loop ticks on its receive threads: a thread's first call must round as any other."""
    import threading

    perception = TickPerception.wrap(load_perception(policy_file))
    policy = TickPolicy.wrap(load_policy(policy_file)[0], str(policy_file))
    rng = np.random.default_rng(6)
    inputs = [(r, p) for _ in range(4) for _, r, p in frames(perception.num_taxels, rng)]
    obs = rng.normal(0, 2, (len(inputs), policy.obs_dim)).astype(np.float32)
    expected = [(perception(r, p), policy(o[None])) for (r, p), o in zip(inputs, obs)]
    got = []
    for (r, p), o in zip(inputs, obs):
        thread = threading.Thread(target=lambda r=r, p=p, o=o: got.append((perception(r, p), policy(o[None]))))
        thread.start()
        thread.join()
    for k, ((pe, ae), (pg, ag)) in enumerate(zip(expected, got)):
        np.testing.assert_array_equal(pg, pe, err_msg=f"perception, frame {k}")
        np.testing.assert_array_equal(ag, ae, err_msg=f"policy, frame {k}")
