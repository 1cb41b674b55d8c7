"""Which job a free worker runs next: cell-major, warm cells first, lost jobs retried a bounded number of times.

Both executors (local processes, Ray actors) hand out jobs through one `JobQueue`, so they
schedule alike: jobs keep the suite's cell-major order; a worker that asks for work gets
the next job of a cell whose env it has already built (its "warm" cells) if one is left,
else the first job of a cell no worker has started (so workers split the cells instead of
each building every cell's env), else the first job in cell-major order. A job whose worker
was lost (a killed process, a dead node) is handed out before any other, with the reason
kept, at most `max_retries` times; after that it is given up and the caller records it as an
error episode, so a job that kills every worker it touches cannot stall a run. Nothing here
runs an episode.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from collections.abc import Collection

from bench.protocols.suite import Job

MAX_RETRIES = 2  # a job is tried at most 1 + MAX_RETRIES times when its workers keep getting lost
DEPTH = 2  # jobs a remote worker may hold: one running, one waiting, so it never idles between episodes


def depth(queued: int, workers: int) -> int:
    """How many jobs a worker may hold now: DEPTH while every worker can get a waiting job, else 1.

    Near the end of a run a job waiting behind another on a busy worker would leave an idle
    worker with nothing to do; one job each then finishes sooner.
    """
    return DEPTH if queued >= workers else 1


class JobQueue:
    """Jobs still to hand out, grouped by cell in cell-major order."""

    def __init__(self, jobs: list[Job], max_retries: int = MAX_RETRIES):
        self.max_retries = max_retries
        self.cells: OrderedDict[str, deque[Job]] = OrderedDict()
        for job in jobs:
            self.cells.setdefault(job.cell.key, deque()).append(job)
        self.started: set[str] = set()  # cells some worker has taken a job of (and so built, or is building)
        self.retries: dict[str, list[str]] = {}  # job id -> why each earlier attempt was lost
        self.lost_jobs: deque[Job] = deque()  # jobs whose worker was lost: handed out first

    def __len__(self) -> int:
        return len(self.lost_jobs) + sum(len(q) for q in self.cells.values())

    def __bool__(self) -> bool:
        return bool(self.lost_jobs) or any(self.cells.values())

    def take(self, warm: Collection[str] = ()) -> Job | None:
        """The next job for a worker whose built cells are `warm` (None when nothing is left)."""
        if self.lost_jobs:
            return self.lost_jobs.popleft()
        for key, queue in self.cells.items():
            if key in warm and queue:
                return self._pop(key)
        for key, queue in self.cells.items():
            if queue and key not in self.started:
                return self._pop(key)
        for key, queue in self.cells.items():
            if queue:
                return self._pop(key)
        return None

    def take_group(self, warm: Collection[str] = (), size: int = 1) -> list[Job]:
        """Up to `size` jobs of one cell and condition for a vectorised worker (`vector=N`): `take`'s next job and
        those after it in its queue (lost jobs first, as `take` gives them); empty when nothing is left."""
        first = self.take(warm)
        if first is None:
            return []
        group = [first]

        def same(job: Job) -> bool:
            return job.cell.key == first.cell.key and job.condition.name == first.condition.name

        while len(group) < size and self.lost_jobs and same(self.lost_jobs[0]):
            group.append(self.lost_jobs.popleft())
        queue = self.cells.get(first.cell.key)
        while len(group) < size and queue and same(queue[0]):
            group.append(self._pop(first.cell.key))
            queue = self.cells.get(first.cell.key)
        return group

    def _pop(self, key: str) -> Job:
        self.started.add(key)
        queue = self.cells[key]
        job = queue.popleft()
        if not queue:
            del self.cells[key]
        return job

    def lost(self, job: Job, reason: str) -> bool:
        """Queue again a job whose worker was lost (ahead of all others); False when its retries are used up."""
        reasons = self.retries.setdefault(job.job_id, [])
        reasons.append(reason)
        if len(reasons) > self.max_retries:
            return False
        self.lost_jobs.append(job)
        return True

    def attempts(self, job: Job) -> list[str]:
        """Why earlier attempts at `job` were lost (empty for a job that ran first time)."""
        return list(self.retries.get(job.job_id, []))


def given_up_message(reasons: list[str]) -> str:
    """The error recorded for a job whose workers were lost on every attempt."""
    return f"worker lost on each of {len(reasons)} attempts (last: {reasons[-1]})"
