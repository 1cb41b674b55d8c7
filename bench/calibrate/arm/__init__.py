"""A real arm calibrated from its own torque log by inverse dynamics (`method: idim`).

`spec` (what a spec says), `model` (the declared model and its names resolved), `data` (the log as
inverse dynamics needs it), `inertial` and `idim` (a link's standard parameters; the regressor, fit
and intervals), `loop` (the calibration: fit, effects traced, checks), `entries` and `report` (what
it wrote), `forward` (the forward-simulation check), `generate` (synthetic arm logs with a known answer).
"""
