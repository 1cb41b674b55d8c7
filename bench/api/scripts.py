"""Command lines of scripts built on bench (`python -m baselines.bc ...`): the same grammar, help and errors.

`build_from_argv` parses `key=value` arguments onto a frozen dataclass (an unknown key is an error
with a suggestion), `command_help` writes `--help` from that dataclass, and `guarded` ends the
script as every bench command ends: bad input is one line on stderr and exit code 2.
"""

from __future__ import annotations

from bench.core.config import build_from_argv, command_help
from bench.core.guard import guarded

__all__ = ["build_from_argv", "command_help", "guarded"]
