import importlib.util
import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as the CLI: no spinning OpenMP workers (see tacgnn/cli.py)

import pytest  # noqa: E402

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"
# Files whose tests train, kill and resume runs, compile MuJoCo Warp's kernels, render videos or run
# whole commands: `make test` runs them, `make test-fast` (-m "not slow") leaves them out.
SLOW_FILES = {"test_warp.py", "test_warp_ppo.py", "test_kill_resume.py", "test_training_output.py", "test_sysid.py",
              "test_commands.py", "test_script_errors.py", "test_distributed.py", "test_real_ros.py",
              "test_continuous_pace.py", "test_demo.py", "test_render.py", "test_policy_curves.py",
              "test_perception_loop.py", "test_temporal_loop.py", "test_learning_cli.py", "test_faithful_hand.py",
              "test_real_one_controller.py", "test_config_overrides.py", "test_ppo.py", "test_datasets.py"}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in SLOW_FILES:
            item.add_marker(pytest.mark.slow)


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
