"""Execute jobs on an executor (serial or a process pool), envs built once per worker.

Each worker keeps a cache cell -> (env, policy); jobs arrive cell-major, so a worker
builds each cell's simulator once and soft-resets it for every episode. Finished
records stream back to the parent, which appends them to episodes.jsonl as they land.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Callable, Iterable

from bench.records import EpisodeRecord
from bench.rollout import RunContext, run_episode
from bench.suite import Job

# -- worker side -----------------------------------------------------------------------------
_W: dict = {}


def _init_worker(suite_name: str, policy_name: str, cfg, ctx: RunContext) -> None:
    import warnings

    warnings.filterwarnings("ignore")
    from bench import registry

    _W.clear()
    _W.update(suite=registry.make_suite(suite_name), factory=registry.policy_factory(policy_name),
              cfg=cfg, ctx=ctx, cache={})


def _run_job(job: Job) -> EpisodeRecord:
    cache = _W["cache"]
    key = job.cell.key
    built = cache.get(key)
    if built is None:
        try:
            env = _W["suite"].make_env(job.cell, _W["ctx"].horizon)
            policy = _W["factory"](job.cell, env, _W["cfg"])
        except Exception as exc:  # a cell whose env cannot be built: record, go on
            return _error_record(job, f"building env/policy failed: {type(exc).__name__}: {exc}")
        built = cache[key] = (env, policy)
    env, policy = built
    record, usable = run_episode(job, env, policy, _W["ctx"])
    if not usable:  # the env may be in a bad state after an error: rebuild next time
        cache.pop(key, None)
        try:
            env.close()
        except Exception:
            pass
    return record


def _error_record(job: Job, error: str) -> EpisodeRecord:
    ctx = _W["ctx"]
    c = job.cell
    return EpisodeRecord(
        run_id=ctx.run_id, job_id=job.job_id, suite=c.suite, suite_version=ctx.suite_version, task=c.task,
        robot=c.robot, env=c.env, split=c.split, condition=job.condition.name, axis=job.condition.axis,
        level=job.condition.level, params={}, episode=job.episode, seed=job.seed, init_state_hash=None,
        success_once=False, success_at_end=False, return_=0.0, length=0, steps_to_success=None, error=error,
        policy=ctx.policy_id, checkpoint_sha256=ctx.checkpoint_sha256, backend=None, wall_s=0.0,
        finished_at=round(time.time(), 3), worker_pid=os.getpid(), versions=ctx.versions,
    )


# -- parent side -----------------------------------------------------------------------------
def execute(
    jobs: list[Job],
    *,
    suite_name: str,
    policy_name: str,
    cfg,
    ctx: RunContext,
    workers: int,
    on_record: Callable[[EpisodeRecord], None],
) -> None:
    """Run `jobs`, calling `on_record` in the parent for each finished episode (in finish order)."""
    if not jobs:
        return
    if workers <= 1:
        _init_worker(suite_name, policy_name, cfg, ctx)
        try:
            for job in jobs:
                on_record(_run_job(job))
        finally:
            _close_cache()
        return
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                               initializer=_init_worker, initargs=(suite_name, policy_name, cfg, ctx))
    try:
        pending = set()
        queue: Iterable[Job] = iter(jobs)
        # keep a bounded window in flight so an interrupt loses little and order stays cell-major
        window = workers * 4
        for job in queue:
            pending.add(pool.submit(_run_job, job))
            if len(pending) >= window:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    on_record(fut.result())
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                on_record(fut.result())
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _close_cache() -> None:
    for env, _ in _W.get("cache", {}).values():
        try:
            env.close()
        except Exception:
            pass
    _W.get("cache", {}).clear()
