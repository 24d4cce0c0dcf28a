"""The skin layout: the paper's 653 taxels, in the authors' order, on the link surfaces."""

import mujoco
import numpy as np
import pytest

from tacgnn.config import ConfigError
from tacgnn.hand.allegro import HandConfig
from tacgnn.hand.skin_layout import PALM_COLUMN_COUNTS, Patch, SkinLayout, default_skin
from tacgnn.sim.scene import SimConfig, compile_with_skin, hand_scene
from tacgnn.sim.tactile import TactileModel

EXPECTED_ORDER = [
    ("palm", 113),
    ("index_tip", 72), ("index_medial", 36), ("index_proximal", 36),
    ("middle_tip", 72), ("middle_medial", 36), ("middle_proximal", 36),
    ("ring_tip", 72), ("ring_medial", 36), ("ring_proximal", 36),
    ("thumb_tip", 72), ("thumb_medial", 36),
]


def test_paper_skin_has_653_taxels_in_authors_order():
    skin = default_skin()
    assert skin.num_taxels == 653
    assert [(p.name, p.size) for p in skin.patches] == EXPECTED_ORDER
    assert list(skin.offsets()) == list(np.cumsum([0] + [n for _, n in EXPECTED_ORDER]))
    palm_rows = skin.patches[0].grid_cells()[:, 0]
    assert tuple(np.bincount(palm_rows)) == PALM_COLUMN_COUNTS


def _model(skin=None):
    skin = skin or default_skin()
    sim = SimConfig()
    return compile_with_skin(hand_scene(HandConfig(), sim), skin, sim), skin


def _distance_to_geoms(model, data, body_id, points):
    """Distance from each point to the nearest surface of the body's geoms (ray-free, by geom type)."""
    best = np.full(len(points), np.inf)
    for g in np.flatnonzero(model.geom_bodyid == body_id):
        rot, centre, size = data.geom_xmat[g].reshape(3, 3), data.geom_xpos[g], model.geom_size[g]
        local = (points - centre) @ rot
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
            q = np.abs(local) - size
            dist = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0)
        else:  # capsule
            z = np.clip(local[:, 2], -size[1], size[1])
            dist = np.linalg.norm(local - np.stack([0 * z, 0 * z, z], 1), axis=1) - size[0]
        best = np.minimum(best, np.abs(dist))
    return best


def test_taxels_lie_on_their_links_surface_and_move_with_them():
    model, skin = _model()
    data = mujoco.MjData(model)
    tactile = TactileModel(skin, model)
    offsets = skin.offsets()
    for qpos in (np.zeros(16), np.full(16, 0.4)):
        data.qpos[:16] = qpos
        mujoco.mj_forward(model, data)
        pos = tactile.positions(data.xpos[None], data.xmat[None])[0]
        for p, patch in enumerate(skin.patches):
            dist = _distance_to_geoms(model, data, tactile.body_ids[p], pos[offsets[p]:offsets[p + 1]])
            assert dist.max() < 1e-3, (patch.name, dist.max())
    # moving one joint moves exactly the taxels downstream of it
    data.qpos[:16] = 0
    mujoco.mj_forward(model, data)
    before = tactile.positions(data.xpos[None], data.xmat[None])[0]
    data.qpos[2] = 0.5  # index j2: medial and distal move
    mujoco.mj_forward(model, data)
    after = tactile.positions(data.xpos[None], data.xmat[None])[0]
    moved = np.linalg.norm(after - before, axis=1) > 1e-6
    names = [skin.patches[i].name for i in np.unique(skin.patch_index()[moved])]
    assert names == ["index_tip", "index_medial"]


def test_patch_validation_names_the_problem():
    with pytest.raises(ConfigError, match="pitch"):
        Patch(name="p", body="palm", surface="plane", rows=2, cols=2, pitch=-1.0, origin=(0, 0, 0))
    with pytest.raises(ConfigError, match="row_counts"):
        Patch(name="p", body="palm", surface="plane", rows=2, cols=2, pitch=0.01, origin=(0, 0, 0),
              row_counts=(1, 2, 3))
    with pytest.raises(ConfigError, match="repeat"):
        p = default_skin().patches[0]
        SkinLayout(patches=(p, p))


def test_patch_on_missing_link_is_rejected():
    bad = Patch(name="wrist", body="wrist_link", surface="plane", rows=2, cols=2, pitch=0.01,
                origin=(0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="wrist_link"):
        _model(SkinLayout(patches=(bad,)))


def test_another_layout_needs_no_code_change():
    skin = SkinLayout(patches=tuple(p for p in default_skin().with_pitch_scale(1.05).patches
                                    if p.body != "palm"))
    model, skin = _model(skin)
    tactile = TactileModel(skin, model)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert tactile.positions(data.xpos[None], data.xmat[None]).shape == (1, 540, 3)
