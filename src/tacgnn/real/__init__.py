"""From the simulator to a real hand: skin calibration, taxel kinematics, the blind controller.

Import needs no ROS; the ROS nodes (`controller_node`, `collect`, `sim_hand`) import
rospy/rclpy only when a node starts. The names below load on first use, not with the
package: `tacgnn real-hand` and `tacgnn sysid` import modules of this package, and the
controller behind `BlindController` pulls in torch and MuJoCo, which the command line must
not load before it has set up the GL backend and thread settings.
See docs/real_hand.md for the whole path (system identification, randomised training,
skin calibration, running the controller).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from tacgnn.real.controller import BlindController, BlindControllerConfig
    from tacgnn.real.kinematics import TaxelKinematics
    from tacgnn.real.skin import (
        CalibrationError,
        SkinCalibration,
        SkinProcessor,
        calibrate,
        load_raw_frames,
        patch_gain_from_load,
    )

_HOMES = {"BlindController": "controller", "BlindControllerConfig": "controller", "TaxelKinematics": "kinematics",
          "CalibrationError": "skin", "SkinCalibration": "skin", "SkinProcessor": "skin", "calibrate": "skin",
          "load_raw_frames": "skin", "patch_gain_from_load": "skin"}

__all__ = ["BlindController", "BlindControllerConfig", "TaxelKinematics", "CalibrationError", "SkinCalibration",
           "SkinProcessor", "calibrate", "load_raw_frames", "patch_gain_from_load"]


def __getattr__(name: str) -> Any:
    if name in _HOMES:
        return getattr(importlib.import_module(f"tacgnn.real.{_HOMES[name]}"), name)
    raise AttributeError(f"module 'tacgnn.real' has no attribute {name!r}")
