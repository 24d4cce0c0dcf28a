"""Where the taxels are when the hand is at rest: the GCN's fixed graph and rest node positions.

The skin layout gives every taxel in its link's frame; the hand model gives where each link
is at zero joint angles. Only the hand is compiled (no scene, sensors or objects), so
perception depends on the hand and its skin, not on the simulator.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from tacgnn.config import from_dict
from tacgnn.hand.allegro import HandConfig, add_hand
from tacgnn.hand.skin_layout import SkinLayout

CM = 100.0


def rest_positions(skin: SkinLayout, hand: HandConfig | None = None) -> np.ndarray:
    """(T, 3) float32 world positions (m) of the skin's taxels with every joint at 0 rad.

    A taxel at ``p`` in its link's frame is at ``x_link + R_link p`` in the world, computed
    in float32 as the simulator's tactile model computes it (one product of the link pose
    ``[R (row-major) | x]`` with a per-patch matrix): on the regular grid several neighbours
    lie at exactly the same distance, and a rounding difference would change which of them
    the GCN's kNN graph keeps.
    """
    spec = mujoco.MjSpec()
    spec.compiler.degree = False
    add_hand(spec, hand or HandConfig())
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    out = []
    for patch in skin.patches:
        body = model.body(patch.body).id
        local = patch.local_positions()[0]
        pose = np.concatenate([data.xmat[body], data.xpos[body]]).astype(np.float32)[None]  # (1, 12)
        pose_map = np.vstack([np.einsum("ik,tj->ijtk", np.eye(3), local).reshape(9, -1),
                              np.tile(np.eye(3), len(local))]).astype(np.float32)  # (12, 3 n)
        out.append((pose @ pose_map).reshape(-1, 3))
    return np.concatenate(out)


def rest_positions_cm(skin: SkinLayout | dict, hand: HandConfig | None = None) -> torch.Tensor:
    """:func:`rest_positions` in cm as a tensor, from a layout or its dict (a dataset's metadata)."""
    if not isinstance(skin, SkinLayout):
        skin = from_dict(SkinLayout, skin)
    return torch.from_numpy(rest_positions(skin, hand) * CM)
