"""Meta-World's own scripted policy for a task, given the true goal through its input only.

The ML benchmarks hide the goal (the last 3 observation values are zeroed); Meta-World's
scripted policies read it from there. `GoalFedExpert` writes the env's true goal
(`MetaWorldEnv.true_goal()`, a privileged accessor) into a copy of the observation before
asking the policy, so the observation the harness records and other policies see stays
goal-free. With the goal, the policies solve the five ML10 test tasks (NOTES-simulators.md).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from bench.api.sims import TOO_HIGH, MetaWorldEnv
from bench.protocols import STATE, Obs


class GoalFedExpert:
    """Meta-World's scripted policy, given the true goal in place of the hidden one."""

    def __init__(self, policy: Any, true_goal: Callable[[], np.ndarray]):
        self._policy, self._true_goal = policy, true_goal

    def reset(self, seed: int | None = None) -> None:
        """Meta-World's policies are stateless; nothing to reset."""

    def act(self, obs: Obs) -> np.ndarray:
        full = np.array(obs[STATE], dtype=np.float64)
        full[-3:] = self._true_goal()
        with warnings.catch_warnings():  # per call: holds even when the caller resets the filters
            warnings.filterwarnings("ignore", message=TOO_HIGH, category=UserWarning)
            action = self._policy.get_action(full)
        return np.clip(action, -1.0, 1.0).astype(np.float32)


def make_expert(env: MetaWorldEnv) -> GoalFedExpert:
    """Meta-World's scripted policy for the env's task (`metaworld.policies.ENV_POLICY_MAP`)."""
    from metaworld.policies import ENV_POLICY_MAP

    return GoalFedExpert(ENV_POLICY_MAP[env.task](), env.true_goal)
