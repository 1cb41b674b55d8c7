"""`bench run`: the command line over `bench.api` (config -> plan -> run -> records -> summary)."""

from __future__ import annotations

import sys
from pathlib import Path

from bench import api
from bench.api import RUNNER_KEYS, BenchError, RunConfig, nothing_measured, render_summary, score
from bench.api.data import EPISODES, read_records
from bench.api.plugins import axes_help, plugin_keys, policy_for
from bench.core import config as config_mod
from bench.core.config import command_help
from bench.core.errors import ConfigError, NothingMeasured


def help_text(argv: list[str] | None = None) -> str:
    """`bench run --help`: the runner's keys, then the keys of the suite and policy given in `argv` (or defaults)."""
    suite, policy = "held_out_robots", None
    for arg in argv or []:
        key, _, value = arg.partition("=")
        if key == "suite":
            suite = value
        elif key == "policy":
            policy = value
    plugin_keys_text = ""
    try:
        policy = policy_for(suite, policy)
        for own in plugin_keys(suite, policy):
            keys = config_mod.key_help(own.schema, own.keys) if own.keys else "  (none)"
            plugin_keys_text += f"\nkeys of {own.owner}:\n{keys}\n"
    except BenchError as exc:
        plugin_keys_text = f"\n(keys of suite {suite} / policy {policy}: {exc})\n"
    return (
        "usage: bench run [key=value ...]\n\n"
        "Runs a policy on every cell (task x robot x env) and condition of a suite, appends one\n"
        "record per episode to OUT/RUN_ID/episodes.jsonl as it finishes, then writes\n"
        "OUT/RUN_ID/summary.json (success per cell with Wilson intervals, seen/unseen means with\n"
        "bootstrap intervals, the seen-unseen transfer gap) and prints the table.\n"
        "Rerunning with the same run_id resumes: recorded episodes are skipped. One run writes a run directory\n"
        "at a time: a second one on the same run_id is refused, naming the first (docs/guarantees.md).\n"
        "Exit codes: 0 done (a last line counts the episodes that errored, per cell), 2 bad input or a\n"
        "missing capability (nothing written), 3 nothing measured: no episode completed, or a cell has\n"
        "none while others do (records and summary are kept; docs/guarantees.md).\n"
        "Each key belongs to the runner, to the suite or to the policy; `bench run suite=NAME\n"
        "policy=NAME --help` lists the keys of that suite and policy.\n\n"
        f"runner keys:\n{config_mod.key_help(RunConfig, RUNNER_KEYS)}\n{plugin_keys_text}\n"
        "examples:\n"
        "  bench run suite=held_out_robots\n"
        "  bench run suite=held_out_robots policy=random episodes=10 workers=2\n"
        "  bench run suite=held_out_robots robots=[UR5e,IIWA] episodes=3 run_id=try1\n"
        "  bench run suite=held_out_robots policy=checkpoint checkpoint=bc/policy.safetensors\n"
        "  bench run robots=[Panda] perturb.friction=[0.01,0.1] perturb.latency=uniform(0,4)\n"
        "  bench run suite=gym env_id=HalfCheetah-v5 perturb.gravity=[0.5,1.5] perturb.mass.bodies=[torso] "
        "perturb.mass.levels=[2]\n"
        "  bench run robots=[Panda] obs=rgb cameras=[agentview] image_size=96 policy=random perturb.light=[0.3] "
        "video=1   # cameras: docs/cameras.md\n"
        "  bench run suite=my_pkg.suites:MySuite policy=my_pkg.policies:make   # out-of-tree plugins\n"
        "  bench run executor=ray ray_address=10.0.0.5:6379 actors=64      # a Ray cluster (docs/ray.md)\n"
        "  bench run policy=bc vector=8   # 8 envs per worker in lockstep, one batched policy call a step (docs/performance.md)\n"
        + _perturb_help()
    )


def _perturb_help() -> str:
    return (
        "\nperturbations (perturb.AXIS=[levels] | uniform(lo,hi) | loguniform(lo,hi) | from(CALIBRATION); dict form\n"
        "perturb.AXIS.levels=[...] perturb.AXIS.bodies=[...]; details: docs/perturbations.md):\n" + axes_help() + "\n"
        "\ncombined axes: perturb.combine=[A,B,...] also runs the axes together, every combination of their levels\n"
        "(each from its own perturb.A=...; the single-axis conditions stay), or a seeded share of them with\n"
        "perturb.combine.axes=[A,B] perturb.combine.fraction=0.5 (the all-at-once combination, every axis at its\n"
        "level farthest from nominal, always kept). Reported per combination (summary key `interactions`): its drop\n"
        "from nominal, the sum of its single drops, and the interaction = drop - sum with a paired interval (> 0: the\n"
        "axes compound; < 0: less than additive).\n"
        "  bench run robots=[Panda] perturb.friction=[0.02] perturb.mass=[3] perturb.combine=[friction,mass]\n"
    )


def main(argv: list[str]) -> int:
    if any(a in ("-h", "--help") for a in argv):
        print(help_text([a for a in argv if a not in ("-h", "--help")]))
        return 0

    p, executor = api.plan_with_workers(api.parse_run(argv), own_process=True)  # parsed once, planned once
    for line in api.calibration_notes(p):  # what the run's robot is, before its episodes
        print(line, file=sys.stderr, flush=True)
    result = api.run(p, progress=True, executor=executor)
    if result.summary is not None:
        render_summary(result.summary)
        why = nothing_measured(result.summary, result.records)
        if why:
            raise NothingMeasured(f"run {p.config.run_id} ({result.run_dir}): {why}")
    return 0


def main_score(argv: list[str]) -> int:
    """`bench score RUN_DIR`: recompute summary.json from episodes.jsonl and print the table."""
    if not argv or argv[0] in ("-h", "--help"):
        print(
            command_help(
                "usage: bench score RUN_DIR",
                "Recomputes RUN_DIR/summary.json from RUN_DIR/episodes.jsonl (the records are the source of\n"
                "truth) and prints the table. Exits 3 when the run measured nothing: no episode completed, or\n"
                "a cell has none while others do (docs/guarantees.md).",
                examples=["bench score runs/my_run"],
            ),
            end="",
        )
        return 0 if argv else 2

    if len(argv) != 1:
        raise ConfigError(f"score takes one RUN_DIR, got {argv}")
    summary = score(argv[0])
    render_summary(summary)
    why = nothing_measured(summary, read_records(Path(argv[0]) / EPISODES))
    if why:
        raise NothingMeasured(f"{argv[0]}: {why}")
    return 0
