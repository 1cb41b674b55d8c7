"""Shared test data: an episode record and a run's provenance with plain defaults, for tests of what reads them."""

from __future__ import annotations

from typing import Any

from bench.records import EpisodeRecord

DEFAULTS: dict[str, Any] = dict(
    run_id="r",
    suite="s",
    suite_version="1",
    task="Lift",
    robot="Panda",
    env="default",
    split="seen",
    condition="nominal",
    axis=None,
    level=None,
    params={},
    episode=0,
    seed=0,
    init_state_hash="h",
    success_once=False,
    success_at_end=False,
    return_=0.0,
    length=10,
    steps_to_success=None,
    error=None,
    policy="p",
    checkpoint_sha256=None,
    backend="b",
    wall_s=0.0,
    finished_at=0.0,
    worker_pid=0,
)


def record(success: bool | None = None, **fields: Any) -> EpisodeRecord:
    """An EpisodeRecord: DEFAULTS, then `success` for both success flags, then `fields`.

    The job_id follows the runner's `TASK/ROBOT/ENV|CONDITION|EPISODE` unless given.
    """
    values = dict(DEFAULTS)
    if success is not None:
        values["success_once"] = values["success_at_end"] = bool(success)
    values.update(fields)
    values["params"] = dict(values["params"])
    values.setdefault(
        "job_id", f"{values['task']}/{values['robot']}/{values['env']}|{values['condition']}|{values['episode']}"
    )
    return EpisodeRecord(**values)


def provenance(**fields: Any) -> dict[str, Any]:
    """A summary's `provenance` block (schema bench.scoring.summary): plain values, then `fields`."""
    values: dict[str, Any] = {
        "bench_version": "0",
        "git_sha": None,
        "packages": {},
        "python": "3",
        "platform": "x",
        "cores": 2,
        "workers": 1,
        "backend": [],
        "seed": 0,
        "episode_seeds": [],
        "started_at": "s",
        "finished_at": None,
    }
    values.update(fields)
    return values
