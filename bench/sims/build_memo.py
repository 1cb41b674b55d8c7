"""Measurements an env build makes, made once per run and cell and shared by the workers that build that cell.

A suite's env may measure something when it is built (the Lift observer drives the gripper open and shut
to learn its joint range: ~1 s on UR5e, Jaco, Kinova3 and XArm7). When several workers build the same
cell (two workers splitting the last cell of a run, a Ray actor joining a cell), each would measure the
same thing again. While a worker builds a cell (`building`), `remembered(name, measure)` returns what the
first builder of that cell in this run measured, or measures and keeps it for the next.

Exact by construction: the memo lives in a folder the run makes for itself and removes when it ends
(`bench.execution.runner.memo_folder`), and is keyed by the cell, so only builds of the same cell from the
same config in the same invocation share a value, and a build is deterministic. A worker that cannot see
the folder (a Ray actor on another machine) measures for itself; outside `building` (a benchmark, a test,
a notebook) nothing is remembered. Values are dicts of numpy arrays, written atomically
(`bench.core.io.write_bytes_atomic`).
"""

from __future__ import annotations

import hashlib
import io
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path

import numpy as np

from bench.core.io import write_bytes_atomic

_BUILDING: ContextVar[tuple[str, str] | None] = ContextVar("bench_build_memo", default=None)


@contextmanager
def building(memo_dir: str | None, cell_key: str) -> Iterator[None]:
    """While the env of `cell_key` is built: `remembered` shares its measurements through `memo_dir`
    (None, or a folder this process cannot see: nothing is shared)."""
    token = _BUILDING.set((memo_dir, cell_key) if memo_dir and os.path.isdir(memo_dir) else None)
    try:
        yield
    finally:
        _BUILDING.reset(token)


def remembered(name: str, measure: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """What `measure()` returns for the cell being built: read from the memo when a worker of this run
    measured it already, else measured (and kept when a memo is active). `name` names the measurement
    (one file per cell and name)."""
    active = _BUILDING.get()
    if active is None:
        return measure()
    memo_dir, cell_key = active
    digest = hashlib.sha256(cell_key.encode()).hexdigest()[:24]
    path = Path(memo_dir) / f"{digest}.{name}.npz"
    try:
        with np.load(path, allow_pickle=False) as kept:
            return {k: kept[k] for k in kept.files}
    except FileNotFoundError:  # not measured yet in this run (files appear whole: tmp + rename)
        pass
    value = measure()
    buf = io.BytesIO()
    np.savez(buf, **value)
    try:
        write_bytes_atomic(path, buf.getvalue())
    except OSError:  # the folder cannot be written: nothing to share
        pass
    return value
