"""The experiment and bench scripts report a user's mistake as the command line does: one line, exit 2."""

import subprocess
import sys
from pathlib import Path

import pytest

from tacgnn.config import ConfigError
from tacgnn.user_errors import labelled_paths, run_script

ROOT = Path(__file__).resolve().parents[1]


def test_a_user_error_is_one_line_naming_the_script(capsys, monkeypatch):
    def main():
        raise ConfigError("--seed 3: data/x was made with this seed")

    monkeypatch.setattr(sys, "argv", ["experiments/some_script.py", "--seed", "3"])
    assert run_script(main) == 2
    err = capsys.readouterr().err
    assert err == "some_script.py: --seed 3: data/x was made with this seed\n"


def test_a_bug_still_raises_and_debug_shows_a_user_errors_traceback(monkeypatch):
    def bug():
        raise ZeroDivisionError

    def mistake():
        raise FileNotFoundError(2, "No such file or directory", "runs/none.pt")

    monkeypatch.setattr(sys, "argv", ["x.py"])
    with pytest.raises(ZeroDivisionError):
        run_script(bug)
    monkeypatch.setattr(sys, "argv", ["x.py", "--debug"])
    with pytest.raises(FileNotFoundError):
        run_script(mistake)
    assert sys.argv == ["x.py"]  # the script's own parser never sees --debug
    assert run_script(lambda: None) == 0


def test_labelled_paths_name_the_bad_argument(tmp_path):
    ckpt = tmp_path / "model.pt"
    ckpt.write_bytes(b"")
    assert labelled_paths([f"GT, x=2={ckpt}"]) == [("GT, x=2", str(ckpt))]  # a label may hold '='
    with pytest.raises(ConfigError, match="'runs/a.pt': a policy is given as LABEL=PATH"):
        labelled_paths(["runs/a.pt"])
    with pytest.raises(FileNotFoundError) as err:
        labelled_paths([f"GT={tmp_path / 'missing.pt'}"])
    assert err.value.filename == str(tmp_path / "missing.pt")


@pytest.mark.parametrize("args, expected", [
    (["out.png", "runs/a.pt"], "continuous_angle.py: 'runs/a.pt': a policy is given as LABEL=PATH"),
    (["out.png", "GT=runs/none.pt"], "continuous_angle.py: runs/none.pt: No such file or directory"),
])
def test_a_script_run_with_bad_input_prints_one_line_and_exits_2(tmp_path, args, expected):
    run = subprocess.run([sys.executable, str(ROOT / "experiments" / "continuous_angle.py"),
                          *[str(tmp_path / a) if a.endswith(".png") else a for a in args]],
                         capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert run.returncode == 2, run.stderr
    assert run.stderr == expected + "\n"
    assert not list(tmp_path.iterdir())  # nothing written
