"""Shared test data: an episode record and a run's provenance with plain defaults, for tests of what reads them;
and what `bench run record=` and `bench calibrate` write, for tests of what reads those."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bench.cli import main
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


def recorded(tmp: Path, *keys: str, into: str = "rec") -> Path:
    """The dataset `bench run KEYS record=tmp/INTO` records (its run in tmp/runs; asserts the run exits 0)."""
    rec = tmp / into
    assert main(["run", *keys, "run_id=r", f"out={tmp / 'runs'}", f"record={rec}"]) == 0
    return rec


def calibrated(case: Path, out: Path, *keys: str, spec: Path | None = None) -> Path:
    """`bench calibrate spec=SPEC logs=CASE/logs out=OUT quiet=true KEYS` of a generated case (SPEC: the case's
    spec.yaml unless given), asserted to exit 0: the calibration.json it wrote."""
    argv = [f"spec={spec or case / 'spec.yaml'}", f"logs={case / 'logs'}", f"out={out}", "quiet=true", *keys]
    assert main(["calibrate", *argv]) == 0
    return out / "calibration.json"


def each_env(suite: Any, horizon: int = 10) -> Iterator[tuple[Any, Any]]:
    """(cell, env) for every cell of `suite`, its env built for the turn and closed after it."""
    for cell in suite.all_cells():
        env = suite.make_env(cell, horizon)
        try:
            yield cell, env
        finally:
            env.close()
