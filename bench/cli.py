"""`bench` command line: a thin dispatcher onto one handler per subcommand.

Each subcommand lives in the module that owns its concept and exposes
`main(argv: list[str]) -> int`; it is imported only when called, so `bench list`
and `bench --help` stay fast (no simulator is imported).

Arguments are Hydra-style `key=value` overrides (nested keys with dots, lists as
`[a,b]`); a few commands also take positional paths. Bad input raises a
`BenchError`, printed here on one line with exit code 2.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable

from bench.errors import BenchError, ConfigError, valid_choices

# name -> (handler "module:function", one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("bench.run:main", "run a policy across a suite's tasks and conditions; writes records + summary"),
    "list": ("bench.registry:main_list", "list registered suites (with their seen/unseen manifest) and policies"),
    "check": ("bench.check:main", "check a suite's split hygiene and its simulator contract"),
    "score": ("bench.run:main_score", "re-score a run directory from its episodes.jsonl"),
    "leaderboard": ("bench.leaderboard:main", "leaderboard tools: validate FILE | merge RUN... out=FILE | show FILE"),
    "perf": ("bench.perf:main", "measure harness throughput against raw simulator stepping"),
    "logs": (
        "bench.logs.cli:main",
        "real-log tools: info DIR | import SRC out=DIR | card DIR | rank DIR calibration=FILE",
    ),
    "replay": ("bench.replay.cli:main", "open-loop replay of logged commands in the simulator; per-joint RMSE/NRMSE"),
    "serve": ("bench.remote.server:main", "serve a bench policy over openpi's websocket protocol (for policy=remote)"),
    "actions": ("bench.policy_on_logs:main", "policy on logs: a policy fed logged observations vs the logged actions"),
    "correlate": (
        "bench.agreement:main",
        "sim-real agreement of per-policy outcomes: Pearson, Spearman, Kendall, MMRV",
    ),
    "calibrate": ("bench.calibrate.cli:main", "Real2Sim: fit a model to logs, trace the residual to missing effects"),
    "regress": ("bench.regress:main", "CI regression gate: candidate vs baseline checkpoint, paired by seed"),
    "report": ("bench.report:main", "static HTML report of a run or leaderboard"),
    "coverage": ("bench.coverage:main", "data-coverage metrics of a training set against a suite"),
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

`bench COMMAND --help` describes a command and its keys. Bad input exits 2.
"""


def _usage() -> str:
    width = max(len(n) for n in COMMANDS)
    lines = [f"  {name.ljust(width)}  {help_}" for name, (_, help_) in COMMANDS.items()]
    return USAGE.format(commands="\n".join(lines))


def _one_line(text: str) -> str:
    """A message on one line (newlines of wrapped library messages folded), at most 2,000 characters."""
    line = " ".join(str(text).split())
    return line if len(line) <= 2000 else line[:1997] + "..."


def _quiet_pipe() -> int:
    """stdout's reader went away (`bench ... | head`): stop writing, say nothing, exit 0."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout is not a real file (captured): nothing left to flush
        pass
    return 0


def guarded(command: Callable[[], int | None]) -> int:
    """Run one command the way the CLI does: its exit code, never a traceback.

    Bad input (a `BenchError`) is one line on stderr and exit code 2; so is an OS error about a
    file (missing, unreadable, unwritable, a full disk: the line names the file). Ctrl-C keeps the
    records written so far (exit 130). A broken pipe (`bench ... --help | head`) exits quietly.
    Anything else is a bug in bench: one line saying so, exit 1 (`BENCH_TRACEBACK=1` prints the
    traceback instead). `python -m baselines.bc` and the other experiment scripts go through here too.
    """
    import os

    try:
        return int(command() or 0)
    except BenchError as exc:
        print(f"error: {_one_line(str(exc))}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("interrupted: records written so far are kept; rerun with the same run_id to resume", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return _quiet_pipe()
    except RecursionError:
        if os.environ.get("BENCH_TRACEBACK"):
            raise
        print("error: input nested too deeply to read", file=sys.stderr)
        return 2
    except MemoryError:
        if os.environ.get("BENCH_TRACEBACK"):
            raise
        print("error: out of memory (an input asks for more than this machine has)", file=sys.stderr)
        return 2
    except OSError as exc:
        if os.environ.get("BENCH_TRACEBACK"):
            raise
        where = exc.filename if exc.filename is not None else ""
        reason = exc.strerror or type(exc).__name__
        print(f"error: {_one_line(f'{where}: {reason}' if where else reason)}", file=sys.stderr)
        return 2
    except Exception as exc:  # a bug, not bad input: one line, and a way to see the traceback
        if os.environ.get("BENCH_TRACEBACK"):
            raise
        print(
            f"internal error: {type(exc).__name__}: {_one_line(str(exc))[:500]} (a bug in bench; "
            "BENCH_TRACEBACK=1 shows where)",
            file=sys.stderr,
        )
        return 1


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    return guarded(lambda: _dispatch(argv))


def _dispatch(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    if argv[0] in ("-V", "--version"):
        from bench import __version__

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
