"""`bench` command line: a thin dispatcher onto one handler per subcommand.

Each subcommand's module (`bench/cli/<command>.py`) exposes `main(argv: list[str]) -> int`:
it parses the arguments into the command's config, calls the command's function in `bench.api`
(which does the work) and prints what it returns. A module is imported only when its command
runs, so `bench list` and `bench --help` stay fast (no simulator is imported). bench.cli imports
only bench.api, bench.cli and bench.core (import-linter's `cli-uses-the-api` contract).

Arguments are Hydra-style `key=value` overrides (nested keys with dots, lists as
`[a,b]`); a few commands also take positional paths. Bad input raises a
`BenchError`, printed here on one line with exit code 2.
"""

from __future__ import annotations

import importlib
import sys

from bench import __version__
from bench.core.errors import ConfigError, valid_choices
from bench.core.guard import guarded

# name -> (handler "module:function", one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("bench.cli.run:main", "run a policy across a suite's tasks and conditions; writes records + summary"),
    "list": (
        "bench.cli.listing:main_list",
        "list registered suites (with their seen/unseen manifest) and policies",
    ),
    "check": ("bench.cli.check:main", "check a suite's split hygiene and its simulator contract"),
    "score": ("bench.cli.run:main_score", "re-score a run directory from its episodes.jsonl"),
    "leaderboard": (
        "bench.cli.leaderboard:main",
        "leaderboard tools: validate FILE | merge RUN... out=FILE | show FILE",
    ),
    "perf": ("bench.cli.perf:main", "measure harness throughput against raw simulator stepping"),
    "logs": (
        "bench.cli.logs:main",
        "real-log tools: info DIR | verify DIR | import SRC out=DIR | card DIR | rank DIR calibration=FILE",
    ),
    "replay": ("bench.cli.replay:main", "open-loop replay of logged commands in the simulator; per-joint RMSE/NRMSE"),
    "serve": ("bench.cli.serve:main", "serve a bench policy over openpi's websocket protocol (for policy=remote)"),
    "actions": ("bench.cli.actions:main", "policy on logs: a policy fed logged observations vs the logged actions"),
    "correlate": (
        "bench.cli.correlate:main",
        "sim-real agreement of per-policy outcomes: Pearson, Spearman, Kendall, MMRV",
    ),
    "calibrate": ("bench.cli.calibrate:main", "Real2Sim: fit a model to logs, trace the residual to missing effects"),
    "regress": (
        "bench.cli.regress:main",
        "CI regression gate: candidate vs baseline checkpoint, paired by seed (paired=false: unpaired runs)",
    ),
    "compare": ("bench.cli.compare:main", "which of two policies is better: paired by seed, stops at the answer"),
    "report": ("bench.cli.report:main", "static HTML report of a run, leaderboard or checkpoint sweep"),
    "coverage": ("bench.cli.coverage:main", "data-coverage metrics of a training set against a suite"),
    "predict": ("bench.cli.predict:main", "real success from a sim run plus a few real trials (prediction-powered)"),
    "sweep": ("bench.cli.sweep:main", "run a suite per training checkpoint; success vs step; the best, selected"),
}

USAGE = """usage: bench COMMAND [key=value ...]

Will this policy transfer? Runs policies across held-out robots, environments,
perturbed physics and real logs, and scores transfer gaps with intervals.

commands:
{commands}

examples:
  bench run suite=held_out_robots                     # its default policy (the committed BC checkpoint)
  bench run suite=held_out_robots policy=random episodes=10 workers=2
  bench run suite=held_out_robots robots=[UR5e,IIWA] episodes=5 seed=1 run_id=my_run
  bench list
  bench leaderboard validate runs/<run_id>/summary.json

`bench COMMAND --help` describes a command and its keys. Bad input exits 2; a run, score or gate that
measured nothing exits 3 (docs/guarantees.md).
"""


def _usage() -> str:
    width = max(len(n) for n in COMMANDS)
    lines = [f"  {name.ljust(width)}  {help_}" for name, (_, help_) in COMMANDS.items()]
    return USAGE.format(commands="\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    return guarded(lambda: _dispatch(argv))


def _dispatch(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    if argv[0] in ("-V", "--version"):
        print(f"bench {__version__}")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        raise ConfigError(f"unknown command {name!r}; {valid_choices(name, COMMANDS)}")
    module_name, func_name = COMMANDS[name][0].split(":")
    handler = getattr(importlib.import_module(module_name), func_name)
    return int(handler(rest) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
