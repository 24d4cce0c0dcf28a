"""Evaluation: test-split errors, dead taxels, a whole patch lost, the touched / untouched split."""

import pytest
import torch

from tacgnn.hand.skin_layout import default_skin
from tacgnn.perception.data import TactileData
from tacgnn.perception.evaluation import (
    ball_errors,
    dead_taxels,
    evaluate,
    patch_loss,
    patch_taxels,
)
from tacgnn.perception.train_config import PerceptionTrainConfig
from tacgnn.perception.training import train


@pytest.fixture(scope="module")
def checkpoint(dataset, tmp_path_factory):
    run = tmp_path_factory.mktemp("run")
    train(PerceptionTrainConfig.for_task("baoding", "tacgnn", epochs=1, threads=1), dataset, run,
          log=lambda *_: None)
    return run / "checkpoint.pt"


def test_patch_taxels_follow_the_skin_vector():
    skin = default_skin()
    assert torch.equal(patch_taxels(skin, "palm"), torch.arange(113))
    assert torch.equal(patch_taxels(skin, "index_tip"), torch.arange(113, 113 + 72))
    with pytest.raises(ValueError, match="no skin patch named 'sole'.*palm"):
        patch_taxels(skin, "sole")


def test_dead_taxels():
    dead = dead_taxels(653, 0.1, seed=3)
    assert len(dead) == 65 and len(dead.unique()) == 65
    assert torch.equal(dead, dead_taxels(653, 0.1, seed=3))
    for bad in (-0.1, 1.5):
        with pytest.raises(ValueError, match="dead taxel fraction"):
            dead_taxels(653, bad, seed=0)


def test_evaluate_with_dead_taxels(checkpoint, dataset):
    intact = evaluate(checkpoint, dataset)
    assert set(intact) >= {"position_rmse_cm", "touched_rmse_cm", "untouched_rmse_cm", "untouched_fraction"}
    all_dead = evaluate(checkpoint, dataset, dead_fraction=1.0)
    assert all_dead["untouched_fraction"] == 1.0  # no taxel reads anything: every ball is untouched
    assert all_dead["position_rmse_cm"] != intact["position_rmse_cm"]


def test_losing_a_whole_patch(checkpoint, dataset):
    """The palm carries most contacts: losing it changes the error. Losing a patch never makes a
    ball touched."""
    palm = patch_loss(checkpoint, dataset, "palm")
    assert palm["position_rmse_cm_without_palm"] == pytest.approx(
        evaluate(checkpoint, dataset, lost_patch="palm")["position_rmse_cm"])
    assert palm["rmse_ratio"] == pytest.approx(palm["position_rmse_cm_without_palm"] / palm["position_rmse_cm"])
    assert palm["rmse_ratio"] != pytest.approx(1.0)
    assert palm["untouched_fraction_without_palm"] > palm["untouched_fraction"]
    # a lost patch can only turn touched balls into untouched ones
    thumb = patch_loss(checkpoint, dataset, "thumb_medial")
    assert thumb["untouched_fraction_without_thumb_medial"] >= thumb["untouched_fraction"]
    with pytest.raises(ValueError, match="no skin patch named 'wrist'"):
        patch_loss(checkpoint, dataset, "wrist")


def test_ball_visibility_split():
    """Ball 0 has an activated taxel at its surface, ball 1 none: errors land in the right group."""
    positions = torch.zeros(2, 3, 3)
    positions[:, 0] = torch.tensor([0.0, 0.0, -2.6])  # under ball 0 (centre at 0)
    positions[:, 1] = torch.tensor([20.0, 0.0, 0.0])  # active, but far from both balls
    readings = torch.tensor([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
    positions[:, 2] = torch.tensor([6.0, 0.0, -2.6])  # under ball 1, but not active
    targets = torch.tensor([[0.0, 0, 0, 6, 0, 0]] * 2)
    pred = targets + torch.tensor([[0.1, 0.1, 0.1, 1.0, 1.0, 1.0]])
    se, touch, swap = ball_errors(pred, TactileData(readings, positions, targets), match_balls=False)
    assert touch.tolist() == [[True, False]] * 2 and not swap.any()
    assert se[touch].mean().sqrt() == pytest.approx(0.1) and se[~touch].mean().sqrt() == pytest.approx(1.0)
    # with matching, a prediction of the balls in swapped order is scored against the swap
    swapped = pred[:, [3, 4, 5, 0, 1, 2]]
    se, touch, swap = ball_errors(swapped, TactileData(readings, positions, targets), match_balls=True)
    assert swap.all() and touch.tolist() == [[False, True]] * 2
    assert se[touch].mean().sqrt() == pytest.approx(0.1)
