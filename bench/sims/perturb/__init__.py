"""Perturbed simulators: the axes and their `perturb.*` grammar, and conditions applied to an env at each reset.

`axes` (the table of axes, key=value -> conditions), `reset` (targets, validation, nominal values, a
condition applied at reset: re-exported here as the package's face), `interface` (held, delayed and
noisy commands and observations), `visual` and `scene` (what the cameras see), `physx` (the same
model axes on SAPIEN/PhysX).
"""

from bench.sims.perturb.reset import apply, nominal_of, set_nominal, targets, validate, validate_run, write_fields

__all__ = ["apply", "nominal_of", "set_nominal", "targets", "validate", "validate_run", "write_fields"]
