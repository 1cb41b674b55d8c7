"""The executor contract: what runs a plan's jobs (local processes, a Ray cluster, yours).

`bench.api.run(cfg, executor=...)` takes any object that meets `Executor`. What it can do beyond
running jobs is declared in `capabilities`, not found by probing attributes:

- `"cluster"`: it must reach (and size) a cluster before the first byte is written —
  `connect(n_jobs, suite, policy) -> workers` — and describes it in `cluster` (run.json's executor);
- `"notes"`: it reports progress lines itself; the run sets `note` to the progress bar's printer;
- `"status"`: its workers report what they wait for (a policy server warming up); the run sets `status` to
  the progress bar's `waiting(text, worker)`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from bench.core.errors import ConfigError
from bench.protocols.suite import Job

EXECUTOR_CAPABILITIES = frozenset({"cluster", "notes", "status"})


@runtime_checkable
class Executor(Protocol):
    """Runs jobs and hands back each episode record as it finishes, one call at a time."""

    capabilities: frozenset[str]

    def execute(self, jobs: list[Job], spec: Any, on_record: Callable[[Any], None]) -> None:
        """Run `jobs` with the worker spec `spec` (a `bench.execution.runner.WorkerSpec`): build each cell's
        env once per worker, run the episodes, call `on_record(record)` for each (a `bench.records.EpisodeRecord`),
        in finish order. Both types live in layers above this one, so the contract cannot name them."""
        ...

    def close(self) -> None:
        """Release what `execute` (or `connect`) acquired: processes, actors, a private cluster."""
        ...


@runtime_checkable
class ClusterExecutor(Executor, Protocol):
    """An executor with the "cluster" capability."""

    cluster: dict[str, object]  # JSON: run.json's executor

    def connect(self, jobs: int | None, suite_ref: str, policy_ref: str) -> int:
        """Reach the cluster (one line on failure) and return how many workers the run gets."""
        ...


def capabilities(executor: object) -> frozenset[str]:
    """An executor's declared capabilities (an object without the attribute declares none)."""
    caps = frozenset(getattr(executor, "capabilities", frozenset()))
    unknown = caps - EXECUTOR_CAPABILITIES
    if unknown:
        raise ConfigError(
            f"executor {type(executor).__name__} declares unknown capabilities {sorted(unknown)}; "
            f"valid: {', '.join(sorted(EXECUTOR_CAPABILITIES))}"
        )
    return caps
