"""Result documents: the shipped JSON Schemas, validation and reading JSON files.

Schemas ship inside the package (`bench/core/schemas/*.json`) and are versioned by a
document's `"schema"` field, e.g. `bench.summary/1`. A document holding NaN or
infinity is refused before the schema is even consulted: results say null + a reason.
"""

from __future__ import annotations

import json
from functools import cache
from importlib.resources import files
from pathlib import Path
from typing import Any

from bench.core.errors import DataError
from bench.core.io import first_nonfinite

SCHEMAS = {
    "bench.summary/1": "summary-1.json",
    "bench.leaderboard/1": "leaderboard-1.json",
    "bench.regress/1": "regress-1.json",
    "bench.regress/2": "regress-2.json",
    "bench.compare/1": "compare-1.json",
    "bench.sweep/1": "sweep-1.json",
}


@cache
def schema(schema_id: str) -> dict[str, object]:
    """The JSON Schema for `schema_id` (e.g. "bench.summary/1")."""
    if schema_id not in SCHEMAS:
        raise DataError(f"unknown schema {schema_id!r}; known: {', '.join(SCHEMAS)}")
    doc: dict[str, object] = json.loads(files("bench.core").joinpath("schemas", SCHEMAS[schema_id]).read_text())
    return doc


def validate(doc: object, source: str = "document") -> str:
    """Validate `doc` against the schema its `"schema"` field names; return that id.

    Raises DataError with one line naming the failing field.
    """
    import jsonschema  # jsonschema: loaded only when a result is validated

    if not isinstance(doc, dict) or "schema" not in doc:
        raise DataError(f"{source}: not a bench result (no 'schema' field); known schemas: {', '.join(SCHEMAS)}")
    sid = doc["schema"]
    if not isinstance(sid, str) or sid not in SCHEMAS:
        raise DataError(f"{source}: unknown schema {str(sid)[:80]!r} (field $.schema); known: {', '.join(SCHEMAS)}")
    nan_at = first_nonfinite(doc)
    if nan_at:
        raise DataError(f"{source}: field {nan_at} is NaN/inf; results must use null with a reason")
    validator = jsonschema.Draft202012Validator(schema(sid))
    errors = sorted(validator.iter_errors(doc), key=lambda e: list(e.absolute_path))
    if errors:
        e = errors[0]
        where = "$" + "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in e.absolute_path)
        raise DataError(f"{source}: field {where}: {e.message.splitlines()[0][:200]} (schema {sid})")
    problem = semantic_problem(doc)
    if problem:
        raise DataError(f"{source}: {problem} (schema {sid})")
    return sid


_COUNTS = ("n", "episodes", "successes", "errors", "trials", "pairs", "seed", "n_boot")
_TOL = 1e-6
_DIFFERENCES = ("drop", "gap", "diff", "vs_", "change", "delta", "slope")  # differences of rates lie in [-1, 1]


def semantic_problem(obj: object, path: str = "$", rate: bool = False, n: int | None = None) -> str | None:
    """What a JSON Schema cannot say about a result, or None: every estimate's interval is ordered and holds
    its value; success rates and their intervals lie in [0, 1]; counts and seeds are non-negative integers;
    successes never exceed episodes."""
    if isinstance(obj, dict):
        ci, value = obj.get("ci"), obj.get("value")
        if isinstance(ci, list) and len(ci) == 2 and all(isinstance(c, (int, float)) for c in ci):
            lo, hi = float(ci[0]), float(ci[1])
            if lo > hi + _TOL:
                return f"field {path}.ci is [{lo:g}, {hi:g}]: an interval's lower end must not exceed its upper end"
            if (
                isinstance(value, (int, float))
                and not isinstance(value, bool)
                and not lo - _TOL <= float(value) <= hi + _TOL
            ):
                return f"field {path}.value is {value:g}, outside its interval [{lo:g}, {hi:g}]"
            if rate and (lo < -_TOL or hi > 1 + _TOL):
                return f"field {path}.ci is [{lo:g}, {hi:g}]: a success rate's interval lies in [0, 1]"
        if rate and isinstance(value, (int, float)) and not isinstance(value, bool) and not -_TOL <= value <= 1 + _TOL:
            return f"field {path}.value is {value:g}: a success rate lies in [0, 1]"
        for key in _COUNTS:
            v = obj.get(key)
            if isinstance(v, (int, float)) and not isinstance(v, bool) and v < 0:
                return f"field {path}.{key} is {v:g}; valid: a non-negative integer"
        own = obj.get("n", obj.get("episodes"))
        n = own if isinstance(own, int) and not isinstance(own, bool) else n
        k = obj.get("successes")
        if isinstance(k, int) and isinstance(n, int) and k > n:
            return f"field {path}.successes is {k}, more than the {n} episodes"
        for key, v in obj.items():
            name = str(key)
            is_rate = rate or ("success" in name and not any(w in path + name for w in _DIFFERENCES))
            found = semantic_problem(v, f"{path}.{key}", is_rate, n)
            if found:
                return found
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            if path.endswith("seeds") and isinstance(v, int) and not isinstance(v, bool) and v < 0:
                return f"field {path}[{i}] is {v}; valid: a non-negative integer"
            found = semantic_problem(v, f"{path}[{i}]", rate, n)
            if found:
                return found
    return None


def load_json(path: Path, expect: type | None = None) -> Any:
    """Parse a JSON file; a missing or corrupt file is a one-line DataError.

    With `expect` (e.g. dict), a document of another JSON type is refused too.
    """
    path = Path(path)
    doc = _parse_json(path)
    if expect is not None and not isinstance(doc, expect):
        raise DataError(f"{path}: expected a JSON {expect.__name__}, found {type(doc).__name__}")
    return doc


def _parse_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"), parse_constant=lambda c: float(c))
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise DataError(f"{path}: is a folder, not a JSON file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: not valid JSON ({str(exc).splitlines()[0]})") from None
    except (RecursionError, ValueError) as exc:  # nesting too deep; integers of thousands of digits
        raise DataError(
            f"{path}: not a JSON file bench can read ({type(exc).__name__}: {str(exc).splitlines()[0][:120]})"
        ) from None
