"""Writing files safely and turning values into JSON: one owner for both.

Every file bench writes whole (summaries, run metadata, verdicts, reports' JSON, checkpoint
specs) goes through `write_text_atomic`: a temp file in the same folder, fsync, rename — a
reader never sees half a file and a crash never leaves a truncated one. JSON never holds
NaN or infinity: `jsonable` maps numpy types to Python ones and `finite_or_none` turns a
non-finite number into None (the caller records why).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any, SupportsFloat

import numpy as np

_UMASK = os.umask(0o022)
os.umask(_UMASK)  # read the process umask (set and restored at import)


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    """Write `data` to `path` via a temp file in the same folder + fsync + rename (never half a file)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
            os.fchmod(fh.fileno(), 0o666 & ~_UMASK)  # mkstemp makes 0600; give what open() would
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write UTF-8 `text` to `path` atomically (see `write_bytes_atomic`)."""
    write_bytes_atomic(path, text.encode("utf-8"))


def write_atomic(path: str | os.PathLike[str], obj: object) -> None:
    """Write `obj` as indented JSON (no NaN allowed) to `path` atomically."""
    write_text_atomic(path, json.dumps(obj, indent=2, sort_keys=False, allow_nan=False) + "\n")


def finite_or_none(value: SupportsFloat) -> float | None:
    """`value` as a float, or None when it is NaN or infinite (JSON has no such numbers)."""
    v = float(value)
    return v if math.isfinite(v) else None


def jsonable(x: object, digits: int | None = None) -> Any:  # JSON out
    """numpy scalars/arrays, tuples and nested containers -> plain Python, floats rounded to `digits`."""
    if isinstance(x, dict):
        return {str(k): jsonable(v, digits) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v, digits) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist(), digits)
    if isinstance(x, np.generic):
        return x.item()  # numpy scalars keep their full precision
    if isinstance(x, float) and digits is not None:
        return round(x, digits)
    return x


def json_safe(x: object) -> Any:  # JSON out
    """`jsonable(x)` with NaN / inf numbers as None and paths as strings: a document every JSON reader takes."""
    x = jsonable(x)
    if isinstance(x, dict):
        return {k: json_safe(v) for k, v in x.items()}
    if isinstance(x, list):
        return [json_safe(v) for v in x]
    if isinstance(x, float):
        return finite_or_none(x)
    if isinstance(x, os.PathLike):
        return os.fspath(x)
    return x


def first_nonfinite(obj: object, path: str = "$") -> str | None:
    """The JSON path of the first NaN/inf number inside `obj`, or None."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return path
    if isinstance(obj, dict):
        for k, v in obj.items():
            found = first_nonfinite(v, f"{path}.{k}")
            if found:
                return found
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            found = first_nonfinite(v, f"{path}[{i}]")
            if found:
                return found
    return None


def sha256_file(path: str | os.PathLike[str]) -> str:
    """The sha256 of a file's bytes (hex), read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
