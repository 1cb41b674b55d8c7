"""How a command ends: its exit code and at most one line on stderr, never a traceback (bad input exits 2).

`bench`'s dispatcher and the experiment scripts (`python -m baselines.bc` ...) both end through `guarded`.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable

from bench.core.errors import BenchError, NothingMeasured


def _one_line(text: str) -> str:
    """A message on one line (newlines of wrapped library messages folded), at most 2,000 characters."""
    line = " ".join(str(text).split())
    return line if len(line) <= 2000 else line[:1997] + "..."


def _quiet_pipe() -> int:
    """stdout's reader went away (`bench ... | head`): stop writing, say nothing, exit 0."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout is not a real file (captured): nothing left to flush
        pass
    return 0


def guarded(command: Callable[[], int | None]) -> int:
    """Run one command the way the CLI does: its exit code, never a traceback.

    Bad input (a `BenchError`) is one line on stderr and exit code 2; so is an OS error about a
    file (missing, unreadable, unwritable, a full disk: the line names the file). A run, score or
    gate that measured nothing (`NothingMeasured`) is one line starting `nothing measured:`, exit 3.
    Ctrl-C keeps the records written so far (exit 130). A broken pipe (`bench ... --help | head`)
    exits quietly.
    Anything else is a bug in bench: one line saying so, exit 1 (`BENCH_TRACEBACK=1` prints the
    traceback instead). `python -m baselines.bc` and the other experiment scripts go through here too.
    """
    try:
        return int(command() or 0)
    except NothingMeasured as exc:
        print(f"nothing measured: {_one_line(str(exc))}", file=sys.stderr)
        return exc.exit_code
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
