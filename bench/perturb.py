"""Perturbed simulators: conditions applied to an env at each episode reset.

Contract used by `bench.rollout`: `apply(env, condition, rng) -> (stepper, params)`
restores the env's nominal values, applies the condition with draws from `rng`
(the episode's own generator) and returns the object to reset/step (the env, or
a wrapper for interface axes) plus the sampled values to record.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from bench.errors import ConfigError
from bench.suite import NOMINAL, Condition


def conditions_from_config(perturb: dict[str, Any]) -> list[Condition]:
    """The run's conditions from `perturb.*` overrides: nominal first, then one per axis level."""
    if not perturb:
        return [NOMINAL]
    raise ConfigError(f"perturb: axes {sorted(perturb)} are not available yet")


def apply(env, condition: Condition, rng: np.random.Generator) -> tuple[Any, dict[str, Any]]:
    """Apply `condition` to `env` for one episode (nominal: leave it as built)."""
    if condition.axis is None:
        return env, {}
    raise NotImplementedError(f"perturbation axis {condition.axis!r} is not available yet")
