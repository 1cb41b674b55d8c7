"""`policy=baselines.expert_variants:ExpertVariant`: the suite's scripted expert, made worse on purpose.

A population of policies of graded skill for sim-real agreement studies (`baselines/real2sim_demo.py`):

    noise=0.3    Gaussian noise of that standard deviation on every action (seeded per episode)
    scale=0.5    every arm command scaled (a timid expert: slower approach and lift)
    grip=0.5     the gripper command scaled (a weak grasp)

Actions are clipped to the action space. With the defaults it is the expert itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.api import ConfigError
from bench.protocols import PolicyPlugin


@dataclass(frozen=True)
class Options:
    """Keys of the expert variant."""

    noise: float = 0.0  # std of Gaussian noise added to every action
    scale: float = 1.0  # factor on the arm commands (all but the last dimension)
    grip: float = 1.0  # factor on the gripper command (the last dimension)


class _Variant:
    def __init__(self, expert, options: Options, low: np.ndarray, high: np.ndarray):
        self.expert, self.o, self.low, self.high = expert, options, low, high
        self.rng = np.random.default_rng(0)

    def reset(self, seed: int | None = None) -> None:
        self.expert.reset(seed)
        self.rng = np.random.default_rng([0 if seed is None else int(seed), 7])

    def act(self, obs) -> np.ndarray:
        a = np.asarray(self.expert.act(obs), dtype=np.float64).copy()
        a[:-1] *= self.o.scale
        a[-1] *= self.o.grip
        if self.o.noise > 0:
            a += self.rng.normal(0.0, self.o.noise, a.shape)
        return np.clip(a, self.low, self.high)


class ExpertVariant(PolicyPlugin):
    """The scripted expert with action noise, scaled arm commands and a scaled gripper command."""

    Options = Options

    def preflight(self, options: Options, suite, cells, horizon: int) -> None:
        if "expert" not in suite.capabilities:
            raise ConfigError(f"policy ExpertVariant: suite {suite.name!r} declares no scripted expert")
        for key in ("noise", "scale", "grip"):
            if getattr(options, key) < 0:
                raise ConfigError(f"{key}={getattr(options, key)}: must be >= 0")

    def make(self, cell, env, ctx):
        spec = env.action_spec
        return _Variant(ctx.suite.make_expert(cell, env), ctx.options, np.asarray(spec.low), np.asarray(spec.high))
