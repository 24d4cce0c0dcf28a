"""The late skin's ring: each env gets its own frame that many steps old, and old saved states load."""

import numpy as np

from tacgnn.sim.skin_ring import SkinRing


def _frame(step: int, envs: int = 5, taxels: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """A frame whose every value says the step and env it came from."""
    tactile = (100.0 * step + np.arange(envs, dtype=np.float32))[:, None].repeat(taxels, 1)
    return tactile, tactile[..., None].repeat(3, 2)


def test_each_env_gets_its_frame_of_delay_steps_ago_and_a_reset_repeats_its_first():
    ring, delay = SkinRing(5, 3, 4), np.array([0, 1, 2, 1, 1])
    ring.fill(slice(None), *_frame(0))
    history = [[0.0 + e] * 3 for e in range(5)]  # per env, the frames it has had, oldest first
    for step in range(1, 9):
        tactile, positions = ring.push(*_frame(step), delay)
        for e in range(5):
            history[e].append(100.0 * step + e)
        np.testing.assert_array_equal(tactile[:, 0], [history[e][-1 - d] for e, d in enumerate(delay)])
        np.testing.assert_array_equal(positions[..., 2], tactile)
        if step == 4:  # env 2 resets: its history is the new episode's first frame
            first = _frame(step)[0][[2]] + 0.5
            ring.fill(np.array([2]), first, first[..., None].repeat(3, 2))
            history[2] += [history[2][-1] + 0.5] * 3


def test_a_state_saved_env_by_env_loads_into_the_same_ages():
    """States saved before the ring was stored by age: (N, slots, T) with a head per env."""
    frames = np.arange(2 * 3 * 4, dtype=np.float32).reshape(2, 3, 4)
    head = np.array([0, 2])
    ring = SkinRing(2, 3, 4)
    ring.load_state_dict({"frames": frames, "positions": frames[..., None].repeat(3, 3), "head": head})
    for age in range(3):  # slot (head + age) % 3 of the old layout held the frame `age` steps old
        np.testing.assert_array_equal(ring.frames[(int(ring.head) + age) % 3],
                                      [frames[e, (head[e] + age) % 3] for e in range(2)])
    headless = SkinRing(2, 3, 4)  # older still: no head, newest first from slot 0
    headless.load_state_dict({"frames": frames, "positions": frames[..., None].repeat(3, 3)})
    np.testing.assert_array_equal(headless.frames, frames.transpose(1, 0, 2))
    again = SkinRing(2, 3, 4)
    again.load_state_dict(ring.state_dict())
    for name in SkinRing.STATE:
        np.testing.assert_array_equal(getattr(again, name), getattr(ring, name))
