"""`policy=scripted`: the suite's own scripted expert for the cell's task.

One registry name serves every suite: a suite that declares the "expert" capability
builds its expert (`Suite.make_expert`), e.g. the Lift expert of `baselines/scripted_lift.py`
for the robosuite suites and Meta-World's own policies for the Meta-World suites.
"""

from __future__ import annotations

from bench.api import RegistryError


def make(cell, env, ctx):
    """Policy factory (entry point `bench.policies: scripted`)."""
    suite = ctx.suite
    if "expert" not in suite.capabilities:
        raise RegistryError(
            f"policy 'scripted': suite {suite.name!r} declares no scripted expert "
            f"(its reference policy is {suite.reference_policy!r})"
        )
    return suite.make_expert(cell, env)
