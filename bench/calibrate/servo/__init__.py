"""Position servos (Dynamixel, Feetech) calibrated from their own logs: the torque law (`law`), the effect library
(`effects`), logs (`data`), batched simulation (`sim`), the fit (`fit`), the loop (`loop`), MuJoCo CPU (`mujoco`),
outputs (`report`) and the spec (`spec`). docs/calibration.md, "Position servos"."""

from bench.calibrate.servo.data import Columns, ServoRun, read_runs
from bench.calibrate.servo.effects import SERVO_EFFECTS, ServoEffect
from bench.calibrate.servo.law import ServoParams
from bench.calibrate.servo.loop import ServoCalibration, calibrate_servo, summary
from bench.calibrate.servo.report import write_servo_report
from bench.calibrate.servo.spec import ServoSpec, is_servo_spec, parse_servo_spec

__all__ = [
    "SERVO_EFFECTS",
    "Columns",
    "ServoCalibration",
    "ServoEffect",
    "ServoParams",
    "ServoRun",
    "ServoSpec",
    "calibrate_servo",
    "is_servo_spec",
    "parse_servo_spec",
    "read_runs",
    "summary",
    "write_servo_report",
]
