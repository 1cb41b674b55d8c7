"""The MJX Lift scene for suites (`suites/mjx_lift.py`): its batch of worlds, observation and checks; `require`
gives its policies JAX as the scene runs it (baselines/mjx_lift_expert.py)."""

from __future__ import annotations

from bench.sims.mjx import require
from bench.sims.mjx_lift import ACTION_NAMES, AXES, OBS_FIELDS, LiftBatch, World, check_worlds, memory_estimate

__all__ = ["ACTION_NAMES", "AXES", "OBS_FIELDS", "LiftBatch", "World", "check_worlds", "memory_estimate", "require"]
