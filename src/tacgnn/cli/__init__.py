"""The `tacgnn` command line (`tacgnn --help`; the commands in `tacgnn.cli.app`)."""

import os

# Both are read once, when their library loads: set them before anything imports mujoco or torch.
# MuJoCo picks its OpenGL backend at import; the default (GLFW) needs a display, EGL renders
# offscreen anywhere. Idle OpenMP workers of torch's libgomp spin by default: with two jobs on a
# 2-core machine that made a 1-thread perception epoch 3-4x slower (15.7-17.1 s against 4.2-5.4 s
# with PASSIVE, same load).
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from tacgnn.cli.app import build_parser, main  # noqa: E402

__all__ = ["build_parser", "main"]
