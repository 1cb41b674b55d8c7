"""Real2Sim from Python: calibrate a suite's robot or a real arm from logs, write the report, identify the model.

`bench calibrate suite=NAME robot=R logs=DIR` is the command over the same functions; a calibration
is carried into runs with `RunConfig(calibration=...)` (docs/calibration.md).
"""

from __future__ import annotations

from bench.calibrate.apply import model_hash
from bench.calibrate.arm.blocks import torque_error
from bench.calibrate.arm.data import load_arm_log
from bench.calibrate.arm.loop import ArmCalibration, calibrate_arm, score_reference
from bench.calibrate.arm.report import write_arm_report
from bench.calibrate.arm.spec import load_arm_spec
from bench.calibrate.report import write_report
from bench.calibrate.suite_robot import calibrate_suite, torque_joints

__all__ = [
    "ArmCalibration",
    "calibrate_arm",
    "calibrate_suite",
    "load_arm_log",
    "load_arm_spec",
    "model_hash",
    "score_reference",
    "torque_error",
    "torque_joints",
    "write_arm_report",
    "write_report",
]
