"""Errors of a trained perception model: on a test split, with dead taxels, without a whole patch,
and split by whether the skin touches each ball."""

from __future__ import annotations

from pathlib import Path

import torch

from tacgnn.config import ConfigError, from_dict
from tacgnn.datasets.store import DatasetError, read_manifest
from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.perception.checkpoint import load_model
from tacgnn.perception.data import TactileData, load_tactile, split
from tacgnn.perception.models import PerceptionModel
from tacgnn.perception.objectives import Objective


@torch.no_grad()
def predict(model: PerceptionModel, data: TactileData, batch: int = 1024) -> torch.Tensor:
    """The model's outputs for every frame, in eval mode, `batch` frames at a time."""
    model.eval()
    return torch.cat([model(*data.batch(slice(i, i + batch))) for i in range(0, len(data), batch)])


def patch_taxels(skin: SkinLayout | dict, patch: str) -> torch.Tensor:
    """Indices of one patch's taxels in the skin vector (e.g. ``"palm"``)."""
    if not isinstance(skin, SkinLayout):
        skin = from_dict(SkinLayout, skin)
    names = [p.name for p in skin.patches]
    if patch not in names:
        raise ConfigError(f"no skin patch named {patch!r}; the skin has {', '.join(names)}")
    i = names.index(patch)
    start, stop = skin.offsets()[i:i + 2]
    return torch.arange(int(start), int(stop))


def dead_taxels(num_taxels: int, fraction: float, seed: int) -> torch.Tensor:
    """A seeded random ``round(fraction * T)`` of the taxels, as a broken skin would lose them."""
    if not 0.0 <= fraction <= 1.0:
        raise ConfigError(f"the dead taxel fraction must be in [0, 1], got {fraction}")
    gen = torch.Generator().manual_seed(seed)
    return torch.randperm(num_taxels, generator=gen)[:int(round(fraction * num_taxels))]


def without_taxels(data: TactileData, taxels: torch.Tensor) -> TactileData:
    """The frames with these taxels reading 0 in every frame."""
    readings = data.readings.clone()
    readings[:, taxels] = 0.0
    return data.with_readings(readings)


def evaluate(checkpoint: str | Path, dataset: str | Path, dead_fraction: float = 0.0, seed: int = 0,
             whole: bool = False, lost_patch: str | None = None) -> dict:
    """Errors of a trained model on a dataset's test split (or all of it with `whole`).

    `dead_fraction` zeroes that share of the taxels (the same ones in every frame), as a
    real skin with broken taxels would read; `lost_patch` zeroes every taxel of one patch
    of the dataset's skin (e.g. "palm").
    """
    model, cfg, _ = load_model(checkpoint)
    test = _test_frames(cfg, dataset, whole)
    if dead_fraction > 0:
        test = without_taxels(test, dead_taxels(test.readings.shape[1], dead_fraction, seed))
    if lost_patch is not None:
        test = without_taxels(test, patch_taxels(read_manifest(dataset)["metadata"]["skin"], lost_patch))
    torch.set_num_threads(cfg.threads)
    return _metrics(model, cfg, test)


def patch_loss(checkpoint: str | Path, dataset: str | Path, patch: str, whole: bool = False) -> dict:
    """Errors with and without one whole patch of the skin, and their ratio.

    Returns the intact metrics, the same metrics with every taxel of `patch` reading 0
    (keys suffixed ``_without_<patch>``), and ``rmse_ratio`` = position RMSE without the
    patch / intact position RMSE.
    """
    model, cfg, _ = load_model(checkpoint)
    test = _test_frames(cfg, dataset, whole)
    lost = without_taxels(test, patch_taxels(read_manifest(dataset)["metadata"]["skin"], patch))
    torch.set_num_threads(cfg.threads)
    intact, without = _metrics(model, cfg, test), _metrics(model, cfg, lost)
    before, after = intact["position_rmse_cm"], without["position_rmse_cm"]
    return {**intact, **{f"{k}_without_{patch}": v for k, v in without.items()},
            "rmse_ratio": after / before if before > 0 else float("nan")}


def _test_frames(cfg, dataset: str | Path, whole: bool) -> TactileData:
    """The frames a training run never saw: its test split (same max_samples), or all frames."""
    data = load_tactile(dataset, cfg.task, 0 if whole else cfg.max_samples, joints=cfg.model.joint_inputs > 0)
    if data.readings.shape[1] != cfg.model.num_taxels:
        raise DatasetError(f"{dataset}: has {data.readings.shape[1]} taxels, the model was trained on "
                         f"{cfg.model.num_taxels}")
    return data if whole else split(data, cfg.train_fraction, cfg.seed)[1]


def _metrics(model: PerceptionModel, cfg, data: TactileData) -> dict:
    pred = predict(model, data)
    metrics = Objective(cfg.task, cfg.match_balls).metrics(pred, data.targets)
    if cfg.task == "baoding":
        metrics.update(ball_visibility_errors(pred, data, cfg.match_balls))
    return metrics


def ball_visibility_errors(pred: torch.Tensor, data: TactileData, match_balls: bool,
                           seen_within_cm: float = 3.0) -> dict:
    """Baoding: position RMSE (cm) of balls the skin touches and of balls it does not.

    A ball is "seen" when an activated taxel lies within `seen_within_cm` of its centre
    (the balls' radius is 2.6 cm), "blind" otherwise: it rests on the other ball or on
    a part of the hand without skin, and only indirect cues place it. With the
    permutation-invariant loss the better ball assignment of each frame is used.
    """
    t = data.targets
    if match_balls:
        swapped = t[:, [3, 4, 5, 0, 1, 2]]
        use = ((pred - swapped) ** 2).sum(1) < ((pred - t) ** 2).sum(1)
        t = torch.where(use[:, None], swapped, t)
    active = data.readings > 0
    se: dict[bool, list[torch.Tensor]] = {True: [], False: []}
    for b in range(2):
        centre = t[:, None, 3 * b:3 * b + 3]
        nearest = (data.positions - centre).norm(dim=-1).masked_fill(~active, float("inf")).amin(1)
        err = ((pred[:, 3 * b:3 * b + 3] - t[:, 3 * b:3 * b + 3]) ** 2).mean(1)
        seen = nearest < seen_within_cm
        se[True].append(err[seen])
        se[False].append(err[~seen])
    seen_err, blind_err = torch.cat(se[True]), torch.cat(se[False])

    def rmse(e: torch.Tensor) -> float:
        return float(e.mean().sqrt()) if len(e) else float("nan")

    return {"seen_rmse_cm": rmse(seen_err), "blind_rmse_cm": rmse(blind_err),
            "blind_fraction": len(blind_err) / (len(seen_err) + len(blind_err))}
