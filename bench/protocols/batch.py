"""Capability of envs that are worlds of one batched simulator (an MJX suite): the vectorised runner steps the
worlds of a batch in one call (`bench.execution.vector.step_batches`), then each world's own `step` reads its row.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol, runtime_checkable

import numpy.typing as npt


@runtime_checkable
class WorldBatch(Protocol):
    """A batched simulator holding several worlds."""

    def step_all(self, actions: Mapping[int, npt.ArrayLike]) -> None:
        """One control step of the worlds named in `actions` (world index -> action) in one call; the others keep
        their state. Each stepped world's next `step` returns that call's result instead of stepping again."""
        ...


@runtime_checkable
class BatchEnv(Protocol):
    """An env adapter that is world `index` of `batch` (e.g. `bench.sims.mjx_lift.World`)."""

    batch: WorldBatch
    index: int


def batch_of(env: object) -> WorldBatch | None:
    """The batch `env` is a world of, or None for an env that steps alone."""
    if isinstance(env, BatchEnv) and isinstance(env.batch, WorldBatch):
        return env.batch
    return None
