"""The control tick's networks on the ROS loop's receive threads give what they give anywhere else."""

import threading

import numpy as np
import pytest
import torch
from real_policy import blind_policy

from tacgnn.real import BlindController, BlindControllerConfig

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def policy_file(tmp_path_factory):
    return blind_policy(tmp_path_factory.mktemp("policy"))


def frames(num_taxels, rng):
    """Skin frames: empty, lone and few contacts, many, and equal readings."""
    for n in (0, 1, 2, 3, 5, 12, 40, 150, num_taxels):
        for ties in (False, True):
            readings = np.zeros(num_taxels, np.float32)
            active = rng.choice(num_taxels, n, replace=False)
            readings[active] = rng.exponential(0.5, n).astype(np.float32) + 1e-7
            if ties and n > 4:
                readings[active[1]] = readings[active[0]]
            yield n, readings


def test_controller_steps_are_the_same_on_a_fresh_thread(policy_file):
    """Torch sets a thread's threads up lazily: a thread's first tick must round as any other."""
    here = BlindController(BlindControllerConfig(policy=str(policy_file)))
    there = BlindController(BlindControllerConfig(policy=str(policy_file)))
    rng = np.random.default_rng(6)
    q = (here.joint_low + here.joint_high) / 2
    for step, (n, readings) in enumerate(frames(here.num_taxels, rng)):
        pose, vel = q + rng.normal(0, 0.05, q.shape), rng.normal(0, 0.5, q.shape)
        expected = here.step(pose, vel, readings)
        got: list = []
        thread = threading.Thread(target=lambda out, *a: out.append(there.step(*a)), args=(got, pose, vel, readings))
        thread.start()
        thread.join()
        np.testing.assert_array_equal(got[0], expected, err_msg=f"step {step}, {n} active taxels")
