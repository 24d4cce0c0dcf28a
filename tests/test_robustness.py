"""The robustness table: each row is the nominal hand with one change, 'a real hand' is the default
randomisation; an interrupted table resumes without redoing its rows; bad input is one line."""

import json

import pytest

from tacgnn.config import override
from tacgnn.envs.baoding import BaodingConfig
from tacgnn.envs.randomization import RANGES, RandomizationConfig
from tacgnn.learning import robustness
from tacgnn.learning.policy import SHIPPED_GROUND_TRUTH


def test_each_row_changes_one_thing_from_the_nominal_hand():
    nominal = RandomizationConfig.nominal(0.15)
    for row in robustness.rows(uses_skin=True):
        cfg = override(BaodingConfig(), robustness.overrides(row, 0.15))
        r = cfg.randomization
        assert r.enabled
        if row.randomization is None:  # a real hand: every default range
            assert r == RandomizationConfig(enabled=True)
            continue
        changed = {name for name in RANGES if getattr(r, name) != getattr(nominal, name)}
        assert changed == {k for k in row.randomization if k in RANGES}, row.name
    damped = next(row for row in robustness.rows(False) if row.name == "damping x3")
    assert override(BaodingConfig(), robustness.overrides(damped, 0.15)).randomization.damping_scale == (3.0, 3.0)
    names = [row.name for row in robustness.rows(uses_skin=False)]
    assert "a real hand" in names and not any(name.startswith("skin") for name in names)


class Stopped(Exception):
    """The table's run ends here (a kill, a Ctrl-C)."""


def test_an_interrupted_table_resumes_without_redoing_its_rows(tmp_path, monkeypatch):
    calls, stop_at = [], [3]

    def fake_evaluate(checkpoint, task, episodes, num_envs, seed, env_overrides):
        calls.append(task)
        if len(calls) == stop_at[0]:
            raise Stopped  # the first run is stopped during its third row
        return {"task": task, "success_rate": 1.0, "ci95": (0.9, 1.0), "fall_rate": 0.0}

    monkeypatch.setattr(robustness, "evaluate", fake_evaluate)
    out = tmp_path / "table.json"
    args = [str(SHIPPED_GROUND_TRUTH), "--episodes", "4", "--envs", "2", "--out", str(out)]
    with pytest.raises(Stopped):
        robustness.main(args)
    assert [r["row"] for r in json.loads(out.read_text())] == ["nominal", "damping x0.3"]
    calls.clear()
    stop_at[0] = -1
    robustness.main(args)
    total = len(robustness.rows(uses_skin=False))
    assert len(calls) == total - 2 and len(json.loads(out.read_text())) == total
    assert out.with_suffix(".md").read_text().count("\n") == total + 2
    calls.clear()
    robustness.main([*args[:-2], "--seed", "1", "--out", str(out)])  # another seed: every row again
    assert len(calls) == total


def test_robustness_names_bad_input(tmp_path, capsys):
    from tacgnn.cli import main

    (tmp_path / "a_file").write_text("")  # a folder cannot be made inside it, even by root
    for args, named in ((["nowhere.pt"], "not found"), ([str(SHIPPED_GROUND_TRUTH), "--episodes", "0"], "--episodes"),
                        ([str(SHIPPED_GROUND_TRUTH), "--out", str(tmp_path / "a_file" / "t.json")], "cannot")):
        assert main(["robustness", *args]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and named in err, err
