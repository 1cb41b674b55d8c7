"""Exceptions of the harness: one class per kind of failure; bad input is exit code 2 at the CLI.

Messages are one line: they name the field, the bad value and what would be valid. The one
exception that is not bad input is `NothingMeasured` (exit 3): the command ran, but no episode
(or no episode of some cell) completed, so its numbers measure nothing (docs/guarantees.md).
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable


class BenchError(Exception):
    """Bad input the user can fix; the CLI prints the message on one line and exits 2."""

    exit_code = 2


class ConfigError(BenchError):
    """An unknown key or a value of the wrong type in the `key=value` overrides."""


class RegistryError(BenchError):
    """A suite or policy name that no entry point provides."""


class DataError(BenchError):
    """A log, dataset or result file that is missing, malformed or inconsistent."""


class SpecError(BenchError):
    """A malformed calibration or policy spec."""


class SplitError(BenchError):
    """A suite whose seen/unseen split is not clean (overlap, repeated initial states)."""


def did_you_mean(value: str, valid: Iterable[str]) -> str:
    """Return ' Did you mean X?' for the closest valid name, or '' when nothing is close."""
    match = difflib.get_close_matches(str(value), [str(v) for v in valid], n=1, cutoff=0.5)
    return f" Did you mean {match[0]!r}?" if match else ""


def valid_choices(value: str, valid: Iterable[str]) -> str:
    """Return 'valid: A, B, C.' and, when one is close to `value`, ' Did you mean X?' (the end of an error line)."""
    names = list(valid)  # a dict gives its keys
    return f"valid: {', '.join(names)}.{did_you_mean(value, names)}"


class ExecutorError(BenchError):
    """The jobs cannot run where asked: a worker that cannot start, an unreachable or mismatched Ray cluster."""


class NothingMeasured(BenchError):
    """A run, score or gate in which no episode completed, or a cell has none while others do (exit 3).

    Not bad input: everything was written (records, summary) and is kept; the one line says which
    cells measured nothing and why their episodes failed.
    """

    exit_code = 3
