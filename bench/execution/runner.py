"""The worker every executor runs jobs with: envs built once per worker and cell, one record per job.

A `Worker` keeps a cache cell -> (env, policy); jobs arrive cell-major (bench.execution.scheduling),
so a worker builds each cell's simulator once and soft-resets it for every episode. With `vector=N` a worker
gets up to N jobs of one cell and condition at once and steps them in lockstep (`Worker.run_vector`,
`bench.execution.vector`), one env and one policy per vector slot, each built once.
Everything a worker needs travels in one picklable `WorkerSpec`, so any executor
(`bench.execution.local.LocalExecutor`, `bench.execution.ray_executor.RayExecutor`) builds the same
workers and produces the same records. An executor is any object with
`execute(jobs, worker_spec, on_record)`.
"""

from __future__ import annotations

import gc
import os
import shutil
import tempfile
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench.execution.processes import alive
from bench.execution.rollout import RunContext, job_record, needs_shadow, run_episode
from bench.execution.scheduling import given_up_message
from bench.execution.vector import run_vector
from bench.protocols import EnvAdapter, Policy, PolicyContext, registry
from bench.protocols.suite import Job
from bench.records import EpisodeRecord
from bench.sims.build_memo import building
from bench.sims.perturb.interface import PerturbedInterface
from bench.sims.perturb.reset import ModelEdit, write_fields


@dataclass(frozen=True)
class WorkerSpec:
    """Everything a worker process needs to rebuild the run's suite and policy (picklable)."""

    suite_ref: str  # registry name or package.module:Class
    suite_options: Any  # an instance of the suite's Options
    policy_ref: str  # registry name or package.module:attr
    policy_options: Any  # an instance of the policy plugin's Options
    seed: int  # the run seed
    ctx: RunContext
    calibration: tuple[str, Sequence[ModelEdit]] | None = None  # a suite calibration's (robot, model edits)
    build_memo: str | None = None  # the run's folder for measurements shared by builds of a cell (`memo_folder`)
    vector: int = 1  # `vector=N`: episodes of one cell and condition a worker steps in lockstep (`Worker.run_vector`)
    calibration_delay: int = 0  # the calibration's transport delay: its robot's commands act this many steps late


class Worker:
    """Runs jobs in this process: builds each cell's env and policy once, then one episode per job.

    `freeze`: this process exists to run episodes (a child, a Ray actor, the `bench run` command), so
    after the first build everything alive is frozen for the collector (`freeze_imports`)."""

    def __init__(self, spec: WorkerSpec, freeze: bool = False):
        warnings.filterwarnings("ignore")

        self.spec = spec
        self.suite = registry.make_suite(spec.suite_ref, spec.suite_options)
        self.plugin = registry.load_policy(spec.policy_ref)
        self.on_status: Callable[[str | None], None] | None = None  # where the policy's waits are reported
        self.policy_ctx = PolicyContext(
            spec.policy_options, self.suite, spec.seed, spec.ctx.horizon, status=self._status
        )
        self.needs = tuple(self.plugin.obs_keys(spec.policy_options))
        self.cache: dict[tuple[str, int], tuple[EnvAdapter, Policy]] = {}  # (cell key, vector slot) -> built
        self.shadows: dict[tuple[str, int], Policy] = {}  # a second policy fed the true instruction (`needs_shadow`)
        self.freeze = freeze

    @property
    def warm(self) -> set[str]:
        """The cells this worker has built (the scheduler prefers their jobs)."""
        return {key for key, _ in self.cache}

    def built(self, job: Job, slot: int = 0) -> tuple[EnvAdapter, Policy]:
        """The (env, policy) of the job's cell in vector slot `slot` (`vector=N`: one per env), built on first use."""
        key = (job.cell.key, slot)
        if key not in self.cache:
            with building(self.spec.build_memo, job.cell.key):  # a cell another worker built: reuse what it measured
                env = self.suite.make_env(job.cell, self.spec.ctx.horizon)
            try:
                if self.spec.calibration is not None:
                    robot, edits = self.spec.calibration
                    if job.cell.robot == robot:  # checked against this model by `plan`
                        assert env.mujoco is not None, f"the calibration of {robot} edits a MuJoCo model"
                        write_fields(env.mujoco, edits)
                        if self.spec.calibration_delay:  # the delay the servos' calibration found: no draws
                            env = PerturbedInterface(env, np.random.default_rng(0), latency=self.spec.calibration_delay)
                missing = [k for k in self.needs if k not in env.obs_spec]
                if missing:  # the suite declared them (checked before the run), but its env does not give them
                    raise RuntimeError(
                        f"the policy needs observation keys {missing}; the env gives {sorted(env.obs_spec)}"
                    )
                policy = self.plugin.make(job.cell, env, self.policy_ctx)
            except BaseException:
                env.close()
                raise
            self.cache[key] = (env, policy)
            if self.freeze:  # after the first build the heavy imports are done: see `freeze_imports`
                freeze_imports()
                self.freeze = False
        return self.cache[key]

    def _prepare(self, job: Job, slot: int) -> tuple[EnvAdapter, Policy, Policy | None] | EpisodeRecord:
        """The job's env, policy and shadow in `slot`, or the error record of a cell that cannot be built."""
        try:
            env, policy = self.built(job, slot)
        except Exception as exc:  # a cell whose env cannot be built: record, go on
            return error_record(job, self.spec.ctx, f"building env/policy failed: {type(exc).__name__}: {exc}")
        try:
            shadow = self.shadow(job, env, slot) if needs_shadow(job) else None
        except Exception as exc:  # its shadow cannot be built: record, go on
            return error_record(job, self.spec.ctx, f"building the shadow policy failed: {type(exc).__name__}: {exc}")
        return env, policy, shadow

    def run(self, job: Job) -> EpisodeRecord:
        """One episode; a cell whose env or policy cannot be built is recorded as an error."""
        built = self._prepare(job, 0)
        if isinstance(built, EpisodeRecord):
            return built
        record, usable = run_episode(job, *built[:2], self.spec.ctx, shadow=built[2])
        if not usable:  # the env may be in a bad state after an error: rebuild next time
            self.drop(job.cell.key, 0)
        return record

    def run_vector(self, jobs: Sequence[Job]) -> list[EpisodeRecord]:
        """The episodes of `jobs` (one cell and condition) in lockstep, one env each (`bench.execution.vector`);
        their records in job order. One job is `run`."""
        if len(jobs) == 1:
            return [self.run(jobs[0])]
        records: dict[int, EpisodeRecord] = {}
        ready: list[tuple[int, Job, tuple[EnvAdapter, Policy, Policy | None]]] = []
        for slot, job in enumerate(jobs):
            built = self._prepare(job, slot)
            if isinstance(built, EpisodeRecord):
                records[slot] = built
            else:
                ready.append((slot, job, built))
        results = run_vector(
            [job for _, job, _ in ready],
            [b[0] for _, _, b in ready],
            [b[1] for _, _, b in ready],
            self.spec.ctx,
            [b[2] for _, _, b in ready],
        )
        for (slot, job, _), (record, usable) in zip(ready, results):
            records[slot] = record
            if not usable:  # the env may be in a bad state after an error: rebuild next time
                self.drop(job.cell.key, slot)
        return [records[slot] for slot in range(len(jobs))]

    def shadow(self, job: Job, env: EnvAdapter, slot: int = 0) -> Policy:
        """The cell's shadow policy in `slot`: a second instance from the same plugin, built on first use."""
        key = (job.cell.key, slot)
        if key not in self.shadows:
            self.shadows[key] = self.plugin.make(job.cell, env, self.policy_ctx)
        return self.shadows[key]

    def _status(self, text: str | None) -> None:
        if self.on_status is not None:
            self.on_status(text)

    def drop(self, key: str, slot: int = 0) -> None:
        env, _ = self.cache.pop((key, slot), (None, None))
        self.shadows.pop((key, slot), None)
        if env is not None:
            try:
                env.close()
            except Exception:
                pass

    def close(self) -> None:
        for key, slot in list(self.cache):
            self.drop(key, slot)


MEMO_PREFIX = "bench-build-memo-"  # + the pid of the process whose run made it


@contextmanager
def memo_folder() -> Iterator[str]:
    """A folder for one run's build memo (`WorkerSpec.build_memo`, `bench.sims.build_memo`) under the system's
    temporary folder, removed when the run ends.

    A run killed before it could remove its folder (kill -9) leaves it behind: each new one first removes
    the folders of processes that are gone."""
    for old in Path(tempfile.gettempdir()).glob(f"{MEMO_PREFIX}*"):
        pid = old.name[len(MEMO_PREFIX) :].split("-", 1)[0]
        if pid.isdigit() and not alive(int(pid)):
            shutil.rmtree(old, ignore_errors=True)
    with tempfile.TemporaryDirectory(prefix=f"{MEMO_PREFIX}{os.getpid()}-") as folder:
        yield folder


def freeze_imports() -> None:
    """Move every object alive now out of the cyclic collector's sight (`gc.freeze`), once per process.

    Called after a worker process's first build, when the suite's and policy's lazy imports are done:
    torch and robosuite alone leave ~240k long-lived objects that every full collection would walk again,
    0.1-0.14 s each, and robosuite runs one per env close (`MjSim.free`) besides Python's own every few
    thousand allocations; the interpreter's exit walks them once more (~0.4 s). Frozen objects are still
    freed by reference counting; only cyclic garbage alive at this moment (the first env's, at most) stays
    until the process exits. Not done in a process that merely calls `bench.api.run` (a notebook's).
    """
    gc.freeze()


def error_record(job: Job, ctx: RunContext, error: str) -> EpisodeRecord:
    """The record of an episode that could not start (its env or policy failed to build)."""
    return job_record(
        job,
        ctx,
        level=job.condition.level,
        params={},
        init_state_hash=None,
        success_once=False,
        success_at_end=False,
        return_=0.0,
        length=0,
        steps_to_success=None,
        error=error,
        backend=None,
        wall_s=0.0,
    )


def with_retries(record: EpisodeRecord, reasons: list[str]) -> EpisodeRecord:
    """`record`, noting in `extras["retries"]` why earlier attempts at its job were lost (if any were)."""
    if reasons:
        record.extras = {**record.extras, "retries": list(reasons)}
    return record


def given_up_record(job: Job, ctx: RunContext, reasons: list[str]) -> EpisodeRecord:
    """The error record of a job whose worker was lost on every allowed attempt."""
    return with_retries(error_record(job, ctx, given_up_message(reasons)), reasons)
