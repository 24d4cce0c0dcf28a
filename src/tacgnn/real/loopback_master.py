"""A ROS 1 master (roscore) on a free loopback port, and the environment that points nodes at it.

The simulated hand, the benches and the integration tests run the whole ROS path on one
machine; each needs its own master so that runs never talk to each other.
"""

from __future__ import annotations

import os
import socket
import subprocess
import time
from pathlib import Path

LOOPBACK = "127.0.0.1"


def free_port() -> int:
    with socket.socket() as s:
        s.bind((LOOPBACK, 0))
        return int(s.getsockname()[1])


def loopback_env(port: int, home: Path) -> dict[str, str]:
    """This process's environment with ROS pointed at the master on `port`, logs under `home`."""
    return {**os.environ, "ROS_MASTER_URI": f"http://{LOOPBACK}:{port}", "ROS_HOSTNAME": LOOPBACK,
            "ROS_IP": LOOPBACK, "ROS_HOME": str(home), "ROS_LOG_DIR": str(home / "log"), "MUJOCO_GL": "egl"}


def start_roscore(env: dict[str, str], port: int, timeout_s: float = 30.0) -> subprocess.Popen:
    """Start roscore on `port` and wait until it accepts connections (RuntimeError if it does not)."""
    core = subprocess.Popen(["roscore", "-p", str(port)], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + timeout_s
    while True:
        with socket.socket() as s:
            if s.connect_ex((LOOPBACK, port)) == 0:
                break
        if time.monotonic() > deadline or core.poll() is not None:
            core.kill()
            raise RuntimeError(f"roscore did not start on port {port} within {timeout_s:.0f} s")
        time.sleep(0.2)
    time.sleep(1.0)  # rosout registers
    return core


def stop_roscore(core: subprocess.Popen) -> None:
    core.terminate()
    try:
        core.wait(10)
    except subprocess.TimeoutExpired:
        core.kill()
