"""A pure-numpy suite for testing the runner fast: a point on a line pushed towards a goal.

Loaded without packaging as `suite=tests.toy_suite:ToySuite` (from the checkout's root).
Its own keys: `goal=` (where the point must get to) and fault injection for the runner's
error paths: `fault=raise|nan_reward|nan_obs|hang` on the episodes of robot `fault_robot`
from step `fault_step`.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import numpy as np

from bench.protocols import STATE, ActionSpec, Feature, PolicyPlugin
from bench.protocols.suite import Cell, SuiteBase

FAULTS = ("none", "raise", "nan_reward", "nan_obs", "hang")
GAINS = {"a": 0.1, "b": 0.08, "c": 0.04}  # robot c is slow: a short horizon leaves it short of the goal


@dataclass(frozen=True)
class ToyOptions:
    """Keys of the toy suite."""

    goal: float = 0.5  # where the point must get to
    fault: str = "none"  # inject a fault: none, raise, nan_reward, nan_obs, hang
    fault_robot: str = "c"  # the robot whose episodes get the fault
    fault_step: int = 3  # the step at which it happens
    step_delay: float = 0.0  # wall seconds each step sleeps (to make runs slow enough to kill)


class ToyEnv:
    """x' = x + gain * a (each robot has its own gain); reward -|x - goal|; success |x - goal| < 0.05."""

    backend = "toy-1"
    fps = 10.0
    mujoco = None
    inputs = None
    model_axes = None
    obs_spec = {STATE: Feature.state([("pos", 1), ("goal", 1)])}
    action_spec = ActionSpec.box(["push"], -1.0, 1.0)

    def __init__(
        self, horizon: int, goal: float, gain: float, fault: str = "none", fault_step: int = 3, step_delay: float = 0.0
    ):
        self.horizon, self.goal, self.gain, self.fault, self.fault_step = horizon, goal, gain, fault, fault_step
        self.step_delay = step_delay
        self.x, self.t = 0.0, 0

    def _obs(self) -> dict:
        return {STATE: np.array([self.x, self.goal], np.float32)}

    def reset(self, seed: int) -> dict:
        self.x, self.t = float(np.random.default_rng(seed).uniform(-1, 1)), 0
        self._x0 = self.x
        return self._obs()

    def step(self, action: np.ndarray):
        if self.step_delay:
            time.sleep(self.step_delay)
        self.t += 1
        self.x += self.gain * float(np.clip(action[0], -1, 1))
        reward = -abs(self.x - self.goal)
        obs = self._obs()
        if self.t >= self.fault_step and self.fault != "none":
            if self.fault == "raise":
                raise RuntimeError("toy env exploded")
            if self.fault == "nan_reward":
                reward = float("nan")
            if self.fault == "nan_obs":
                obs[STATE][0] = np.nan
            if self.fault == "hang":
                time.sleep(60)
        return obs, reward, False, self.t >= self.horizon, {}

    def success(self) -> bool:
        return abs(self.x - self.goal) < 0.05

    def init_state(self) -> np.ndarray:
        return np.array([self._x0, self.gain])

    def close(self) -> None:
        pass


class GreedyExpert:
    """Pushes straight at the goal (the suite's scripted expert)."""

    def reset(self, seed: int) -> None:
        pass

    def act(self, obs: dict) -> np.ndarray:
        pos, goal = obs[STATE]
        return np.array([np.clip(10 * (goal - pos), -1, 1)], np.float32)


class ToySuite(SuiteBase):
    """A point pushed to a goal on a line; robots a, b seen, c held out (for runner tests)."""

    name = "toy"
    version = "1"
    Options = ToyOptions
    reference_policy = "scripted"
    default_horizon = 30
    manifest = {"robots": {"seen": ["a", "b"], "unseen": ["c"]}}
    capabilities = frozenset({"expert"})

    def __init__(self, options: ToyOptions | None = None) -> None:
        super().__init__(options)
        if self.options.fault not in FAULTS:
            from bench.core.errors import ConfigError

            raise ConfigError(f"fault={self.options.fault!r}: valid: {', '.join(FAULTS)}")

    @classmethod
    def preload(cls) -> None:
        """Leaves this process's pid in the folder TOY_PRELOAD_MARK names (tests of prestarted workers)."""
        mark = os.environ.get("TOY_PRELOAD_MARK")
        if mark:
            open(os.path.join(mark, str(os.getpid())), "w").close()

    def all_cells(self) -> list[Cell]:
        return [Cell(self.name, "reach", r, "line", s) for s, robots in self.manifest["robots"].items() for r in robots]

    def obs_spec(self, cell: Cell):
        return ToyEnv.obs_spec

    def make_env(self, cell: Cell, horizon: int) -> ToyEnv:
        o = self.options
        fault = o.fault if cell.robot == o.fault_robot else "none"
        return ToyEnv(horizon, o.goal, GAINS[cell.robot], fault, o.fault_step, o.step_delay)

    def make_expert(self, cell: Cell, env) -> GreedyExpert:
        return GreedyExpert()


def chunk_policy(cell, env, ctx):
    """A plain factory returning a policy that answers with action chunks (T, A) of 4 rows."""

    class Chunked:
        def reset(self, seed: int) -> None:
            """Nothing to reset: every answer is the greedy step towards the goal, 4 times."""

        def act(self, obs: dict) -> np.ndarray:
            pos, goal = obs[STATE]
            return np.repeat(np.array([[np.clip(10 * (goal - pos), -1, 1)]], np.float32), 4, axis=0)

    return Chunked()


def nan_policy(cell, env, ctx):
    """A factory whose policy answers NaN from the second call on."""

    class NaNPolicy:
        def reset(self, seed: int) -> None:
            self.calls = 0

        def act(self, obs: dict) -> np.ndarray:
            self.calls += 1
            return np.array([np.nan if self.calls > 1 else 0.0], np.float32)

    return NaNPolicy()


class NeedsCamera(PolicyPlugin):
    """A plugin whose policy reads a camera the toy suite does not have (obs-key check before the run)."""

    def obs_keys(self, options) -> tuple[str, ...]:
        return (STATE, "rgb.front")

    def make(self, cell, env, ctx):
        return GreedyExpert()
