import importlib.util
import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as the CLI: no spinning OpenMP workers (see tacgnn/cli.py)

import pytest  # noqa: E402

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"


@pytest.fixture(scope="session")
def experiment_script():
    """experiment_script(name): the module of experiments/<name>.py, loaded as running the script
    would (experiments/ first on the import path, so one script can import another)."""
    sys.path.insert(0, str(EXPERIMENTS))

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, EXPERIMENTS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    yield load
    sys.path.remove(str(EXPERIMENTS))


@pytest.fixture
def poison_loss(monkeypatch):
    """poison_loss(fault, at_call): the at_call-th perception loss becomes NaN ("loss"), or
    stays finite with an infinite gradient behind it ("gradient")."""
    from tacgnn.perception.objectives import Objective

    def install(fault: str, at_call: int) -> None:
        real, calls = Objective.loss, []

        def poisoned(self, pred, target):
            loss = real(self, pred, target)
            calls.append(1)
            if len(calls) == at_call:
                if fault == "loss":
                    return loss * float("nan")
                loss.register_hook(lambda g: g * float("inf"))
            return loss

        monkeypatch.setattr(Objective, "loss", poisoned)

    return install
