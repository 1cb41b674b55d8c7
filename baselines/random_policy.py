"""Uniform random actions within the env's action bounds, from a generator seeded per episode."""

from __future__ import annotations

from typing import Any

import numpy as np

from bench.protocols import Obs, PolicyContext, PolicyPlugin


class RandomPolicy:
    """The floor every policy should beat; seeded by the episode seed for reproducibility."""

    def __init__(self, low: np.ndarray, high: np.ndarray):
        self.low, self.high = np.asarray(low, np.float64), np.asarray(high, np.float64)
        self._span, self._n = self.high - self.low, len(self.low)
        self._rng = np.random.default_rng(0)

    def reset(self, seed: int | None = None) -> None:
        self._rng = np.random.default_rng(seed)

    def act(self, obs: Obs | None) -> np.ndarray:
        return (self.low + self._span * self._rng.random(self._n)).astype(np.float32)


class RandomPlugin(PolicyPlugin):
    """`policy=random`: reads no observation, so it runs with any `obs=` (state or camera images)."""

    def obs_keys(self, options: Any) -> tuple[str, ...]:
        return ()

    def make(self, cell: Any, env: Any, ctx: PolicyContext) -> RandomPolicy:
        return RandomPolicy(env.action_spec.low, env.action_spec.high)


make = RandomPlugin()  # entry point `bench.policies: random`
