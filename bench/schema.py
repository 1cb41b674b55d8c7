"""Result documents: the shipped JSON Schemas, validation and reading JSON files.

Schemas ship inside the package (`bench/schemas/*.json`) and are versioned by a
document's `"schema"` field, e.g. `bench.summary/1`. A document holding NaN or
infinity is refused before the schema is even consulted: results say null + a reason.
"""
from __future__ import annotations

import json
from functools import lru_cache
from importlib.resources import files
from pathlib import Path
from typing import Any

from bench.errors import DataError
from bench.io import first_nonfinite

SCHEMAS = {"bench.summary/1": "summary-1.json", "bench.leaderboard/1": "leaderboard-1.json",
           "bench.regress/1": "regress-1.json"}


@lru_cache(maxsize=None)
def schema(schema_id: str) -> dict:
    """The JSON Schema for `schema_id` (e.g. "bench.summary/1")."""
    if schema_id not in SCHEMAS:
        raise DataError(f"unknown schema {schema_id!r}; known: {', '.join(SCHEMAS)}")
    return json.loads(files("bench").joinpath("schemas", SCHEMAS[schema_id]).read_text())


def validate(doc: Any, source: str = "document") -> str:
    """Validate `doc` against the schema its `"schema"` field names; return that id.

    Raises DataError with one line naming the failing field.
    """
    import jsonschema

    if not isinstance(doc, dict) or "schema" not in doc:
        raise DataError(f"{source}: not a bench result (no 'schema' field); known schemas: {', '.join(SCHEMAS)}")
    sid = doc["schema"]
    if not isinstance(sid, str) or sid not in SCHEMAS:
        raise DataError(f"{source}: field 'schema': unknown schema {str(sid)[:80]!r}; "
                        f"known schemas: {', '.join(SCHEMAS)}")
    nan_at = first_nonfinite(doc)
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
