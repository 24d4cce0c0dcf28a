"""From the simulator to a real hand: skin calibration, taxel kinematics, the blind controller.

Import needs no ROS; `tacgnn.real.ros` imports rospy/rclpy only when a node starts.
See docs/real_hand.md for the whole path (system identification, randomised training,
skin calibration, running the controller).
"""

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

__all__ = ["BlindController", "BlindControllerConfig", "TaxelKinematics", "CalibrationError", "SkinCalibration",
           "SkinProcessor", "calibrate", "load_raw_frames", "patch_gain_from_load"]
