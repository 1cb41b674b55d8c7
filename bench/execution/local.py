"""The local executor: episodes in this process and in spawned child processes, each running a `Worker`.

The parent runs episodes from the first second while its children start; a dispatcher thread feeds
each child jobs as soon as it is ready (`bench.execution.scheduling`) and streams their records back
to the parent, which appends them to episodes.jsonl as they land. A child that dies has its
unanswered jobs retried elsewhere (bounded). Children may start before the jobs are known
(`LocalExecutor.prestart`), importing what the suite and policy `preload` meanwhile.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Hashable, Sequence
from multiprocessing import resource_tracker
from multiprocessing.connection import Connection, wait

from bench.core.errors import BenchError, ExecutorError
from bench.execution.runner import Worker, WorkerSpec, given_up_record, with_retries
from bench.execution.scheduling import MAX_RETRIES, JobQueue, depth
from bench.protocols import registry
from bench.protocols.suite import Job, policy_ref
from bench.records import EpisodeRecord

_CTX = mp.get_context("spawn")  # a fresh interpreter per child: no inherited threads or locks


def _child_main(conn: Connection, spec: WorkerSpec | None, preload: tuple[str, str | None] | None = None) -> None:
    """A child process: build a Worker, report ready, then run the jobs the parent sends until None.

    Started ahead of the plan (`spec` None), it first imports what the suite's envs and the policy need
    (`preload`: the suite and policy refs, whose `preload` methods do it), then waits for the spec.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle; it stops the children
    if spec is None:
        if preload is not None:
            _preload(*preload)
        try:
            spec = conn.recv()
        except (EOFError, OSError):  # the parent is gone (its plan failed): nothing to do
            return
    try:
        worker = Worker(spec, freeze=True)
    except BaseException as exc:
        conn.send(("init_error", str(exc) if isinstance(exc, BenchError) else f"{type(exc).__name__}: {exc}"))
        return
    lock = threading.Lock()  # the policy may report a wait from a timer thread while a record is sent

    def send(message: tuple) -> None:
        with lock:
            conn.send(message)

    worker.on_status = lambda text: send(("status", text))
    send(("ready", os.getpid()))
    try:
        while True:
            jobs = conn.recv()  # one job, or `vector=N` of one cell and condition
            if jobs is None:
                break
            send(("records", worker.run_vector(jobs)))
    except (EOFError, OSError):  # the parent is gone: nothing to report to
        pass
    finally:
        worker.close()


def _preload(suite_ref: str, policy: str | None) -> None:
    """Import what the suite's envs and the policy (`policy=`, None: the suite's default) need, ignoring
    errors: the plan and the builds report them with their own messages."""
    try:
        suite_cls = registry.suite_class(suite_ref)
        suite_cls.preload()
        registry.load_policy(policy_ref(suite_cls, policy)).preload()
    except Exception:
        pass


class _Child:
    """A child process, the jobs sent to it and not yet answered, and the cells it has built.

    Made with `spec` None (`LocalExecutor.prestart`), it imports what `preload` names and waits for
    `give(spec)`."""

    def __init__(self, spec: WorkerSpec | None, preload: tuple[str, str | None] | None = None):
        self.conn, theirs = _CTX.Pipe()
        self.proc = _CTX.Process(target=_child_main, args=(theirs, spec, preload), daemon=True)
        self.proc.start()
        theirs.close()
        self.ready = False
        self.inflight: deque[list[Job]] = deque()  # the job groups sent and not yet answered, in order
        self.warm: set[str] = set()

    def give(self, spec: WorkerSpec) -> None:
        """Send a prestarted child its spec; a child that died meanwhile is found by its EOF."""
        try:
            self.conn.send(spec)
        except OSError:
            pass

    def exit_reason(self) -> str:
        self.proc.join(5)
        code = self.proc.exitcode
        how = f"was killed by signal {-code}" if code is not None and code < 0 else f"exited with code {code}"
        return f"worker process {self.proc.pid} {how}"


class _Children:
    """Child processes fed by a dispatcher thread: each gets jobs as soon as it is ready (`scheduling.depth`).

    A child that dies has its unanswered jobs put back in the queue (bounded retries) and is
    replaced while jobs remain. Records go to `emit` as they arrive.
    """

    def __init__(
        self,
        n: int,
        spec: WorkerSpec,
        queue: JobQueue,
        cond: threading.Condition,
        emit: Callable[[EpisodeRecord], None],
        status: Callable[[str | None, Hashable], None] | None = None,
        started: Sequence[_Child] = (),
    ):
        self.spec, self.queue, self.cond, self.emit = spec, queue, cond, emit
        self.status = status
        self.children = list(started[:n])  # prestarted children first (the dispatcher sends their spec), then new
        self.unspecified = list(self.children)
        self.children += [_Child(spec) for _ in range(n - len(self.children))]
        self.respawns = n * (MAX_RETRIES + 1)
        self.retired: list[_Child] = []  # told to stop (or killed); joined by close()
        self.wake_r, self.wake_w = mp.Pipe(duplex=False)  # close() wakes the dispatcher out of its wait
        self.error: BaseException | None = None
        self.stopping = False
        self.thread = threading.Thread(target=self._serve, name="bench-dispatch", daemon=True)
        self.thread.start()

    def busy(self) -> bool:
        """Some child still has jobs in flight (call with `cond` held)."""
        return any(c.inflight for c in self.children)

    def _serve(self) -> None:
        try:
            # a prestarted child's spec is sent here, not by the caller: a send may block until the child reads it
            for waiting in self.unspecified:
                waiting.give(self.spec)
            while not self.stopping:
                ready = wait([self.wake_r, *(c.conn for c in self.children)], timeout=1.0)
                for conn in ready:
                    child = next((c for c in self.children if c.conn is conn), None)
                    if child is not None:
                        self._receive(child)
                self._feed()
        except BaseException as exc:  # surfaced in the main thread
            with self.cond:
                self.error = exc
                self.cond.notify_all()

    def _receive(self, child: _Child) -> None:
        try:
            kind, payload = child.conn.recv()
        except (EOFError, OSError):
            self._lost(child, child.exit_reason())
            return
        if kind == "ready":
            child.ready = True
        elif kind == "status":
            if self.status is not None:
                self.status(payload, child.proc.pid)
        elif kind == "init_error":
            raise ExecutorError(f"a worker process could not start: {payload}")
        else:
            with self.cond:
                group = child.inflight.popleft()
                assert [j.job_id for j in group] == [r.job_id for r in payload], (group, payload)
                reasons = [self.queue.attempts(job) for job in group]
                self.cond.notify_all()
            for record, why in zip(payload, reasons):
                self.emit(with_retries(record, why))

    def _lost(self, child: _Child, reason: str) -> None:
        """A child died: its unanswered jobs go back to the queue (or are given up); replace it."""
        child.conn.close()
        with self.cond:
            self.children.remove(child)
            given_up = [job for group in child.inflight for job in group if not self.queue.lost(job, reason)]
            child.inflight.clear()
            if self.queue and self.respawns > 0:
                self.respawns -= 1
                self.children.append(_Child(self.spec))
            self.cond.notify_all()
        for job in given_up:
            self.emit(given_up_record(job, self.spec.ctx, self.queue.attempts(job)))

    def _feed(self) -> None:
        for child in self.children:
            while child.ready:
                with self.cond:
                    queued = -(-len(self.queue) // self.spec.vector)  # groups left to hand out
                    if len(child.inflight) >= depth(queued, len(self.children) + 1):  # + the parent
                        break
                    group = self.queue.take_group(child.warm, self.spec.vector)
                    if not group:
                        break
                    child.inflight.append(group)
                child.warm.add(group[0].cell.key)
                try:
                    child.conn.send(group)
                except OSError:  # it died since its last message: `_receive` reads what it sent, then its EOF
                    child.ready = False  # requeues its in-flight jobs (this one included) via `_lost`
        with self.cond:
            idle = [] if self.queue else [c for c in self.children if not c.inflight]
            for child in idle:  # nothing left for it: let it close its envs while the others finish
                self.children.remove(child)
        for child in idle:
            self._retire(child)

    def _retire(self, child: _Child) -> None:
        if child.ready:
            try:
                child.conn.send(None)
            except OSError:
                pass
        else:  # still starting: it would only build a Worker to be told to stop
            child.proc.kill()
        self.retired.append(child)

    def stop(self) -> None:
        """Stop the thread and tell the children to stop (those still running an episode are killed); returns
        while they close their envs, so the caller can close its own meanwhile (`join` waits for them)."""
        self.stopping = True
        self.wake_w.send(None)
        self.thread.join(5)
        self.wake_r.close()
        self.wake_w.close()
        for child in list(self.children):
            if child.inflight:
                child.proc.kill()
            self._retire(child)

    def join(self) -> None:
        """Wait (10 s at most, then kill) for the children `stop` told to stop."""
        deadline = time.time() + 10
        for child in self.retired:
            child.proc.join(max(0.0, deadline - time.time()))
            if child.proc.is_alive():
                child.proc.kill()
                child.proc.join(5)
            child.conn.close()


class LocalExecutor:
    """Episodes in this process and, for `workers > 1`, in `workers - 1` spawned child processes.

    The parent runs episodes from the first second while the children start (spawn, imports
    and env builds take seconds each), so start-up overlaps with work; children get jobs as
    soon as they are ready. Jobs go cell-major, a worker preferring a cell whose env it has
    built, then a cell nobody has started (`JobQueue.take`). A child that dies (killed,
    segfault) has its episodes retried elsewhere, at most `MAX_RETRIES` times each, the reasons
    kept in the record's `extras["retries"]`.

    `prestart` starts the children before the jobs are known (`bench.api.plan_with_workers`: while the
    plan finishes). `own_process`: this process exists for the run (the `bench run` command), so its
    own worker freezes the collector after its first build, as the children do (`freeze_imports`).
    """

    capabilities: frozenset[str] = frozenset({"status"})  # no cluster to reach, no notes of its own

    def __init__(self, workers: int, own_process: bool = False):
        self.workers = max(1, int(workers))
        self.own_process = own_process  # this process exists for the run (`bench run`): its worker freezes too
        self.status: Callable[[str | None, Hashable], None] | None = None  # (what a worker waits for, which worker)
        self.started: list[_Child] = []

    def prestart(self, suite_ref: str, policy: str | None, jobs: int) -> None:
        """Start the child processes for `jobs` jobs now, before `execute`: while the caller finishes its plan
        (a checkpoint's preflight imports torch, ~1 s), each imports bench and what the suite's and policy's
        `preload` name (robosuite, torch), then waits for `execute`'s spec. `policy` None: the suite's
        default. Children `execute` does not need, or that `close` finds unused, are killed."""
        more = min(self.workers, jobs) - 1 - len(self.started)
        self.started += [_Child(None, (suite_ref, policy)) for _ in range(more)]

    def close(self) -> None:
        """Stop prestarted children `execute` never took (a plan that failed); nothing else outlives `execute`."""
        self._drop_started(0)

    def _drop_started(self, keep: int) -> list[_Child]:
        """The first `keep` prestarted children; the others are killed (they hold nothing but imports)."""
        kept, extra = self.started[:keep], self.started[keep:]
        self.started = []
        for child in extra:
            child.proc.kill()
        for child in extra:
            child.proc.join(5)
            child.conn.close()
        if extra and not kept:
            stop_resource_tracker()
        return kept

    def execute(self, jobs: list[Job], spec: WorkerSpec, on_record: Callable[[EpisodeRecord], None]) -> None:
        """Run `jobs`, calling `on_record` for each finished episode (in finish order, one call at a time)."""
        n = max(0, min(self.workers, len(jobs)) - 1)  # children: never more processes than jobs
        started = self._drop_started(n)
        if not jobs:
            return
        queue = JobQueue(jobs)
        cond = threading.Condition()
        emit_lock = threading.Lock()

        def emit(record: EpisodeRecord) -> None:
            with emit_lock:
                on_record(record)

        children = _Children(n, spec, queue, cond, emit, self.status, started) if n > 0 else None
        worker = None
        try:
            worker = Worker(spec, freeze=self.own_process)
            if self.status is not None:
                status, me = self.status, os.getpid()
                worker.on_status = lambda text: status(text, me)
            while True:
                with cond:
                    group: list[Job] = []
                    while not group:
                        if children is not None and children.error is not None:
                            raise children.error
                        group = queue.take_group(worker.warm, spec.vector)
                        if not group:
                            if children is None or not children.busy():
                                break
                            cond.wait(0.5)
                    if not group:
                        break
                    reasons = [queue.attempts(job) for job in group]
                for record, why in zip(worker.run_vector(group), reasons):
                    emit(with_retries(record, why))
            if children is not None and children.error is not None:
                raise children.error
        finally:
            if children is not None:
                children.stop()  # the children close their envs while this process closes its own
            try:
                if worker is not None:
                    worker.close()
            finally:
                if children is not None:
                    children.join()
                    stop_resource_tracker()


def stop_resource_tracker(timeout: float = 10.0) -> None:
    """Stop multiprocessing's resource tracker once the children are gone, so a run leaves no process behind.

    Starting a spawned child starts the tracker, a process of its own that otherwise outlives this one
    by a moment (it exits when the last holder of its pipe does); it is started again with the next
    child. This closes our end and reaps it, waiting at most `timeout` seconds (a child that still holds
    the pipe keeps it alive). Private API of multiprocessing: nothing is done where it is absent.
    """
    tracker = getattr(resource_tracker, "_resource_tracker", None)
    lock = getattr(tracker, "_lock", None)
    if tracker is None or lock is None or not hasattr(tracker, "_fd") or not hasattr(tracker, "_pid"):
        return
    with lock:
        fd, pid = tracker._fd, tracker._pid
        if fd is None or pid is None:
            return
        tracker._fd = tracker._pid = None
        try:
            os.close(fd)
        except OSError:
            pass
    deadline = time.monotonic() + timeout
    while True:
        try:
            if os.waitpid(pid, os.WNOHANG)[0]:
                return
        except ChildProcessError:  # already reaped
            return
        if time.monotonic() > deadline:
            return
        time.sleep(0.02)
