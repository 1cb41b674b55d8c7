"""Real2Sim calibration: fit a MuJoCo model to logs, trace the residual to missing effects, report.

Entry points: `load_spec`; `bench.calibrate.trace.calibrate_episodes` (the loop, on arrays of shape (T, n));
`bench.calibrate.suite_robot.calibrate_suite` (a suite's robot in its scene); `bench.calibrate.report.write_report`;
the CLI `bench calibrate spec=SPEC logs=DIR out=DIR` / `suite=NAME robot=NAME logs=DIR out=DIR`.
Modules: spec -> data -> model (+ effects, play) -> fit -> signature -> trace -> report, on replay's
signal map, recording and batched simulator (`bench.replay.spec`, `.data`, `.simulate`, `.metrics`);
residual (the learned residual, apart from the physics), suite_robot + apply (suite calibrations and runs
with them), rank (episodes by surprise); generate writes synthetic cases. See docs/calibration.md.
"""

from __future__ import annotations

from bench.calibrate.spec import CalibrationSpec, load_spec, parse_spec

__all__ = ["CalibrationSpec", "load_spec", "parse_spec"]
