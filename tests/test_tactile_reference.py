"""The fast skin model against a plain reference: random contacts, patch edges, huge forces."""

from dataclasses import replace

import numpy as np
import pytest

from tacgnn.hand.allegro import HandConfig
from tacgnn.hand.skin_layout import SkinLayout, default_skin
from tacgnn.sim.scene import SimConfig, compile_with_skin, hand_scene
from tacgnn.sim.tactile import EDGE_FLOOR, SLOT_SIZE, TactileModel, _CandidateGrid, counter_normal, draw_step_seed


def reference_readings(tactile, sensordata, xpos, xmat, rng=None):
    """The model as the module docstring states it, in float64: each contact against every
    taxel of its patch."""
    layout = tactile.layout
    offsets = layout.offsets()
    force, point = tactile.contacts(sensordata)
    out = np.zeros((len(sensordata), layout.num_taxels))
    for env, p, slot in zip(*np.nonzero(force > 0)):
        patch, body, f = layout.patches[p], tactile.body_ids[p], force[env, p, slot]
        local = xmat[env, body].reshape(3, 3).T @ (point[env, p, slot] - xpos[env, body])
        a = patch.contact_radius * np.cbrt(f)
        d2 = np.sum((patch.local_positions()[0] - local) ** 2, axis=1)
        w = np.sqrt(np.maximum(0.0, 1.0 - d2 / a**2))
        expected = 2 * np.pi * a**2 / (3 * patch.pitch**2)
        out[env, offsets[p]:offsets[p + 1]] += f * w / max(w.sum(), EDGE_FLOOR * expected)
    out[out < layout.threshold] = 0.0
    if rng is not None and layout.noise > 0:
        active = out > 0
        out[active] *= 1.0 + layout.noise * rng.standard_normal(active.sum())
        np.maximum(out, 0.0, out=out)
    return out


def _tactile(skin: SkinLayout) -> TactileModel:
    sim = SimConfig()
    return TactileModel(skin, compile_with_skin(hand_scene(HandConfig(), sim), skin, sim))


def random_state(tactile, num_envs, seed, forces=(0.01, 100.0), reach=3.0):
    """Random link poses and contacts: each slot empty or holding a contact with a log-uniform
    force, near a random taxel (half the time one on the patch's border) and up to `reach`
    pitches from it in any direction, so some lie off the skin and off the lookup grid."""
    rng = np.random.default_rng(seed)
    nbody = int(tactile.body_ids.max()) + 1
    xpos = rng.uniform(-0.3, 0.3, (num_envs, nbody, 3))
    rot = np.linalg.qr(rng.standard_normal((num_envs, nbody, 3, 3)))[0]
    xmat = rot.reshape(num_envs, nbody, 9)
    width = int(tactile.sensor_adr.max()) + tactile.contacts_per_patch * SLOT_SIZE
    sensordata = np.zeros((num_envs, width))
    offsets = tactile.layout.offsets()
    for p, patch in enumerate(tactile.layout.patches):
        cells = patch.grid_cells()
        border = np.flatnonzero((cells[:, 0] == 0) | (cells[:, 0] == patch.rows - 1)
                                | (cells[:, 1] == cells[:, 1].min()) | (cells[:, 1] == cells[:, 1].max()))
        body = tactile.body_ids[p]
        for env in range(num_envs):
            for slot in range(tactile.contacts_per_patch):
                if rng.random() < 0.3:
                    continue
                taxel = rng.choice(border) if rng.random() < 0.5 else rng.integers(patch.size)
                direction = rng.standard_normal(3)
                offset = direction / np.linalg.norm(direction) * rng.uniform(0, reach) * patch.pitch
                local = tactile.local_positions[offsets[p] + taxel] + offset
                adr = tactile.sensor_adr[p] + slot * SLOT_SIZE
                sensordata[env, adr + 1] = np.exp(rng.uniform(*np.log(forces)))
                sensordata[env, adr + 4:adr + 7] = xpos[env, body] + rot[env, body] @ local
    return sensordata, xpos, xmat


def float32_tolerance(tactile, sensordata):
    """The fast path runs in float32. At a disc's rim, w = sqrt(1 - d^2/a^2) turns a rounding
    error of ~1e-7 in d^2/a^2 into up to ~3e-4 in w, i.e. up to 3e-4 F / (k E) in a reading,
    with k E = k (2 pi / 3) (a / pitch)^2 = c F^(2/3)."""
    c = min(np.pi / 3 * (p.contact_radius / p.pitch) ** 2 for p in tactile.layout.patches)
    return 1e-6 + 3e-4 * np.cbrt(tactile.contacts(sensordata)[0].max()) / c


@pytest.fixture(scope="module", params=["compiled", "numpy"])
def tactile(request):
    """Both implementations of the contact spreading: the numba kernel and the numpy path."""
    model = _tactile(replace(default_skin(), threshold=0.0, noise=0.0))
    model.use_compiled = request.param == "compiled"
    return model


def test_compiled_and_numpy_paths_agree_on_a_busy_batch():
    pytest.importorskip("numba")
    tactile = _tactile(replace(default_skin(), threshold=0.0, noise=0.0))
    state = random_state(tactile, num_envs=40, seed=21)
    compiled = tactile.readings(*state)
    tactile.use_compiled = False
    np.testing.assert_allclose(compiled, tactile.readings(*state), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("seed", range(3))
def test_readings_match_the_reference_on_random_contacts(tactile, seed):
    state = random_state(tactile, num_envs=5, seed=seed)
    fast = tactile.readings(*state)
    ref = reference_readings(tactile, *state)
    assert (ref > 0).sum() > 500, "the contacts press many taxels"
    np.testing.assert_allclose(fast, ref, rtol=1e-5, atol=float32_tolerance(tactile, state[0]))


def test_huge_forces_and_far_contacts_match_the_reference(tactile):
    """Discs wider than a whole patch, and contacts up to 20 pitches away from the skin."""
    state = random_state(tactile, num_envs=3, seed=7, forces=(100.0, 1e4), reach=20.0)
    fast = tactile.readings(*state)
    ref = reference_readings(tactile, *state)
    assert (ref > 0).sum(1).max() > 300, "some discs cover whole patches"
    np.testing.assert_allclose(fast, ref, rtol=1e-5, atol=float32_tolerance(tactile, state[0]))


def test_candidates_hold_every_pressed_taxel(tactile):
    """The lookup grid's guarantee, checked directly: all taxels within the contact radius
    are among the contact's candidates (tightly: few others are)."""
    grid = _CandidateGrid(tactile.layout)
    rng = np.random.default_rng(3)
    offsets = tactile.layout.offsets()
    pressed = listed = 0
    for p, patch in enumerate(tactile.layout.patches):
        taxels = tactile.local_positions[offsets[p]:offsets[p + 1]].astype(float)
        local = taxels[rng.integers(patch.size, size=400)] + rng.uniform(-4, 4, (400, 3)) * patch.pitch
        radius = patch.contact_radius * np.cbrt(np.exp(rng.uniform(np.log(0.01), np.log(1e3), 400)))
        first, count = grid.lookup(np.full(400, p), local, radius)
        for point, a, start, n in zip(local, radius, first, count):
            inside = offsets[p] + np.flatnonzero(np.linalg.norm(taxels - point, axis=1) < a)
            assert set(inside) <= set(grid.order[start:start + n])
            pressed += len(inside)
            listed += n
    assert listed < 2 * pressed


def test_threshold_and_noise_match_the_reference():
    tactile = _tactile(default_skin())
    state = random_state(tactile, num_envs=4, seed=11)
    clean = tactile.readings(*state)
    ref = reference_readings(tactile, *state)
    tol = float32_tolerance(tactile, state[0])
    near_threshold = np.abs(ref - tactile.layout.threshold) < tol  # may round either way
    np.testing.assert_allclose(clean[~near_threshold], ref[~near_threshold], rtol=1e-5, atol=tol)
    # noise: each active reading times 1 + noise * the counter-based draw of its flat index
    noisy = tactile.readings(*state, np.random.default_rng(5))
    active = clean > 0
    draws = counter_normal(draw_step_seed(np.random.default_rng(5)), np.flatnonzero(active))
    factor = 1.0 + tactile.layout.noise * draws
    np.testing.assert_array_equal(noisy[active], np.maximum(clean[active] * factor, 0.0))
    assert not noisy[~active].any()


def test_noisy_readings_of_both_paths_agree():
    """The same seed gives the same noisy readings on either path (counter-based draws)."""
    tactile = _tactile(default_skin())
    state = random_state(tactile, num_envs=5, seed=12)
    compiled = tactile.readings(*state, np.random.default_rng(9))
    tactile.use_compiled = False
    numpy_path = tactile.readings(*state, np.random.default_rng(9))
    np.testing.assert_allclose(compiled, numpy_path, rtol=1e-5, atol=1e-6)
    assert (compiled > 0).sum() > 10
    assert not np.array_equal(compiled, tactile.readings(*state))  # the noise is on


def test_another_layout_matches_the_reference():
    skin = replace(default_skin().with_pitch_scale(0.8), threshold=0.0, noise=0.0)
    tactile = _tactile(skin)
    state = random_state(tactile, num_envs=3, seed=2)
    np.testing.assert_allclose(tactile.readings(*state), reference_readings(tactile, *state),
                               rtol=1e-5, atol=float32_tolerance(tactile, state[0]))


def test_positions_match_the_rigid_transform(tactile):
    """130 envs: more than one block of envs per GEMM, the last one partial."""
    _, xpos, xmat = random_state(tactile, num_envs=130, seed=4)
    fast = tactile.positions(xpos, xmat)
    body = tactile.body_ids[tactile.patch_of_taxel]
    rot = xmat[:, body].reshape(130, -1, 3, 3)
    ref = xpos[:, body] + np.einsum("ntij,tj->nti", rot, tactile.local_positions.astype(float))
    assert fast.dtype == np.float32
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-6)


def test_counter_normal_draws_are_independent_standard_normals():
    seed = draw_step_seed(np.random.default_rng(0))
    x = counter_normal(seed, np.arange(400_000)).astype(float)
    # neighbouring taxels, and the same taxels in the next step, are uncorrelated
    assert abs(np.corrcoef(x[:-1], x[1:])[0, 1]) < 0.01
    y = counter_normal(draw_step_seed(np.random.default_rng(1)), np.arange(400_000)).astype(float)
    assert abs(np.corrcoef(x, y)[0, 1]) < 0.01
    assert abs(x.mean()) < 0.01 and abs(x.std() - 1.0) < 0.01
    # quantiles of N(0, 1): 2.5 % and 97.5 % at -+1.96, 16 % at -1
    np.testing.assert_allclose(np.quantile(x, [0.025, 0.16, 0.5, 0.84, 0.975]),
                               [-1.96, -0.994, 0.0, 0.994, 1.96], atol=0.02)
    assert np.abs(x).max() < 4.5  # the table's tails end at 4.3 sigma
