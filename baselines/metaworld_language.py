"""`policy=metaworld_language`: Meta-World's own expert for the task the instruction names, found by matching words.

A scripted policy that reads the instruction (`obs["task"]`, which the Meta-World suites give as a sentence such as
"open the drawer") instead of being told the task: each v3 task has key words, the words of its name ("drawer-open"
-> {drawer, open}; "button-press-topdown" -> {button, press, top}); the task whose key words all occur in the
instruction, the most specific such task when several do, is the one it solves, with Meta-World's scripted policy
for it (given the true goal through its input only, as `policy=scripted` is: `baselines.metaworld_expert`). When no
task matches, or two equally specific ones do, it cannot tell what it is asked and holds still (the zero action:
no hand motion, no grip). So a paraphrase that keeps the key words is followed exactly, and an empty or nonsense
instruction is not: what `perturb.instruction` measures (docs/perturbations.md, "Instruction").

It reads words, not meaning: a synonym for a key word ("shut" for "close") is lost on it. Suites: held_out_envs,
held_out_envs_ml45.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from baselines.metaworld_expert import GoalFedExpert
from bench.api import ConfigError
from bench.api.sims import MetaWorldEnv, unwrap
from bench.protocols import STATE, TASK, Obs, PolicyContext, PolicyPlugin

# a word of a task's name -> the word an instruction uses for it (names that are not words of the sentence)
ALIASES = {"topdown": "top", "picking": "pick", "assembly": "assemble", "of": ""}


def key_words(task: str) -> frozenset[str]:
    """The words an instruction must hold to name `task` ("button-press-topdown-v3" -> {button, press, top})."""
    parts = re.sub(r"-v\d+$", "", task).split("-")
    return frozenset(w for w in (ALIASES.get(p, p) for p in parts) if w)


def words(text: str) -> frozenset[str]:
    return frozenset(re.findall(r"[a-z]+", text.lower()))


def resolve(instruction: str, tasks: dict[str, frozenset[str]]) -> str | None:
    """The task whose key words all occur in `instruction`, the most specific one; None when none does or the
    most specific ones tie (the instruction does not say which)."""
    said = words(instruction)
    found = [(len(k), t) for t, k in tasks.items() if k <= said]
    if not found:
        return None
    best = max(n for n, _ in found)
    top = [t for n, t in found if n == best]
    return top[0] if len(top) == 1 else None


class LanguageExpert:
    """Meta-World's expert of the task the instruction names; the zero action when it cannot tell."""

    def __init__(self, experts: dict[str, Any], dim: int):
        self.experts, self.dim = experts, dim
        self.keys = {t: key_words(t) for t in experts}
        self._seen: dict[str, str | None] = {}  # instruction -> task, as resolved
        self.chosen: str | None = None

    def reset(self, seed: int | None = None) -> None:
        """Meta-World's policies are stateless; the task is read again from the next observation."""
        self.chosen = None

    def act(self, obs: Obs) -> np.ndarray:
        text = str(obs.get(TASK, ""))
        if text not in self._seen:
            self._seen[text] = resolve(text, self.keys)
        self.chosen = self._seen[text]
        if self.chosen is None:
            return np.zeros(self.dim, np.float32)
        return self.experts[self.chosen].act(obs)

    def episode_stats(self) -> dict[str, object]:
        return {"task_read": self.chosen or ""}


@dataclass(frozen=True)
class LanguageOptions:
    """Keys of policy=metaworld_language."""

    experts: str = "all"  # the tasks it can name: all (Meta-World's 50 v3 tasks) or suite (the suite's cells')


class LanguageExpertPlugin(PolicyPlugin):
    """Reads `state` and the instruction (`task`); one expert per Meta-World task it can name."""

    Options = LanguageOptions
    reports_stats = True

    def obs_keys(self, options: Any) -> tuple[str, ...]:
        return (STATE, TASK)

    def preflight(self, options: LanguageOptions, suite: Any, cells: Any, horizon: int) -> None:
        if options.experts not in ("all", "suite"):
            raise ConfigError(f"experts={options.experts!r}: valid: all, suite")

    def make(self, cell: Any, env: Any, ctx: PolicyContext) -> LanguageExpert:
        from metaworld.policies import ENV_POLICY_MAP  # Meta-World: loaded only when the policy is made

        inner = unwrap(env)
        if not isinstance(inner, MetaWorldEnv):
            raise ConfigError(f"policy 'metaworld_language' drives Meta-World envs; {cell.key} is {env.backend}")
        names = list(ENV_POLICY_MAP) if ctx.options.experts == "all" else [c.task for c in ctx.suite.all_cells()]
        experts = {t: GoalFedExpert(ENV_POLICY_MAP[t](), inner.true_goal) for t in names}
        return LanguageExpert(experts, env.action_spec.dim)
