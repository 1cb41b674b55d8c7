"""A plan run: its run directory started (`start`: run.json, the context workers share), the episodes executed
by the plan's executor with progress, the records scored into summary.json (`finish`, `score`), and `run`,
which does all of that for a config or a plan. Re-exported by `bench.api`."""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, cast

from bench import __version__
from bench.api.planning import (
    Plan,
    make_executor,
    plan,
)
from bench.core import config as config_mod
from bench.core import provenance
from bench.core.errors import (
    ConfigError,
)
from bench.core.io import write_atomic
from bench.core.schema import load_json, validate
from bench.execution.progress import RunProgress
from bench.execution.rollout import RunContext
from bench.execution.run_config import (
    RESUMABLE_KEYS,
    RunConfig,
)
from bench.execution.run_lock import RunLock
from bench.execution.runner import Worker, memo_folder
from bench.protocols.executor import ClusterExecutor, Executor, capabilities
from bench.protocols.suite import Job, SuiteSpec
from bench.records import EPISODES, EpisodeRecord, RecordWriter, read_records
from bench.scoring.summary import build, load_run
from bench.scoring.typed import RunMeta


@dataclass(frozen=True)
class RunResult:
    """What `run` produced: the run directory, its summary and all its records."""

    run_dir: Path
    summary: dict[str, Any] | None
    records: list[EpisodeRecord]
    ran: int  # episodes run by this call
    resumed: int  # episodes found already recorded


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _calibration_sha(meta: dict[str, Any]) -> str | None:
    return ((meta.get("provenance") or {}).get("calibration") or {}).get("sha256")


def calibration_notes(p: Plan) -> list[str]:
    """What a run's calibration is, for the user before its episodes: one line naming it and its verdict, and a
    `warning: ...` line when its model simulates the held-out data worse than the declared one or was never
    checked (strict=true refuses those in `plan`). Empty without calibration=."""
    if p.calibration is None:
        return []
    from bench.calibrate.apply import describe, warning  # mujoco: only calibration= runs need it

    loaded = p.calibration.loaded()
    warned = warning(loaded)
    return [describe(loaded), *([f"warning: {warned}"] if warned else [])]


def start(p: Plan, workers: int) -> tuple[dict[str, Any], RunContext]:
    """Open (or resume) the run directory: writes run.json; returns (run metadata, RunContext)."""
    cfg = p.config
    packages = provenance.package_versions()
    meta = RunMeta(
        run_id=str(cfg.run_id),
        suite=p.suite.describe(),
        suite_spec=SuiteSpec.of(p.suite.describe(), packages).to_json(),  # what was run, comparable across runs
        policy={
            "name": cfg.policy,
            "checkpoint": provenance.portable(p.identity.checkpoint),
            "checkpoint_sha256": p.identity.checkpoint_sha256,
        },
        config=provenance.portable_config(p.config_dict()),
        expected_episodes=len(p.jobs),
        provenance={
            "bench_version": __version__,
            "git_sha": provenance.git_sha(),
            "packages": packages,
            **provenance.machine(),
            "workers": workers,
            "backend": [],
            "seed": cfg.seed,
            "episode_seeds": sorted({j.seed for j in p.jobs}),
            "started_at": _now(),
            "finished_at": None,
            **({"calibration": p.calibration.provenance()} if p.calibration else {}),
        },
    ).to_json()
    meta_path = p.run_dir / "run.json"
    if meta_path.exists():
        old = load_json(meta_path)
        new_cfg = meta["config"]
        old_cfg = provenance.portable_config(old.get("config", {}))  # a run recorded before paths were portable
        diffs = [
            k
            for k in sorted(set(old_cfg) | set(new_cfg))
            if k not in RESUMABLE_KEYS and old_cfg.get(k) != new_cfg.get(k)
        ]
        if diffs:
            k = diffs[0]
            raise ConfigError(
                f"run_id={cfg.run_id!r} exists with {k}={old.get('config', {}).get(k)!r} (now "
                f"{new_cfg.get(k)!r}); use the same settings to resume it, or a new run_id"
            )
        was, now = (_calibration_sha(old), _calibration_sha(meta))
        if was != now:  # the same calibration path may hold a newer fit: never mix two robots in one run
            raise ConfigError(
                f"run_id={cfg.run_id!r} was recorded with calibration sha256 {str(was)[:12]} (now "
                f"{str(now)[:12]}); resume it with the same calibration, or use a new run_id"
            )
        meta = old
    else:
        write_atomic(meta_path, meta)
    ctx = dataclasses.replace(
        context(p),
        timeout_s=cfg.timeout,
        trajectory_dir=str(p.run_dir / "trajectories") if cfg.record else None,
        video_dir=str(p.run_dir) if cfg.video else None,
        video_episodes=cfg.video,
    )
    return meta, ctx


def finish(p: Plan, meta: dict[str, Any], workers: int) -> dict[str, Any]:
    """Stamp run.json (finish time, workers, backends), write and return the validated summary.json."""
    records = read_records(p.run_dir / EPISODES)
    meta["provenance"]["finished_at"] = _now()
    meta["provenance"]["workers"] = workers
    meta["provenance"]["backend"] = sorted({r.backend for r in records if r.backend})
    write_atomic(p.run_dir / "run.json", meta)
    summary = build(records, run_meta=meta).to_json()
    validate(summary, "summary")
    write_atomic(p.run_dir / "summary.json", summary)
    return summary


def run(
    cfg: RunConfig | Plan,
    *,
    only: Callable[[Job], bool] | None = None,
    progress: bool = False,
    summarize: bool = True,
    executor: Executor | None = None,
    on_record: Callable[[EpisodeRecord], None] | None = None,
) -> RunResult:
    """Run a config or a plan into its run directory; recorded episodes are skipped (resume).

    The run directory is locked for the call (`bench.execution.run_lock`): a second writer is refused
    (`RunLocked`, nothing written), and the lock of a killed run is taken over.

    Args:
        cfg: a RunConfig (planned here) or a Plan from `plan`.
        only: run only the jobs it accepts (e.g. the first k episodes); the others stay to do.
        progress: show a progress bar on stderr.
        summarize: write summary.json when done (and assemble `record=` datasets).
        executor: a `bench.protocols.executor.Executor` (its `capabilities` say whether it reaches a
            cluster first or prints notes); default: local processes, or Ray with executor=ray.
        on_record: called with each new record after it is written.
    """
    p = cfg if isinstance(cfg, Plan) else plan(cfg)
    lock = RunLock(p.run_dir)  # one writer per run directory, held until the summary is written
    try:
        lock.acquire()
    except BaseException:
        if executor is not None:
            executor.close()  # its prestarted children hold nothing but imports
        raise
    try:
        return _run_locked(p, lock, only, progress, summarize, executor, on_record)
    finally:
        lock.release()


def _run_locked(
    p: Plan,
    lock: RunLock,
    only: Callable[[Job], bool] | None,
    progress: bool,
    summarize: bool,
    executor: Executor | None,
    on_record: Callable[[EpisodeRecord], None] | None,
) -> RunResult:
    """`run` with the run directory's lock held."""
    c = p.config
    episodes_path = p.run_dir / EPISODES
    done_ids = {r.job_id for r in read_records(episodes_path)}
    todo = [j for j in p.jobs if j.job_id not in done_ids and (only is None or only(j))]
    workers = min(p.workers, max(1, len(todo)))  # no more workers than episodes to run
    executor = executor or make_executor(c, workers)
    caps = capabilities(executor)  # what it declares (bench.protocols.executor), never probed
    try:
        if todo and "cluster" in caps:  # a cluster: reached and sized before anything is written
            workers = cast(ClusterExecutor, executor).connect(len(todo), p.config.suite, str(p.config.policy))
        meta, ctx = start(p, workers)
        t0 = time.time()
        with (
            RecordWriter(episodes_path) as writer,
            RunProgress(progress, c, len(todo), len(done_ids), len(p.jobs), p.run_dir, workers) as bar,
        ):
            if lock.took_over is not None:
                bar.note(f"took over the lock of {lock.took_over.describe()}, which is gone (a run that was killed)")

            def write(record: EpisodeRecord) -> None:
                writer.write(record)
                bar.advance(record)
                if on_record is not None:
                    on_record(record)

            if progress and "notes" in caps:
                cast(Any, executor).note = bar.note
            if progress and "status" in caps:
                cast(Any, executor).status = bar.waiting  # what a worker waits for (a policy server warming up)
            with memo_folder() as memo:  # what one build of a cell measures, for the workers that build it again
                executor.execute(todo, p.worker_spec(ctx, memo), write)
    finally:
        executor.close()
    meta["provenance"]["executor"] = (
        c.executor if "cluster" not in caps else {"kind": c.executor, **cast(ClusterExecutor, executor).cluster}
    )
    summary = finish(p, meta, workers) if summarize else None
    records = read_records(episodes_path)
    if summarize and c.record:
        from bench.execution.recording import assemble  # pyarrow (LeRobot writer): only record= runs need it

        path = assemble(records, p.run_dir / "trajectories", Path(c.record))
        bar.note(f"recorded {sum(r.error is None for r in records)} episodes as a LeRobot v3 dataset: {path}")
    bar.note(
        f"{len(todo)} episode{'' if len(todo) == 1 else 's'} in {time.time() - t0:.1f} s; records: {episodes_path}"
    )
    return RunResult(p.run_dir, summary, records, len(todo), len(done_ids))


def score(run_dir: str | os.PathLike[str]) -> dict[str, Any]:
    """Recompute, validate and write RUN_DIR/summary.json from its episodes.jsonl (the source of truth)."""
    records, meta = load_run(Path(run_dir))
    config_mod.check_stored(
        RunConfig, meta.get("config") if isinstance(meta, dict) else None, str(Path(run_dir) / "run.json")
    )
    summary = build(records, run_meta=meta).to_json()
    validate(summary, "summary")
    write_atomic(Path(run_dir) / "summary.json", summary)
    return summary


def context(p: Plan, run_id: str | None = None) -> RunContext:
    """The RunContext workers of plan `p` share, for runs that write no run directory (benchmarks)."""
    return RunContext(
        run_id=run_id or str(p.config.run_id),
        suite_version=p.suite.version,
        policy_id=str(p.config.policy),
        checkpoint_sha256=p.identity.checkpoint_sha256,
        versions=provenance.package_versions(),
        horizon=p.horizon,
        timeout_s=0,
        policy_stats=bool(p.plugin.reports_stats),
    )


def worker(p: Plan, ctx: RunContext | None = None) -> Worker:
    """An in-process worker of a plan (benchmarks time episodes with it; nothing is written)."""
    return Worker(p.worker_spec(ctx or context(p)))
