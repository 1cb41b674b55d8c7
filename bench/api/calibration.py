"""Real2Sim from Python: calibrate a suite's robot from logs, write the report, identify the model it fits.

`bench calibrate suite=NAME robot=R logs=DIR` is the command over the same functions; a calibration
is carried into runs with `RunConfig(calibration=...)` (docs/calibration.md).
"""

from __future__ import annotations

from bench.calibrate.apply import model_hash
from bench.calibrate.report import write_report
from bench.calibrate.suite import calibrate_suite, torque_joints

__all__ = ["calibrate_suite", "model_hash", "torque_joints", "write_report"]
