"""experiments/table3_report.py: episodes of all seeds pooled into one rate and interval."""

import json

import pytest

from tacgnn.learning.evaluate import wilson_interval


@pytest.fixture(scope="module")
def report(experiment_script):
    return experiment_script("table3_report")


def _write(path, rates, steps=30.0, episodes=100):
    path.write_text(json.dumps([{"task": t, "episodes": episodes, "success_rate": r, "mean_steps_to_success": steps}
                                for t, r in zip(("simple", "middle", "hard"), rates)]))


def _run_report(report, results, *options):
    """Run table3_report.py's command line on `results`; the markdown it wrote."""
    import sys
    out = results / "t3.md"
    argv, sys.argv = sys.argv, ["table3_report.py", "--results", str(results), "--out", str(out), *options]
    try:
        report.main()
    finally:
        sys.argv = argv
    return out.read_text()


def _rows(text):
    """Table rows keyed by their first cell."""
    return {line.split(" | ")[0]: line for line in text.splitlines() if line.startswith("| ")}


def _swap_rows(text):
    """perception_swap_report's rows keyed by their first cell, without the leading "| "."""
    return {line.split(" | ")[0].strip("| "): line for line in text.splitlines()}


def test_seeds_pool_into_one_rate_with_a_wilson_interval(report, tmp_path):
    _write(tmp_path / "blind_gcn_hard_s0_model_000800.json", (0.9, 0.8, 0.5), steps=20.0)
    _write(tmp_path / "blind_gcn_hard_s1_model_000800.json", (0.7, 0.6, 0.3), steps=40.0)
    _write(tmp_path / "blind_gcn_hard_s2_model_000400.json", (0.0, 0.0, 0.0))  # other iterations: ignored
    per_seed = report.collect(tmp_path, "blind_gcn_hard", 800)
    assert sorted(per_seed) == [0, 1]
    simple = report.pooled_cells(per_seed)[0]
    lo, hi = wilson_interval(160, 200)
    # 160 of 200 episodes; steps weighted by successes: (90 * 20 + 70 * 40) / 160 = 28.75
    assert simple == f"**80.0** [{100 * lo:.1f}-{100 * hi:.1f}] (90.0 / 70.0); 29 steps"


def test_missing_rows_read_not_run(report, tmp_path):
    _write(tmp_path / "blind_tacgnn_hard_s0_model_000800.json", (0.95, 0.9, 0.8))
    rows = _rows(_run_report(report, tmp_path))
    assert "**95.0**" in rows["| TacGNN-32"] and "94.71 / 88.57 / 79.78" in rows["| TacGNN-32"]
    assert rows["| MLP"].count("not run") == 3


def test_a_retrained_teacher_reports_its_own_runs_alone(report, tmp_path):
    """Runs from another teacher (table3.sh's TEACHER_TAG) must neither pool with nor be compared to
    the runs of the first teacher, whose results files sit in the same folder."""
    _write(tmp_path / "gt_hard_s0_model_002000.json", (0.98, 0.98, 0.96))
    _write(tmp_path / "gt_t2_hard_s0_model_002000.json", (0.5, 0.5, 0.5))
    _write(tmp_path / "blind_tacgnn_wu4_lr0.0001_hard_s1_model_000600.json", (0.1, 0.1, 0.1))
    _write(tmp_path / "blind_tacgnn_wu4_lr0.0001_t2_hard_s1_model_000600.json", (0.9, 0.8, 0.7))
    _write(tmp_path / "blind_gcn_wu4_lr0.0001_t2_hard_s1_model_000600.json", (0.6, 0.6, 0.6))
    text = _run_report(report, tmp_path, "--iterations", "600", "--teacher", "t2")
    rows = _rows(text)
    assert rows["| ground truth (teacher, Hard fine-tune)"].startswith("| ground truth (teacher, Hard fine-tune) | **50.0**")
    assert "(90.0); " in rows["| TacGNN-32, warm-up, learning rate 1e-4, teacher t2"]
    assert rows["| MLP, warm-up, learning rate 1e-4, teacher t2"].count("not run") == 3
    assert "| TacGNN-32, warm-up, PPO learning rate 1e-4 (session 7)" not in rows  # the first teacher's rows
    assert rows["| GCN"].startswith("| GCN | 1 / 1 | **+30.0** [")  # 90 - 60 on Simple, t2 runs only
    assert "TacGNN-32 + joint angles minus" not in text  # no such run: no such section
    # the page names the command that remakes it, teacher included
    assert "`.venv/bin/python experiments/table3_report.py --iterations 600 --teacher t2`" in text

    _write(tmp_path / "blind_tacgnn_joints_wu4_lr0.0001_t2_hard_s1_model_000600.json", (0.95, 0.9, 0.9))
    text = _run_report(report, tmp_path, "--iterations", "600", "--teacher", "t2")
    joints = text.split("TacGNN-32 + joint angles minus")[1].splitlines()
    assert joints[2].startswith("| GCN | 1 / 1 | **+35.0** [")  # 95 - 60
    assert joints[3].startswith("| TacGNN-32 | 1 / 1 | **+5.0** [")  # 95 - 90
    assert "| MLP + joint angles |" not in text  # not run: no comparison row
    assert "| GCN on rest positions" not in _rows(text)  # not run: no comparison row

    _write(tmp_path / "blind_mlp_joints_wu4_lr0.0001_t2_hard_s1_model_000600.json", (0.85, 0.9, 0.9))
    text = _run_report(report, tmp_path, "--iterations", "600", "--teacher", "t2")
    assert "(85.0); " in _rows(text)["| MLP + joint angles, teacher t2 (beyond the paper)"]
    assert _rows(text)["| TacGNN-64, teacher t2 (`PSET_TAG=c64 ... model.channels=64`)"].count("not run") == 3
    joints = text.split("TacGNN-32 + joint angles minus")[1].splitlines()
    assert joints[4].startswith("| MLP + joint angles | 1 / 1 | **+10.0** [")  # 95 - 85

    _write(tmp_path / "blind_gcn_rest_wu4_lr0.0001_t2_hard_s1_model_000600.json", (0.4, 0.4, 0.4))
    rows = _rows(_run_report(report, tmp_path, "--iterations", "600", "--teacher", "t2"))
    assert rows["| GCN on rest positions"].startswith("| GCN on rest positions | 1 / 1 | **+50.0** [")  # 90 - 40
    assert "TacGNN-64 minus" not in "\n".join(rows)  # no TacGNN-64 run: no such section

    _write(tmp_path / "blind_tacgnn_c64_wu4_lr0.0001_t2_hard_s1_model_000600.json", (0.92, 0.9, 0.9))
    text = _run_report(report, tmp_path, "--iterations", "600", "--teacher", "t2")
    wide = text.split("TacGNN-64 minus")[1].splitlines()
    assert wide[2].startswith("| MLP | 1 / 0 | not run")  # the MLP skin-only row never ran here
    assert wide[4].startswith("| GCN | 1 / 1 | **+32.0** [")  # 92 - 60
    assert wide[5].startswith("| GCN on rest positions | 1 / 1 | **+52.0** [")  # 92 - 40
    assert wide[6].startswith("| TacGNN-32 | 1 / 1 | **+2.0** [")  # 92 - 90


def test_a_seed_without_successes_adds_no_steps(report, tmp_path):
    """A run that never succeeds has NaN mean steps: it must not turn the pooled steps into NaN."""
    _write(tmp_path / "blind_mlp_hard_s0_model_000800.json", (0.0, 0.0, 0.0), steps=float("nan"))
    assert report.pooled_cells(report.collect(tmp_path, "blind_mlp_hard", 800))[0] == \
        f"**0.0** [0.0-{100 * wilson_interval(0, 100)[1]:.1f}] (0.0); no success"
    _write(tmp_path / "blind_mlp_hard_s1_model_000800.json", (0.5, 0.5, 0.5), steps=30.0)
    assert report.pooled_cells(report.collect(tmp_path, "blind_mlp_hard", 800))[0].endswith("(0.0 / 50.0); 30 steps")


def test_perception_swap_report_pools_seeds_of_one_perception(experiment_script, tmp_path):
    swap = experiment_script("perception_swap_report")
    _write(tmp_path / "gt_hard_s0_model_002000.json", (0.99, 0.98, 0.96))
    _write(tmp_path / "swap_gt__gthard_s0_tacgnn_pi.json", (0.8, 0.7, 0.6))
    _write(tmp_path / "swap_gt__gthard_s1_tacgnn_pi.json", (0.6, 0.5, 0.4))
    _write(tmp_path / "swap_gt__gthard_s0_cnn_pi.json", (0.5, 0.5, 0.5))
    _write(tmp_path / "swap_gt__gthard_s2_tacgnnraw_pi.json", (0.2, 0.2, 0.2))  # experiments/perception_inputs.sh
    _write(tmp_path / "swap_gt__gthard_s1_mlplog_pi.json", (0.1, 0.1, 0.1))
    _write(tmp_path / "swap_gt__blind_cnn_wu4_lr0.0001_hard_s1_model_000600.json", (0.9, 0.9, 0.9))
    _write(tmp_path / "swap_tacgnn_s1_policy__cnn_s1_perception.json", (0.3, 0.2, 0.1))
    text = swap.table(tmp_path)
    rows = _swap_rows(text)
    lo, hi = wilson_interval(140, 200)
    assert f"70.0 [{100 * lo:.1f}-{100 * hi:.1f}] (80.0 / 60.0)" in rows["TacGNN-32, trained offline (s0, s1)"]
    assert "| 50.0 [" in rows["CNN, trained offline (s0)"]
    assert "| 20.0 [" in rows["TacGNN-32 with raw force, trained offline (s2)"]  # its own row, not pooled with TacGNN
    assert "| 10.0 [" in rows["MLP with log force, trained offline (s1)"]
    differences = text.split("TacGNN-32 (offline) minus")[1]
    cnn_row = next(line for line in differences.splitlines() if line.startswith("| CNN |"))
    assert cnn_row.startswith("| CNN | 2 / 1 | **+20.0** [")  # (80 + 60) / 200 - 50 / 100 on Simple
    assert "| 90.0 [" in rows["CNN, trained in the loop (s1 @600)"]
    assert "| 99.0 [" in rows["true ball positions (the policy's own training input)"]
    assert rows["tacgnn_s1"].startswith("| tacgnn_s1 | cnn_s1 | 30.0 [")
    # under an env change: only that change's files, the nominal ones left out
    _write(tmp_path / "otherhand_x1_gt_hard_s0_model_002000.json", (0.88, 0.9, 0.8))
    _write(tmp_path / "otherhand_x1_swap_gt__gthard_s0_tacgnn_pi.json", (0.4, 0.3, 0.2))
    rows = _swap_rows(swap.table(tmp_path, "otherhand_x1"))
    assert "| 40.0 [" in rows["TacGNN-32, trained offline (s0)"] and "| 88.0 [" in rows[
        "true ball positions (the policy's own training input)"]
    assert not any(name.startswith(("CNN", "tacgnn_s1")) for name in rows)


def test_tacgnn_minus_each_baseline_with_a_seed_bootstrap_interval(report, tmp_path):
    for seed, rates in enumerate([(0.95, 0.9, 0.8), (0.93, 0.9, 0.6)]):
        _write(tmp_path / f"blind_tacgnn_wu4_lr0.0001_hard_s{seed}_model_000600.json", rates, episodes=512)
    _write(tmp_path / "blind_mlp_wu4_lr0.0001_hard_s0_model_000600.json", (0.5, 0.9, 0.7), episodes=512)
    ours = report.collect(tmp_path, "blind_tacgnn_wu4_lr0.0001_hard", 600)
    cells = report.difference_cells(ours, report.collect(tmp_path, "blind_mlp_wu4_lr0.0001_hard", 600))
    diff, lo, hi = (float(x) for x in cells[0].replace("**", "").replace("[", "").replace("]", "").replace(",", "").split())
    assert diff == 43.9 and 30 < lo < diff < hi < 50  # (486 + 476) / 1024 - 256 / 512: far ahead on Simple
    assert cells[1].startswith("**+0.0**")  # level on Middle
    _, lo, hi = (float(x) for x in cells[2].replace("**", "").replace("[", "").replace("]", "").replace(",", "").split())
    assert lo < 0 < hi  # TacGNN's seeds straddle the MLP on Hard (80 % and 60 % against 70 %)
    assert report.difference_cells(ours, {}) == ["not run"] * 3


def test_a_condition_reads_only_its_own_evaluations(report, tmp_path):
    """--condition otherhand_x1 reports results/otherhand_x1_blind_..., not the nominal files."""
    _write(tmp_path / "blind_mlp_wu4_lr0.0001_hard_s0_model_000600.json", (0.9, 0.9, 0.9))
    _write(tmp_path / "otherhand_x1_blind_mlp_wu4_lr0.0001_hard_s0_model_000600.json", (0.4, 0.3, 0.2))
    text = _run_report(report, tmp_path, "--iterations", "600", "--condition", "otherhand_x1")
    row = next(line for line in text.splitlines() if line.startswith("| MLP, warm-up"))
    assert "**40.0**" in row and "**90.0**" not in row
    assert "otherhand_x1" in text.splitlines()[0]
    assert "experiments/table3_report.py --iterations 600 --condition otherhand_x1`" in text


def test_perception_swap_report_keeps_a_retrained_teachers_perceptions_apart(experiment_script, tmp_path):
    swap = experiment_script("perception_swap_report")
    _write(tmp_path / "otherhand_x1_gt_hard_s0_model_002000.json", (0.88, 0.9, 0.8))
    _write(tmp_path / "otherhand_x1_gt_t2_hard_s0_model_002000.json", (0.36, 0.31, 0.3))
    _write(tmp_path / "otherhand_x1_swap_gt__gthard_s0_tacgnn_pi.json", (0.4, 0.3, 0.2))
    _write(tmp_path / "otherhand_x1_swap_gt__gthard_s1_tacgnn_t2_pi.json", (0.17, 0.17, 0.17))
    _write(tmp_path / "otherhand_x1_swap_gt__gthard_s2_gcn_t2_pi.json", (0.13, 0.13, 0.13))
    _write(tmp_path / "otherhand_x1_swap_tacgnn_s1_policy__cnn_s1_perception.json", (0.3, 0.2, 0.1))
    first = swap.table(tmp_path, "otherhand_x1")
    assert "| 40.0 [" in first and "| 17.0 [" not in first and "GCN" not in first  # the t2 files left out
    second = swap.table(tmp_path, "otherhand_x1", "t2")
    rows = _swap_rows(second)
    assert "| 36.0 [" in rows["true ball positions (the policy's own training input)"]
    assert "| 17.0 [" in rows["TacGNN-32, trained offline (s1)"]
    assert "| 13.0 [" in rows["GCN, trained offline (s2)"]
    assert "| 40.0 [" not in second and "policy trained with" not in second  # the first teacher's left out


def test_perception_swap_report_names_table3_perceptions_and_rejects_unknown_ones(experiment_script, tmp_path):
    """table3.sh names the GCN on rest positions gcn_rest (perception_inputs.sh: gcnrest): both are one row;
    a perception the report does not know raises instead of dropping out of the table."""
    swap = experiment_script("perception_swap_report")
    _write(tmp_path / "otherhand_x1_gt_t2_hard_s0_model_002000.json", (0.36, 0.31, 0.3))
    _write(tmp_path / "otherhand_x1_swap_gt__gthard_s0_gcn_rest_t2_pi.json", (0.21, 0.2, 0.2))
    _write(tmp_path / "otherhand_x1_swap_gt__gthard_s1_tacgnn_joints_t2_pi.json", (0.5, 0.5, 0.5))
    _write(tmp_path / "otherhand_x1_swap_gt__gthard_s0_gcnrest_pi.json", (0.23, 0.2, 0.2))  # first teacher's
    rows = _swap_rows(swap.table(tmp_path, "otherhand_x1", "t2"))
    assert "| 21.0 [" in rows["GCN on rest positions, trained offline (s0)"]
    assert "| 50.0 [" in rows["TacGNN-32 + joint angles, trained offline (s1)"]
    first = _swap_rows(swap.table(tmp_path, "otherhand_x1"))  # t2's files left out, no error
    assert "| 23.0 [" in first["GCN on rest positions, trained offline (s0)"]
    assert not any("joint angles" in row for row in first)
    _write(tmp_path / "otherhand_x1_swap_gt__gthard_s2_transformer_t2_pi.json", (0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="unknown perception model 'transformer'"):
        swap.table(tmp_path, "otherhand_x1", "t2")
