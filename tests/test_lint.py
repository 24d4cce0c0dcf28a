"""ruff reports nothing on the package, its tests, benches and experiments, and mypy nothing on the
package, with the settings in pyproject.toml.

Both tools come with the `dev` extra; without them these tests skip and say so.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHECKED = ("src", "tests", "bench", "experiments")


def _run(tool: str, *args: str) -> subprocess.CompletedProcess:
    if importlib.util.find_spec(tool) is None:
        pytest.skip(f"{tool} is not installed (pip install -e '.[dev]')")
    return subprocess.run([sys.executable, "-m", tool, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)


def test_ruff_check_finds_nothing():
    result = _run("ruff", "check", "--no-cache", *CHECKED)
    assert result.returncode == 0, f"ruff check {' '.join(CHECKED)}:\n{result.stdout}{result.stderr}"


def test_mypy_finds_nothing():
    # the cache (.mypy_cache, ignored by git) makes later runs take seconds instead of ~30 s
    result = _run("mypy", "src/tacgnn")
    assert result.returncode == 0, f"mypy src/tacgnn:\n{result.stdout}{result.stderr}"
