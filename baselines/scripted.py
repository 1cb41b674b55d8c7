"""`policy=scripted`: the suite's own scripted expert for the cell's task.

Dispatches by task so one registry name serves every suite: robosuite Lift uses
`scripted_lift.LiftExpert` (agnostic observation only); other suites provide an
expert through `env.make_expert()`.
"""
from __future__ import annotations

from bench.errors import RegistryError


def make(cell, env, cfg):
    """Policy factory (entry point `bench.policies: scripted`)."""
    if hasattr(env, "make_expert"):
        return env.make_expert()
    if cell.task == "Lift":
        from baselines.scripted_lift import LiftExpert

        return LiftExpert(env.obs_names, len(env.action_names))
    raise RegistryError(f"policy 'scripted' has no expert for task {cell.task!r} (suite {cell.suite!r})")
