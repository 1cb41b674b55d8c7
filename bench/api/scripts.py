"""Command lines of scripts built on bench (`python -m baselines.bc ...`): the same grammar, help and errors.

`build_from_argv` parses `key=value` arguments onto a frozen dataclass (an unknown key is an error
with a suggestion), `command_help` writes `--help` from that dataclass, and `guarded` ends the
script as every bench command ends: bad input is one line on stderr and exit code 2. `script_keys`
is the light form for benchmark scripts: `key=value` strings checked against the keys the script
reads, `--help` printing its docstring; `whole` reads one of them as a whole number, naming the key when it is not.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Sequence

from bench.core.config import build_from_argv, command_help
from bench.core.errors import ConfigError, did_you_mean
from bench.core.guard import guarded

__all__ = ["build_from_argv", "command_help", "guarded", "script_keys", "whole"]


def script_keys(argv: Sequence[str], doc: str | None, keys: Iterable[str]) -> dict[str, str]:
    """`key=value` arguments of a script as strings; `-h`/`--help` prints `doc` and exits 0; an argument that is
    not `key=value` with a key of `keys` is one line on stderr and exit 2."""
    valid = sorted(keys)
    if any(a in ("-h", "--help") for a in argv):
        print((doc or "").strip())
        raise SystemExit(0)
    out: dict[str, str] = {}
    for a in argv:
        key, eq, value = a.partition("=")
        if not eq or key not in valid:
            hint = did_you_mean(key, valid) if eq else ""
            print(f"error: {a!r}: arguments are key=value with a key of {', '.join(valid)}.{hint}", file=sys.stderr)
            raise SystemExit(2)
        out[key] = value
    return out


def whole(keys: dict[str, str], key: str, default: int) -> int:
    """`keys[key]` (from `script_keys`) as an int, `default` when absent; ConfigError naming the key otherwise."""
    text = keys.get(key, str(default))
    try:
        return int(text)
    except ValueError:
        raise ConfigError(f"{key}={text!r}: expected a whole number") from None
