"""Uniform random actions within the env's action bounds, from a generator seeded per episode."""
from __future__ import annotations

import numpy as np

from bench.protocols import Obs


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


def make(cell, env, ctx) -> RandomPolicy:
    """Policy factory (entry point `bench.policies: random`)."""
    return RandomPolicy(env.action_spec.low, env.action_spec.high)
