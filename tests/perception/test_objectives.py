"""Objectives: permutation-invariant ball loss, orientation errors that know symmetry and units."""

import numpy as np
import pytest
import torch

from tacgnn.perception.objectives import Objective, targets


def test_baoding_loss_is_permutation_invariant():
    obj = Objective("baoding")
    target = torch.randn(5, 6)
    swapped = target[:, [3, 4, 5, 0, 1, 2]]
    assert obj.loss(swapped, target) == 0.0
    assert obj.loss(target + 1, target) == pytest.approx(1.0)


@pytest.mark.parametrize("task", ["cube", "meat_can", "cylinder"])
def test_orientation_error_knows_symmetry_and_units(task):
    obj = Objective(task)
    rot = torch.linalg.qr(torch.randn(4, 3, 3))[0]
    rot = rot * torch.sign(torch.det(rot))[:, None, None]
    data = {"object_pos": np.zeros((4, 3)), "object_rot": rot.numpy()}
    target = torch.from_numpy(targets(data, task))
    assert obj.metrics(target, target)["orientation_rmse_deg"] == pytest.approx(0.0, abs=0.1)
    # a 10 degree turn about the object's z axis reads as 10 degrees
    c, s = np.cos(np.radians(10)), np.sin(np.radians(10))
    turned = rot.numpy() @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    if task == "cylinder":  # turning about its own axis is ignored: turn about x instead
        turned = rot.numpy() @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    pred = torch.from_numpy(targets({"object_pos": np.zeros((4, 3)), "object_rot": turned}, task))
    assert obj.metrics(pred, target)["orientation_rmse_deg"] == pytest.approx(10.0, abs=0.1)
    if task == "cube":  # a quarter turn of a cube looks the same
        quarter = rot.numpy() @ np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
        pred = torch.from_numpy(targets({"object_pos": np.zeros((4, 3)), "object_rot": quarter}, task))
        assert obj.metrics(pred, target)["orientation_rmse_deg"] == pytest.approx(0.0, abs=0.1)
