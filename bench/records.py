"""Per-episode records: the single source of truth of a run.

`runs/<run_id>/episodes.jsonl` gets one JSON line per finished episode, flushed and
fsynced as it lands, so a run killed with `kill -9` loses at most the episodes in
flight. Reading tolerates (and repairs) a torn last line. Every aggregate is
recomputed from these records, so a resumed run scores like an uninterrupted one.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path

from bench.core.errors import DataError

EPISODES = "episodes.jsonl"
TIMING_FIELDS = ("wall_s", "finished_at", "worker_pid")
SUCCESS_METRICS = ("success_once", "success_at_end")  # a record's 0/1 outcomes


@dataclass
class EpisodeRecord:
    """What happened in one episode (see DESIGN.md, EpisodeRecord)."""

    run_id: str
    job_id: str
    suite: str
    suite_version: str
    task: str
    robot: str
    env: str
    split: str
    condition: str
    axis: str | None
    level: float | list[float] | None  # the condition's level: a value, a [low, high] range, or None (nominal)
    params: dict[str, object]  # sampled perturbation values actually applied (JSON: numbers, strings, lists)
    episode: int
    seed: int
    init_state_hash: str | None
    success_once: bool
    success_at_end: bool
    return_: float
    length: int
    steps_to_success: int | None
    error: str | None
    policy: str
    checkpoint_sha256: str | None
    backend: str | None
    wall_s: float
    finished_at: float
    worker_pid: int
    versions: dict[str, str] = field(default_factory=dict)
    extras: dict[str, object] = field(default_factory=dict)  # e.g. {"policy": policy stats}; omitted when empty

    def to_json(self) -> str:
        d = asdict(self)
        d["return"] = d.pop("return_")
        if not d["extras"]:
            del d["extras"]
        return json.dumps(d, sort_keys=True, allow_nan=False)

    @classmethod
    def from_dict(cls, d: object) -> EpisodeRecord:
        """The record a parsed JSON line holds (TypeError naming the first field that is not a record's)."""
        if not isinstance(d, dict):
            raise TypeError(f"a record is a JSON object, not {type(d).__name__}")
        d = dict(d)
        d["return_"] = d.pop("return")
        bad = check_fields(d)
        if bad:
            raise TypeError(bad)
        return cls(**d)


_NUM = (int, float)
_FIELD_TYPES: dict[str, tuple[tuple[type, ...], bool]] = {  # field -> (types, may be null); `level` is any value
    "run_id": ((str,), False),
    "job_id": ((str,), False),
    "suite": ((str,), False),
    "suite_version": ((str,), False),
    "task": ((str,), False),
    "robot": ((str,), False),
    "env": ((str,), False),
    "split": ((str,), False),
    "condition": ((str,), False),
    "axis": ((str,), True),
    "episode": ((int,), False),
    "seed": ((int,), False),
    "success_once": ((bool,), False),
    "success_at_end": ((bool,), False),
    "return_": (_NUM, True),
    "length": ((int,), False),
    "steps_to_success": ((int,), True),
    "error": ((str,), True),
    "params": ((dict,), False),
    "init_state_hash": ((str,), True),
    "policy": ((str,), False),
    "checkpoint_sha256": ((str,), True),
    "backend": ((str,), True),
    "wall_s": (_NUM, False),
    "finished_at": (_NUM, False),
    "worker_pid": ((int,), False),
    "versions": ((dict,), False),
    "extras": ((dict,), False),
}


def check_fields(d: Mapping[str, object]) -> str | None:
    """What is wrong with a record's fields (type, sign, finiteness), or None."""
    for name, (types, nullable) in _FIELD_TYPES.items():
        if name not in d:
            continue
        v = d[name]
        shown = "return" if name == "return_" else name
        if v is None:
            if nullable:
                continue
            return f"field {shown!r} is null"
        if isinstance(v, bool) and bool not in types:
            return f"field {shown!r} is {v!r}; expected {' or '.join(t.__name__ for t in types)}"
        if not isinstance(v, types):
            return f"field {shown!r} is {v!r}; expected {' or '.join(t.__name__ for t in types)}"
        if isinstance(v, float) and not math.isfinite(v):
            return f"field {shown!r} is {v}; records hold finite numbers (null with an error for a failed episode)"
        if name in ("episode", "seed", "length", "steps_to_success") and isinstance(v, int) and v < 0:
            return f"field {shown!r} is {v}; valid: a non-negative integer"
    return None


class RecordWriter:
    """Append-only writer; each record is flushed and fsynced before `write` returns."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        _repair_torn_tail(self.path)
        self._fh = open(self.path, "a", encoding="utf-8")

    def write(self, record: EpisodeRecord) -> None:
        self._fh.write(record.to_json() + "\n")
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> RecordWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _repair_torn_tail(path: Path) -> None:
    """Cut a partial last line left by a killed process (no newline at the end)."""
    if not path.exists() or path.stat().st_size == 0:
        return
    with open(path, "rb+") as fh:
        data = fh.read()
        if data.endswith(b"\n"):
            return
        cut = data.rfind(b"\n") + 1
        fh.truncate(cut)


def read_records(path: Path) -> list[EpisodeRecord]:
    """All complete records in `path`; a torn last line is ignored, a corrupt middle line is an error."""
    path = Path(path)
    if not path.exists():
        return []
    out: list[EpisodeRecord] = []
    lines = path.read_bytes().split(b"\n")
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            out.append(EpisodeRecord.from_dict(json.loads(line)))
        except (json.JSONDecodeError, UnicodeDecodeError, TypeError, KeyError, RecursionError, ValueError) as exc:
            if i == len(lines) - 1:  # torn tail of a killed run
                break
            why = f"field {exc.args[0]!r} is missing" if isinstance(exc, KeyError) else str(exc).splitlines()[0][:200]
            raise DataError(f"{path}: line {i + 1} is not an episode record ({why})") from None
    return out


def dedupe(records: Iterable[EpisodeRecord]) -> list[EpisodeRecord]:
    """Keep the first record per job id (merged or re-run directories may repeat jobs)."""
    seen, out = set(), []
    for r in records:
        if r.job_id not in seen:
            seen.add(r.job_id)
            out.append(r)
    return out


def comparable(record: EpisodeRecord) -> dict[str, object]:
    """The record without timing fields and run id: two runs with the same seed must agree on this."""
    d: dict[str, object] = json.loads(record.to_json())
    for k in (*TIMING_FIELDS, "run_id"):
        d.pop(k, None)
    return d
