"""experiments/table3_report.py: seeds pooled per run, the in-loop perception error averaged, the figure drawn."""

import json
import sys

import pytest


@pytest.fixture(scope="module")
def report(experiment_script):
    return experiment_script("table3_report")


def _result(task: str, wins: int, error: float | None) -> dict:
    return {"task": task, "episodes": 100, "success_rate": wins / 100, "ci95": [0.0, 1.0],
            "mean_steps_to_success": 60.0, "fall_rate": 0.0, "perception_rmse_cm": error}


def test_seeds_pool_and_the_in_loop_error_is_their_mean(report, tmp_path, capsys, monkeypatch):
    tasks = ("simple", "middle", "hard", "hold")
    for seed, (wins, error) in enumerate(((80, 0.6), (90, 0.8))):
        rows = [_result(t, wins, error) for t in tasks]
        (tmp_path / f"blind_tacgnn_s{seed}_model_000400.json").write_text(json.dumps(rows))
    (tmp_path / "teacher_model_000500.json").write_text(json.dumps([_result(t, 95, None) for t in tasks]))
    figure = tmp_path / "table.png"
    monkeypatch.setattr(sys, "argv", ["table3_report.py", "--folder", str(tmp_path), "--figure", str(figure)])
    report.main()
    lines = capsys.readouterr().out.splitlines()
    blind = next(line for line in lines if line.startswith("| blind_tacgnn (400 it.) | 2 |"))
    assert "85.0 (80.0, 90.0)" in blind  # 170 wins of 200 episodes, each seed's rate beside
    assert "| 0.70/0.70/0.70/0.70 |" in blind  # the two seeds' errors averaged per task
    teacher = next(line for line in lines if line.startswith("| teacher (500 it.) | 1 |"))
    assert "| - |" in teacher  # a ground-truth run has no perception in the loop
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
