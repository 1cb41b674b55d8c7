"""Execute jobs on an executor (in process or a local process pool), envs built once per worker.

A `Worker` keeps a cache cell -> (env, policy); jobs arrive cell-major, so a worker builds
each cell's simulator once and soft-resets it for every episode. Finished records stream
back to the parent, which appends them to episodes.jsonl as they land. Everything a worker
needs travels in one picklable `WorkerSpec`, so any executor (local pool, Ray) can build
the same workers and produce the same records.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Any, Callable

from bench.protocols import EnvAdapter, Policy, PolicyContext
from bench.records import EpisodeRecord
from bench.rollout import RunContext, run_episode
from bench.suite import Job


@dataclass(frozen=True)
class WorkerSpec:
    """Everything a worker process needs to rebuild the run's suite and policy (picklable)."""

    suite_ref: str           # registry name or package.module:Class
    suite_options: Any       # an instance of the suite's Options
    policy_ref: str          # registry name or package.module:attr
    policy_options: Any      # an instance of the policy plugin's Options
    seed: int                # the run seed
    ctx: RunContext
    calibration: dict[str, Any] | None = None  # a loaded suite calibration, applied to its robot's envs


class Worker:
    """Runs jobs in this process: builds each cell's env and policy once, then one episode per job."""

    def __init__(self, spec: WorkerSpec):
        import warnings

        warnings.filterwarnings("ignore")
        from bench import registry

        self.spec = spec
        self.suite = registry.make_suite(spec.suite_ref, spec.suite_options)
        self.plugin = registry.load_policy(spec.policy_ref)
        self.policy_ctx = PolicyContext(spec.policy_options, self.suite, spec.seed, spec.ctx.horizon)
        self.needs = tuple(self.plugin.obs_keys(spec.policy_options))
        self.cache: dict[str, tuple[EnvAdapter, Policy]] = {}

    def built(self, job: Job) -> tuple[EnvAdapter, Policy]:
        """The (env, policy) of the job's cell, built on first use."""
        key = job.cell.key
        if key not in self.cache:
            env = self.suite.make_env(job.cell, self.spec.ctx.horizon)
            try:
                cal = self.spec.calibration
                if cal is not None and job.cell.robot == cal["robot"]:  # checked against this model by `plan`
                    from bench.perturb import write_fields

                    write_fields(env.mujoco, cal["edits"])
                missing = [k for k in self.needs if k not in env.obs_spec]
                if missing:  # the suite declared them (checked before the run), but its env does not give them
                    raise RuntimeError(f"the policy needs observation keys {missing}; the env gives {sorted(env.obs_spec)}")
                policy = self.plugin.make(job.cell, env, self.policy_ctx)
            except BaseException:
                env.close()
                raise
            self.cache[key] = (env, policy)
        return self.cache[key]

    def run(self, job: Job) -> EpisodeRecord:
        """One episode; a cell whose env or policy cannot be built is recorded as an error."""
        try:
            env, policy = self.built(job)
        except Exception as exc:  # a cell whose env cannot be built: record, go on
            return error_record(job, self.spec.ctx, f"building env/policy failed: {type(exc).__name__}: {exc}")
        record, usable = run_episode(job, env, policy, self.spec.ctx)
        if not usable:  # the env may be in a bad state after an error: rebuild next time
            self.drop(job.cell.key)
        return record

    def drop(self, key: str) -> None:
        env, _ = self.cache.pop(key, (None, None))
        if env is not None:
            try:
                env.close()
            except Exception:
                pass

    def close(self) -> None:
        for key in list(self.cache):
            self.drop(key)


def error_record(job: Job, ctx: RunContext, error: str) -> EpisodeRecord:
    """The record of an episode that could not start (its env or policy failed to build)."""
    c = job.cell
    return EpisodeRecord(
        run_id=ctx.run_id, job_id=job.job_id, suite=c.suite, suite_version=ctx.suite_version, task=c.task,
        robot=c.robot, env=c.env, split=c.split, condition=job.condition.name, axis=job.condition.axis,
        level=job.condition.level, params={}, episode=job.episode, seed=job.seed, init_state_hash=None,
        success_once=False, success_at_end=False, return_=0.0, length=0, steps_to_success=None, error=error,
        policy=ctx.policy_id, checkpoint_sha256=ctx.checkpoint_sha256, backend=None, wall_s=0.0,
        finished_at=round(time.time(), 3), worker_pid=os.getpid(), versions=ctx.versions,
    )


# -- the local executor ----------------------------------------------------------------------
_W: dict[str, Worker] = {}  # the worker of this process (pool workers)


def _init_pool_worker(spec: WorkerSpec) -> None:
    _W.clear()
    _W["w"] = Worker(spec)


def _run_pool_job(job: Job) -> EpisodeRecord:
    return _W["w"].run(job)


class LocalExecutor:
    """In process (`workers <= 1`) or a spawned process pool of `workers` workers."""

    def __init__(self, workers: int):
        self.workers = max(1, int(workers))

    def execute(self, jobs: list[Job], spec: WorkerSpec, on_record: Callable[[EpisodeRecord], None]) -> None:
        """Run `jobs`, calling `on_record` in the parent for each finished episode (in finish order)."""
        if not jobs:
            return
        if self.workers <= 1:
            worker = Worker(spec)
            try:
                for job in jobs:
                    on_record(worker.run(job))
            finally:
                worker.close()
            return
        pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=mp.get_context("spawn"),
                                   initializer=_init_pool_worker, initargs=(spec,))
        try:
            pending: set = set()
            # keep a bounded window in flight so an interrupt loses little and order stays cell-major
            window = self.workers * 4
            for job in jobs:
                pending.add(pool.submit(_run_pool_job, job))
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


def execute(jobs: list[Job], spec: WorkerSpec, workers: int, on_record: Callable[[EpisodeRecord], None]) -> None:
    """Run `jobs` on the local executor with `workers` processes (1 = in process)."""
    LocalExecutor(workers).execute(jobs, spec, on_record)
