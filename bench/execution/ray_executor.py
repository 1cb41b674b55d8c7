"""`executor=ray`: the same jobs, the same records, on the actors of a Ray cluster (docs/ray.md).

Each actor is a long-lived process holding one `bench.execution.runner.Worker`, so it builds a cell's
env once and reuses it for every episode of that cell it gets, as a local worker does. The
driver hands out jobs through the same `JobQueue` as the local executor (cell-major, warm
cells first, up to two jobs queued per actor) and writes every record itself, as it arrives:
episodes.jsonl, resume, timeouts (SIGALRM in the actor's main thread), per-episode errors
and summary.json are exactly those of a local run.

Faults: an actor whose process or node dies (or becomes unreachable) is killed for good
and replaced; the jobs it had not answered go back to the queue, each at most
`MAX_RETRIES` times, and the record that finally lands lists why earlier attempts were lost
in `extras["retries"]`. A job that loses its worker every time is recorded as an error.
Only the driver writes, and only the first answer per job, so nothing is written twice.
If the driver dies, Ray ends its actors; rerunning the command resumes like a local run.

Before any episode, every actor reports its Python and package versions; a difference
from the driver, or a suite or policy the actor cannot import, stops the run with one line.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from bench.core.errors import BenchError, ConfigError, ExecutorError
from bench.core.io import write_bytes_atomic
from bench.execution import processes, ray_env
from bench.execution.rollout import trajectory_path
from bench.execution.runner import Worker, WorkerSpec, given_up_record, with_retries
from bench.execution.scheduling import MAX_RETRIES, JobQueue, depth
from bench.protocols import registry
from bench.protocols.suite import Job
from bench.records import EpisodeRecord

if TYPE_CHECKING:
    from ray import ObjectRef
    from ray.actor import ActorHandle

STALL_S = 300.0  # no actor alive and none placed for this long: give up (records so far are kept)
WAIT_NOTE_S = 20.0  # tell the user when actors are still waiting to be placed after this long
PREFLIGHT_S = 600.0  # a node's first worker may install a runtime env (ray_env=pip) before it answers


class NodeInfo(ray_env.NodeReport):
    """A node's answer to `probe_node` (and an actor's to `RayWorker.start`): its versions, the process and node,
    and why it cannot load the run (None when it can)."""

    pid: int
    node: str
    error: str | None


if TYPE_CHECKING:  # what an actor answers: `RayWorker.start`'s node info, or `RayWorker.run`'s records and trajectories
    Ref = ObjectRef[NodeInfo] | ObjectRef[list[tuple[EpisodeRecord, bytes | None]]]


def probe_node(suite_ref: str, policy_ref: str) -> NodeInfo:
    """Run on every node before anything is written: its versions, and whether it can load the suite and policy."""
    import ray  # the ray extra: loaded only for executor=ray

    node = f"{ray.util.get_node_ip_address()} ({ray.get_runtime_context().get_node_id()[:8]})"
    here = ray_env.report()
    out: NodeInfo = {**here, "pid": os.getpid(), "node": node, "error": None}
    try:
        registry.suite_class(suite_ref)
        registry.load_policy(policy_ref)
    except BenchError as exc:
        out["error"] = str(exc)
    except Exception as exc:
        out["error"] = f"{type(exc).__name__}: {exc}"
    return out


def check_worker(driver: ray_env.NodeReport, info: NodeInfo) -> str:
    """Where a worker runs; raises ExecutorError when it differs from the driver or cannot load the run."""
    where = f"pid {info['pid']} on node {info['node']}"
    problem = ray_env.version_mismatch(driver, info, where)
    if problem:
        raise ExecutorError(f"executor=ray: {problem}")
    if info["error"]:
        raise ExecutorError(f"executor=ray: a worker ({where}) cannot load the run: {info['error']}")
    return where


class RayWorker:
    """The actor: one Worker for the actor's lifetime (env reused across its episodes)."""

    def __init__(self, spec: WorkerSpec):
        self.spec = spec
        self.worker: Worker | None = None
        self.traj_dir: str | None = None
        if spec.ctx.trajectory_dir:  # record=: trajectories go to a node-local folder and travel back with records
            self.traj_dir = tempfile.mkdtemp(prefix="bench-traj-")
            self.spec = dataclasses.replace(spec, ctx=dataclasses.replace(spec.ctx, trajectory_dir=self.traj_dir))

    def start(self) -> NodeInfo:
        """Versions of this process, where it runs, and why the Worker could not be built (None if it was)."""
        out = probe_node(self.spec.suite_ref, self.spec.policy_ref)
        if out["error"] is None:
            try:
                self.worker = Worker(self.spec, freeze=True)
            except BenchError as exc:
                out["error"] = str(exc)
            except Exception as exc:
                out["error"] = f"{type(exc).__name__}: {exc}"
        return out

    def run(self, jobs: list[Job]) -> list[tuple[EpisodeRecord, bytes | None]]:
        """The records of `jobs` (one, or `vector=N` of one cell and condition, run in lockstep), each with its
        trajectory file's bytes when the run records them (record=)."""
        assert self.worker is not None, "start() first"
        return [(record, self._trajectory(record)) for record in self.worker.run_vector(jobs)]

    def _trajectory(self, record: EpisodeRecord) -> bytes | None:
        if self.traj_dir is None:
            return None
        path = trajectory_path(self.traj_dir, record.job_id)
        if not path.exists():  # an episode that failed has no trajectory
            return None
        data = path.read_bytes()
        path.unlink()
        return data


@dataclass
class _Actor:
    handle: ActorHandle[RayWorker]
    start_ref: ObjectRef[NodeInfo]
    ready: bool = False
    where: str = "not placed yet"
    inflight: deque[tuple[Ref, list[Job]]] = field(default_factory=deque)  # (ref, job group) in submission order
    warm: set[str] = field(default_factory=set)  # the cells it has built


class RayExecutor:
    """Runs jobs on `actors` Ray actors (0 = as many as the cluster's CPUs/GPUs allow).

    Args:
        address: auto, local (a private cluster on this machine) or HOST:PORT.
        actors: actor count; 0 = cluster CPUs // cpus (and GPUs // gpus when gpus > 0).
        cpus, gpus: resources each actor reserves.
        env: runtime env mode, see `bench.execution.ray_env` (code, pip, installed).
        runtime_env: extra runtime-env fields merged into the mode's (e.g. env_vars, container).
        note: called with one-line progress notes (actors lost, waiting for placement).
    """

    capabilities: frozenset[str] = frozenset({"cluster", "notes"})  # bench.protocols.executor

    def __init__(
        self,
        address: str = "auto",
        actors: int = 0,
        cpus: float = 1.0,
        gpus: float = 0.0,
        env: str = "code",
        runtime_env: Mapping[str, object] | None = None,
        note: Callable[[str], None] | None = None,
    ):
        ray_env.check_address(address)
        if env not in ray_env.RAY_ENVS:
            raise ConfigError(f"ray_env={env!r}: valid: {', '.join(ray_env.RAY_ENVS)}")
        self.address, self.actors, self.cpus, self.gpus, self.env = address, int(actors), cpus, gpus, env
        self.extra_env = runtime_env
        self.note = note or (lambda text: None)
        self.owns_ray = False
        self.connected = False
        self.before: set[int] = set()  # processes below this one before `connect`
        self.size = 0
        self.cluster: dict[str, object] = {}

    # -- connection ---------------------------------------------------------------------------
    def connect(self, jobs: int | None, suite_ref: str, policy_ref: str) -> int:
        """Join the cluster (one line on failure) and return the actor count for `jobs` jobs.

        The runtime env (which code the actors get) is the job's, so it is fixed here, by the
        suite and policy the run loads.
        """
        if not self.connected:
            env = ray_env.runtime_env(self.env, suite_ref, policy_ref, self.extra_env)
            self.before = set(processes.descendants())  # a private cluster's daemons are the ones that appear
            self.owns_ray = ray_env.connect(self.address, env)
            self.connected = True
            try:
                self._preflight(suite_ref, policy_ref)
            except BaseException:
                self.close()
                raise
        ray = ray_env.import_ray()
        res = ray.cluster_resources()
        cpus, gpus = float(res.get("CPU", 0)), float(res.get("GPU", 0))
        self.cluster = {
            "address": self.address,
            "nodes": len([n for n in ray.nodes() if n.get("Alive")]),
            "cpus": cpus,
            "gpus": gpus,
        }
        n = self.actors
        if n == 0:
            n = int(cpus // self.cpus) if self.cpus > 0 else int(cpus)
            if self.gpus > 0:
                n = min(n, int(gpus // self.gpus))
            if n < 1:
                raise ExecutorError(
                    f"the Ray cluster at {self.address} has {cpus:g} CPUs and {gpus:g} GPUs; one "
                    f"actor needs actor_cpus={self.cpus:g} actor_gpus={self.gpus:g}"
                )
        self.size = max(1, min(n, jobs)) if jobs else n
        return self.size

    def _preflight(self, suite_ref: str, policy_ref: str) -> None:
        """Every node that can host an actor: same Python and packages as here, suite and policy importable."""
        ray = ray_env.import_ray()
        from ray.util.scheduling_strategies import (
            NodeAffinitySchedulingStrategy,  # the ray extra: loaded only for executor=ray
        )

        nodes = [n for n in ray.nodes() if n.get("Alive") and n.get("Resources", {}).get("CPU", 0) > 0]
        probe = ray.remote(num_cpus=0, max_retries=0)(probe_node)
        refs = [
            probe.options(scheduling_strategy=NodeAffinitySchedulingStrategy(n["NodeID"], soft=False)).remote(
                suite_ref, policy_ref
            )
            for n in nodes
        ]
        driver = ray_env.report()
        try:
            infos = ray.get(refs, timeout=PREFLIGHT_S)
        except ray.exceptions.GetTimeoutError:
            raise ExecutorError(
                f"executor=ray: the cluster's nodes did not answer within {PREFLIGHT_S:g} s "
                "(is a runtime env still installing? see docs/ray.md)"
            ) from None
        except ray.exceptions.RayError as exc:  # e.g. RuntimeEnvSetupError: ray_env=pip could not install
            first = next((ln.strip() for ln in str(exc).splitlines() if ln.strip()), type(exc).__name__)
            raise ExecutorError(f"executor=ray: preparing the workers failed (ray_env={self.env}): {first}") from None
        for info in infos:
            check_worker(driver, info)

    def close(self) -> None:
        """Disconnect (and stop the private cluster of ray_address=local); actors end with the job.

        The private cluster's processes (those that appeared below this one since `connect`) are waited
        for, and ended if they linger: a run leaves no Ray daemon behind.
        """
        if self.connected and self.owns_ray:
            started = [p for p in processes.descendants() if p not in self.before]
            ray_env.import_ray().shutdown()
            processes.reap(started)
        self.connected = self.owns_ray = False

    # -- running ------------------------------------------------------------------------------
    def execute(self, jobs: list[Job], spec: WorkerSpec, on_record: Callable[[EpisodeRecord], None]) -> None:
        """Run `jobs` on the cluster's actors, calling `on_record` in this process for each finished episode."""
        if not jobs:
            return
        opened = not self.connected  # who connects, closes: api.run connects first to check the cluster
        try:
            self.connect(len(jobs), spec.suite_ref, spec.policy_ref)
            _Run(self, jobs, spec, on_record).loop()
        finally:
            if opened:
                self.close()


class _Run:
    """One execute(): the actors, their in-flight jobs, the queue."""

    def __init__(self, ex: RayExecutor, jobs: list[Job], spec: WorkerSpec, on_record: Callable[[EpisodeRecord], None]):
        self.ray = ray_env.import_ray()
        self.ex, self.spec, self.on_record = ex, spec, on_record
        self.queue = JobQueue(jobs)
        self.driver = ray_env.report()
        self.cls = self.ray.remote(RayWorker).options(
            num_cpus=ex.cpus, num_gpus=ex.gpus, max_restarts=0, max_task_retries=0, scheduling_strategy="SPREAD"
        )
        self.actors: list[_Actor] = []
        self.replacements = ex.size * (MAX_RETRIES + 1)
        self.last_alive = time.time()
        self.noted_wait = False
        for _ in range(ex.size):
            self._spawn()

    def _spawn(self) -> None:
        handle = self.cls.remote(self.spec)
        self.actors.append(_Actor(handle, handle.start.remote()))

    def loop(self) -> None:
        ray = self.ray
        try:
            while self.queue or any(a.inflight for a in self.actors):
                self._feed()
                refs: dict[Ref, tuple[_Actor, list[Job] | None]] = {
                    a.start_ref: (a, None) for a in self.actors if not a.ready
                }
                refs.update({ref: (a, group) for a in self.actors for ref, group in a.inflight})
                if not refs:
                    raise ExecutorError(
                        "no Ray actor left to run the remaining jobs (records so far are kept; "
                        "rerun the same command to resume)"
                    )
                done, rest = ray.wait(list(refs), num_returns=1, timeout=1.0)
                if done and rest:  # everything else that is ready too, without waiting
                    done += ray.wait(rest, num_returns=len(rest), timeout=0)[0]
                for ref in done:
                    actor, job = refs[ref]
                    if actor in self.actors:
                        self._answer(actor, ref, job)
                self._check_stall()
        finally:
            for a in self.actors:
                ray.kill(a.handle, no_restart=True)

    def _answer(self, actor: _Actor, ref: Ref, group: list[Job] | None) -> None:
        ray = self.ray
        try:
            value = ray.get(ref)
        except ray.exceptions.RayTaskError as exc:  # a bug below Worker.run, which records episode errors
            cause = exc.cause if exc.cause is not None else exc
            raise ExecutorError(f"a Ray actor ({actor.where}) failed: {type(cause).__name__}: {cause}") from None
        except ray.exceptions.RuntimeEnvSetupError as exc:
            first = next((ln.strip() for ln in str(exc).splitlines() if ln.strip()), type(exc).__name__)
            raise ExecutorError(f"executor=ray: preparing a worker failed (ray_env={self.ex.env}): {first}") from None
        except ray.exceptions.RayError as exc:  # the actor died, its node died or is unreachable, the result lost
            self._lost(actor, f"Ray actor {actor.where} lost ({type(exc).__name__})")
            return
        if group is None:
            self._started(actor, value)
            return
        actor.inflight.remove((ref, group))
        for job, (record, trajectory) in zip(group, value):
            if trajectory is not None and self.spec.ctx.trajectory_dir:  # written before its record, as locally
                write_bytes_atomic(trajectory_path(self.spec.ctx.trajectory_dir, job.job_id), trajectory)
            self.on_record(with_retries(record, self.queue.attempts(job)))

    def _started(self, actor: _Actor, info: NodeInfo) -> None:
        actor.where = check_worker(self.driver, info)  # a node that joined after the preflight is checked here
        actor.ready = True
        self.last_alive = time.time()

    def _lost(self, actor: _Actor, reason: str) -> None:
        """Kill the actor for good, put its unanswered jobs back (or give them up), start a replacement."""
        self.actors.remove(actor)
        self.ray.kill(actor.handle, no_restart=True)
        lost = [job for _, group in actor.inflight for job in group]
        given_up = [job for job in lost if not self.queue.lost(job, reason)]
        requeued = len(lost) - len(given_up)
        self.ex.note(f"{reason}: {requeued} episode(s) requeued" + (f", {len(given_up)} given up" if given_up else ""))
        for job in given_up:
            self.on_record(given_up_record(job, self.spec.ctx, self.queue.attempts(job)))
        if self.queue and self.replacements > 0:
            self.replacements -= 1
            self._spawn()

    def _feed(self) -> None:
        ready = sum(a.ready for a in self.actors)
        for actor in self.actors:
            while actor.ready and len(actor.inflight) < depth(-(-len(self.queue) // self.spec.vector), ready):
                group = self.queue.take_group(actor.warm, self.spec.vector)
                if not group:
                    return
                actor.inflight.append((actor.handle.run.remote(group), group))
                actor.warm.add(group[0].cell.key)

    def _check_stall(self) -> None:
        now = time.time()
        if any(a.ready for a in self.actors):
            self.last_alive = now
            return
        waiting = now - self.last_alive
        if waiting > WAIT_NOTE_S and not self.noted_wait:
            self.noted_wait = True
            self.ex.note(
                f"waiting for the cluster to place {len(self.actors)} actor(s) (actor_cpus={self.ex.cpus:g}, "
                f"actor_gpus={self.ex.gpus:g} each)"
            )
        if waiting > STALL_S:
            raise ExecutorError(
                f"no Ray actor could be placed for {STALL_S:g} s (each needs "
                f"actor_cpus={self.ex.cpus:g} actor_gpus={self.ex.gpus:g}); records so far are kept: "
                "rerun to resume"
            )
