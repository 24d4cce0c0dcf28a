"""User errors on every sub-command: one line on stderr naming the file, key or value, exit code 2,
no traceback; ``--debug`` shows the traceback; a bug (not a user error) still raises."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tacgnn.cli import main
from tacgnn.config import ConfigError
from tacgnn.learning.policy import SHIPPED_GROUND_TRUTH, SHIPPED_POLICY


def _one_line_error(capsys, argv: list[str], *expected: str) -> str:
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    for text in expected:
        assert text in err, err
    return err


@pytest.mark.parametrize("argv, expected", [
    (["config", "--set", "task=[1,"], ["'task'", "cannot parse"]),
    (["config", "--set", "control_dt=0.013"], ["'control_dt'", "sim.timestep"]),
    (["config", "--set", "control_dt=-0.5"], ["'control_dt'"]),
    (["config", "--set", "num_envs=10000000"], ["'num_envs'"]),
    (["config", "--set", "sim.nthread=100000"], ["'sim.nthread'"]),
    (["config", "--set", "ball_mass=.nan"], ["'ball_mass'", "finite"]),
    (["config", "--set", "hand.stiffness=[1, 2]"], ["'hand.stiffness'"]),
    (["config", "--set", "hand.bogus=1"], ["'hand.bogus'"]),
    (["config", "--set", "=3"], ["no key"]),
    (["render", "--set", "spawn_offsets=[[0, 0, 0]]"], ["'spawn_offsets'"]),
    (["render", "--out", "/dev/null/x.mp4"], ["/dev/null"]),
    (["make-dataset", "baoding", "--out", "/dev/null/ds", "--samples", "10", "--shard-size", "10"], ["/dev/null"]),
    (["make-dataset", "baoding", "--out", "unused", "--samples", "100", "--shard-size", "30"], ["'samples'"]),
    (["make-dataset", "grasp", "--out", "unused", "--set", "settle_steps=0"], ["'settle_steps'"]),
    (["make-dataset", "baoding", "--out", "unused", "--policy", str(SHIPPED_GROUND_TRUTH), "--set",
      "ball_order=canonical"],
     ["trained with ball_order=as_simulated", "--set ball_order=as_simulated"]),
    (["make-dataset", "baoding", "--out", "unused", "--policy", str(SHIPPED_GROUND_TRUTH), "--set",
      "ball_velocity=true"],
     ["trained with ball_velocity=False", "--set ball_velocity=false"]),
    (["evaluate", str(SHIPPED_GROUND_TRUTH), "--episodes", "1", "--set", "ball_velocity=true"],
     ["trained with ball_velocity=False", "--set ball_velocity=false"]),
    (["evaluate", str(SHIPPED_GROUND_TRUTH), "--episodes", "1", "--set", "target_band_rad=0.2"],
     ["trained with target_band_rad=0.0", "--set target_band_rad=0.0"]),
    (["evaluate", str(SHIPPED_GROUND_TRUTH), "--episodes", "1", "--set", "target_band_rad=-1"], ["'target_band_rad'"]),
    (["train-perception", "--dataset", "x", "--run", "y", "--set", "threads=0"], ["'threads'"]),
    (["train-perception", "--dataset", "x", "--run", "y", "--set", "model.channels=-3"], ["'model.channels'"]),
    (["train-perception", "--dataset", "/no/such/dataset", "--run", "y"], ["/no/such/dataset"]),
    (["sysid", "--set", "refine_passes=-1"], ["'refine_passes'"]),
    (["sysid", "/no/such/recording.npz"], ["/no/such/recording.npz"]),
    (["train-policy", "--ppo", "value_loss_coef=-1"], ["'value_loss_coef'"]),
    (["train-policy", "--ppo", "torch_threads=100000"], ["'torch_threads'"]),
    (["train-policy", "--env", "control_dt=-0.5"], ["'control_dt'"]),
    (["train-policy", "--env", "obs_mode=perceived", "--perception", "model.k={a"], ["'model.k'"]),
    (["train-policy", "--env", "obs_mode=perceived", "--perception", "model.channels=0"], ["'model.channels'"]),
    (["evaluate", "/no/such/policy.pt"], ["/no/such/policy.pt"]),
    (["eval-perception", "--checkpoint", "/no/such/model.pt", "--dataset", "x"], ["/no/such/model.pt"]),
    (["export-policy", "/no/such/policy.pt", "--out", "p.pt"], ["/no/such/policy.pt"]),
    (["export-policy", str(SHIPPED_GROUND_TRUTH), "--out", "p.pt", "--perception", str(SHIPPED_GROUND_TRUTH)],
     ["baoding_gt_policy.pt", "without a perception"]),
    (["export-policy", str(SHIPPED_POLICY), "--out", "p.pt", "--perception", str(SHIPPED_GROUND_TRUTH)],
     ["baoding_gt_policy.pt", "not a tacgnn perception checkpoint"]),
    (["export-policy", str(SHIPPED_POLICY), "--out", "/dev/null/p.pt"], ["/dev/null"]),
    (["make-dataset", "baoding", "--out", "unused", "--policy", str(SHIPPED_POLICY), "--set", "target_band_rad=0.2"],
     ["target_band_rad"]),
])
def test_user_errors_are_one_line_with_exit_code_2(capsys, tmp_path, monkeypatch, argv, expected):
    monkeypatch.chdir(tmp_path)
    _one_line_error(capsys, argv, *expected)


def test_a_config_file_is_named_in_its_errors(capsys, tmp_path):
    missing = tmp_path / "missing.yaml"
    _one_line_error(capsys, ["config", "--config", str(missing)], str(missing))
    broken = tmp_path / "broken.yaml"
    broken.write_text("sim: {timestep: 0.005\n")
    _one_line_error(capsys, ["config", "--config", str(broken)], str(broken), "not valid YAML")
    typo = tmp_path / "typo.yaml"
    typo.write_text("sim:\n  timestpe: 0.004\n")
    _one_line_error(capsys, ["config", "--config", str(typo)], str(typo), "'sim.timestpe'", "sim.timestep")
    good = tmp_path / "good.yaml"
    good.write_text("ball_mass: 1e-1\n")  # YAML 1.2 float, not the string '1e-1'
    assert main(["config", "--config", str(good)]) == 0
    assert "ball_mass: 0.1" in capsys.readouterr().out


@pytest.mark.parametrize("dead", ["1.5", "-0.1", "nan", "half"])
def test_dead_fraction_outside_0_1_is_refused_naming_it(capsys, dead):
    with pytest.raises(SystemExit) as exit_:
        main(["eval-perception", "--checkpoint", "x.pt", "--dataset", "x", "--dead", "0.1", dead])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "--dead" in err and dead in err and len(err.strip().splitlines()) == 1


def test_debug_shows_the_traceback_and_bugs_are_not_hidden(monkeypatch):
    with pytest.raises(ConfigError, match="num_envs"):
        main(["config", "--set", "num_envs=0", "--debug"])
    from tacgnn.cli import simulation

    def broken(args):
        raise KeyError("a bug")

    monkeypatch.setattr(simulation, "cmd_config", broken)
    with pytest.raises(KeyError):
        main(["config"])


@pytest.fixture(scope="module")
def perception_run(tmp_path_factory):
    """A synthetic Baoding dataset and an MLP trained on it for one epoch."""
    from tacgnn.datasets import baoding_data
    from tacgnn.datasets.store import ShardedWriter

    root = tmp_path_factory.mktemp("cli") / "data"
    rng = np.random.default_rng(0)
    schema = baoding_data.schema(653)

    def shard(i):
        n = 64
        arrays = {name: np.zeros((n, *field.shape)) for name, field in schema.items()}
        arrays["tactile"] = rng.uniform(0, 1, (n, 653)) * (rng.uniform(size=(n, 653)) < 0.02)
        arrays["taxel_pos"] = rng.normal(0, 0.05, (n, 653, 3))
        arrays["ball_pos"] = rng.normal(0, 0.03, (n, 2, 3))
        return arrays

    ShardedWriter(root, schema, {"kind": "baoding", "num_taxels": 653}, num_shards=2,
                  shard_size=64).generate_missing(shard)
    run = root.parent / "run"
    assert main(["train-perception", "--model", "mlp", "--dataset", str(root), "--run", str(run), "--epochs", "1"]) == 0
    return root, run / "checkpoint.pt"


@pytest.mark.parametrize("field, value", [("tactile", np.inf), ("ball_pos", np.nan)])
def test_eval_perception_refuses_non_finite_data_naming_the_shard(capsys, tmp_path, perception_run, field, value):
    import shutil

    import h5py

    from tacgnn.datasets.store import _sha256

    source, checkpoint = perception_run
    root = tmp_path / "data"
    shutil.copytree(source, root)
    assert main(["eval-perception", "--checkpoint", str(checkpoint), "--dataset", str(root), "--whole"]) == 0
    capsys.readouterr()
    with h5py.File(root / "shard_00001.h5", "r+") as h5:  # a foreign writer's shard, checksum matching
        h5[field][3] = value
    manifest = json.loads((root / "manifest.json").read_text())
    manifest["shards"]["1"]["sha256"] = _sha256(root / "shard_00001.h5")
    (root / "manifest.json").write_text(json.dumps(manifest))
    code = main(["eval-perception", "--checkpoint", str(checkpoint), "--dataset", str(root), "--whole"])
    out, err = capsys.readouterr()
    assert code == 2 and "nan" not in out
    assert "shard_00001.h5" in err and f"'{field}'" in err and len(err.strip().splitlines()) == 1
