"""Taxels at rest: from the hand and its skin layout alone, as the simulator places them."""

import mujoco
import numpy as np
import torch

from tacgnn.config import to_dict
from tacgnn.hand.allegro import HandConfig
from tacgnn.hand.skin_layout import default_skin
from tacgnn.perception.rest_positions import rest_positions, rest_positions_cm


def test_equal_to_the_simulators_taxels_at_zero_joint_angles():
    """Bit for bit: the GCN's kNN graph on the grids depends on the last bit of a distance."""
    from tacgnn.sim.scene import SimConfig, compile_with_skin, hand_scene
    from tacgnn.sim.tactile import TactileModel

    skin, sim = default_skin(), SimConfig()
    model = compile_with_skin(hand_scene(HandConfig(), sim), skin, sim)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    expected = TactileModel(skin, model).positions(data.xpos[None], data.xmat[None])[0]
    assert np.array_equal(rest_positions(skin), expected)


def test_cm_from_a_layout_or_its_dict():
    skin = default_skin()
    cm = rest_positions_cm(to_dict(skin))
    assert cm.shape == (skin.num_taxels, 3) and cm.dtype == torch.float32
    assert torch.equal(cm, rest_positions_cm(skin))
    assert torch.equal(cm, torch.from_numpy(rest_positions(skin) * 100.0))
