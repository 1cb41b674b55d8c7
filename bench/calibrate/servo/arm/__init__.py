"""An arm's position servos (SO-101) calibrated from its LeRobot dataset with the arm's own dynamics: the spec
(`spec`), the dataset in radians (`data`), the servos in the suite's MJCF (`model`), the fit (`fit`), the loop
(`loop`) and its outputs (`report`). docs/calibration.md, "Arms from LeRobot datasets"."""

from bench.calibrate.servo.arm.loop import ArmServoCalibration, calibrate_arm_servos
from bench.calibrate.servo.arm.model import ArmServos, load_arm
from bench.calibrate.servo.arm.report import servo_document, servos_from, summary, write_arm_servo_report
from bench.calibrate.servo.arm.spec import ArmServoSpec, is_servo_arm_spec, parse_servo_arm_spec

__all__ = [
    "ArmServoCalibration",
    "ArmServoSpec",
    "ArmServos",
    "calibrate_arm_servos",
    "is_servo_arm_spec",
    "load_arm",
    "parse_servo_arm_spec",
    "servo_document",
    "servos_from",
    "summary",
    "write_arm_servo_report",
]
