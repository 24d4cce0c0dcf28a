import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as the CLI: no spinning OpenMP workers (see tacgnn/cli.py)
