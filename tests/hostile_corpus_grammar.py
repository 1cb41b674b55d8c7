"""Hostile key=value inputs owned by the grammar (bench.core.config, bench.api limits, perturb.*).

Registered into `hostile_corpus.CASES` through `add`; run with tests/hostile.py.
"""

from __future__ import annotations

from hostile_corpus import RUN, SA, UW, add

for name, extra, match in [
    ("g-run-id-control-char", ["run_id=a\x1bb"], r"run_id"),
    ("g-run-id-129", ["run_id=" + "r" * 129], r"run_id.*128"),
    ("g-run-id-dotdot", ["run_id=.."], r"run_id"),
    ("g-run-id-blank", ["run_id=   "], r"run_id"),
    ("g-key-control-char", ["see\x01d=1"], r"key"),
    ("g-key-unicode", ["épisodes=3"], r"key"),
    ("g-robots-empty", ["robots=[]"], r"robots"),
    ("g-tasks-unclosed", ["tasks=[a,b"], r"tasks"),
    ("g-seed-2-64", ["seed=18446744073709551616"], r"seed"),
    ("g-episodes-minus-inf", ["episodes=-.inf"], r"episodes"),
    ("g-confidence-one", ["confidence=1"], r"confidence"),
    ("g-confidence-nan", ["confidence=nan"], r"confidence"),
    ("g-actor-cpus-nan", ["executor=ray", "actor_cpus=nan"], r"actor_cpus"),
    ("g-perturb-action-hold-huge", ["perturb.action_hold=[100000000]"], r"perturb"),
    ("g-perturb-mass-neg-inf", ["perturb.mass=[-inf]"], r"perturb"),
    ("g-key-twice-perturb", ["perturb.mass=[1]", "perturb.mass=[2]"], r"twice"),
]:
    add(SA, f"run-{name}", [*RUN, *extra], match)

add(
    UW,
    "run-g-steps-absurd",
    [*RUN[:3], "episodes=100000", "horizon=100000", *RUN[4:]],
    r"control steps, over the limit of 1e\+10; reduce episodes=, horizon=",
)
add(SA, "correlate-g-level-zero", ["correlate", "sim={ws}/sim.json", "real={ws}/real.json", "level=0"], r"level")
add(SA, "replay-g-k-nan", ["replay", "logs={ws}/ds", "spec={ws}/spec.yaml", "k=nan"], r"\bk\b")
