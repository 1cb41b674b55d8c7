"""Leaderboard files: JSON Schema validation (and, later, merging and ranking).

Schemas ship inside the package (`bench/schemas/*.json`) and are versioned by the
file's `"schema"` field, e.g. `bench.summary/1`.
"""
from __future__ import annotations

import json
import math
from functools import lru_cache
from importlib.resources import files
from pathlib import Path
from typing import Any

from bench.errors import ConfigError, DataError

SCHEMAS = {"bench.summary/1": "summary-1.json"}


@lru_cache(maxsize=None)
def schema(schema_id: str) -> dict:
    """The JSON Schema for `schema_id` (e.g. "bench.summary/1")."""
    if schema_id not in SCHEMAS:
        raise DataError(f"unknown schema {schema_id!r}; known: {', '.join(SCHEMAS)}")
    return json.loads(files("bench").joinpath("schemas", SCHEMAS[schema_id]).read_text())


def _find_nan(obj: Any, path: str = "$") -> str | None:
    if isinstance(obj, float) and not math.isfinite(obj):
        return path
    if isinstance(obj, dict):
        for k, v in obj.items():
            p = _find_nan(v, f"{path}.{k}")
            if p:
                return p
    if isinstance(obj, list):
        for i, v in enumerate(obj):
            p = _find_nan(v, f"{path}[{i}]")
            if p:
                return p
    return None


def validate(doc: Any, source: str = "document") -> str:
    """Validate `doc` against the schema its `"schema"` field names; return that id.

    Raises DataError with one line naming the failing field.
    """
    import jsonschema

    if not isinstance(doc, dict) or "schema" not in doc:
        raise DataError(f"{source}: not a bench result (no 'schema' field); known schemas: {', '.join(SCHEMAS)}")
    sid = doc["schema"]
    nan_at = _find_nan(doc)
    if nan_at:
        raise DataError(f"{source}: field {nan_at} is NaN/inf; results must use null with a reason")
    validator = jsonschema.Draft202012Validator(schema(sid))
    errors = sorted(validator.iter_errors(doc), key=lambda e: list(e.absolute_path))
    if errors:
        e = errors[0]
        where = "$" + "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in e.absolute_path)
        raise DataError(f"{source}: field {where}: {e.message.splitlines()[0][:200]} (schema {sid})")
    return sid


def load_json(path: Path) -> Any:
    """Parse a JSON file; a missing or corrupt file is a one-line DataError."""
    path = Path(path)
    try:
        return json.loads(path.read_text(), parse_constant=lambda c: float(c))
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: not valid JSON ({str(exc).splitlines()[0]})") from None


USAGE = """usage: bench leaderboard validate FILE...

  validate FILE...   check result files (summary.json, leaderboard.json) against the JSON Schema
                     their "schema" field names; exit 0 when all are valid, 2 otherwise.
"""


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        return 0 if argv else 2
    cmd, rest = argv[0], argv[1:]
    if cmd == "validate":
        if not rest:
            raise ConfigError("leaderboard validate: give at least one FILE")
        for f in rest:
            sid = validate(load_json(Path(f)), str(f))
            print(f"{f}: valid ({sid})")
        return 0
    raise ConfigError(f"leaderboard: unknown subcommand {cmd!r}; valid: validate")
