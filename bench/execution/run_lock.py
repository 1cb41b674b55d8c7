"""One writer per run directory: the lock `bench run` holds while it writes a run's records.

Two runs on the same `out=`/`run_id=` would each run every job and append both records to one
episodes.jsonl. Before its first byte, a run takes `RUN_DIR/.bench-lock`: an exclusive `flock` on
the file, held for the whole run by the parent process (the local executor's children and Ray's
actors never write the run directory; they send records back to it), and a note inside saying
who holds it: PID, host, the process's start tick (so a reused PID is not mistaken for the holder)
and the start time. The note is removed when the run ends.

A second writer refuses with one line naming the holder (`RunLocked`, exit 2) before it writes or
changes anything. A note left by a run that was killed (its PID gone on this host, or now another
process) is taken over and said so. A note from another host is never taken over: whether that
run still goes on cannot be told from here, so the line says how to release it by hand.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path

from bench.core.errors import BenchError
from bench.execution.processes import PROC, alive

LOCK = ".bench-lock"


class RunLocked(BenchError):
    """Another `bench run` is writing this run directory (exit 2; nothing was written)."""


@dataclass(frozen=True)
class Holder:
    """Who holds (or held) a run directory's lock, as its note says."""

    pid: int
    host: str
    started_at: str
    start_tick: int | None = None  # the process's start time in clock ticks since boot (/proc), when known

    def describe(self) -> str:
        return f"PID {self.pid} on {self.host} since {self.started_at}"

    def gone(self) -> bool:
        """This host's process `pid` no longer runs it: exited, or the PID now belongs to another process."""
        if self.host != socket.gethostname():
            return False  # another host's process cannot be looked at from here
        if not alive(self.pid):
            return True
        tick = start_tick(self.pid)
        return self.start_tick is not None and tick is not None and tick != self.start_tick


def start_tick(pid: int) -> int | None:
    """When process `pid` started, in clock ticks since boot (/proc/PID/stat field 22); None without /proc."""
    try:
        stat = (PROC / str(pid) / "stat").read_text()
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[-1].split()  # after "pid (comm)": field 3 (state) onwards
    return int(fields[19]) if len(fields) > 19 and fields[19].isdigit() else None


def read_holder(run_dir: Path) -> Holder | None:
    """The note in `run_dir`'s lock, or None when there is none (or it is empty or unreadable)."""
    try:
        doc = json.loads((run_dir / LOCK).read_text(encoding="utf-8"))
        return Holder(int(doc["pid"]), str(doc["host"]), str(doc["started_at"]), doc.get("start_tick"))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _holder_soon(run_dir: Path, wait_s: float = 2.0) -> Holder | None:
    """The holder's note, waiting a moment for it: a writer that has just taken the lock writes it next."""
    deadline = time.monotonic() + wait_s
    while (holder := read_holder(run_dir)) is None and time.monotonic() < deadline:
        time.sleep(0.02)
    return holder


def _refusal(run_dir: Path, holder: Holder | None, why: str = "") -> RunLocked:
    who = holder.describe() if holder is not None else "another process"
    return RunLocked(
        f"out={str(run_dir)!r}: this run directory is being written by {who}{why}; wait for that run to end, "
        "or give another run_id (nothing was written)"
    )


def check_free(run_dir: Path) -> None:
    """Refuse (`RunLocked`) when `run_dir`'s lock names a process that still runs on this host. Reads only: the
    lock itself is taken by `RunLock.acquire`, which decides when two runs start together."""
    holder = read_holder(run_dir)
    if holder is not None and holder.host == socket.gethostname() and not holder.gone():
        raise _refusal(run_dir, holder)


class RunLock:
    """The lock of one run directory, held from `acquire` to `release` (a context manager does both).

    `took_over`: the note of a killed run this lock replaced (None when the directory was free)."""

    def __init__(self, run_dir: Path):
        self.run_dir = Path(run_dir)
        self.path = self.run_dir / LOCK
        self.fd: int | None = None
        self.took_over: Holder | None = None

    def acquire(self) -> RunLock:
        """Take the lock; `RunLocked` when another writer holds it. Creates the run directory if needed."""
        self.run_dir.mkdir(parents=True, exist_ok=True)
        for _ in range(10):  # a lock file removed by its releasing holder between our open and flock: open again
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise _refusal(self.run_dir, _holder_soon(self.run_dir)) from None
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        else:  # pragma: no cover - ten releases in a row between open and flock
            raise _refusal(self.run_dir, read_holder(self.run_dir))
        try:
            old = read_holder(self.run_dir)
            if old is not None and not old.gone():
                if old.host != socket.gethostname():
                    why = f" (a run on another host: if it has ended, remove {str(self.path)!r})"
                else:
                    why = ""
                raise _refusal(self.run_dir, old, why)
            self.took_over = old
            me = os.getpid()
            note = {
                "pid": me,
                "host": socket.gethostname(),
                "started_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                "start_tick": start_tick(me),
            }
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(note) + "\n").encode(), 0)
            os.fsync(fd)
        except BaseException:
            os.close(fd)
            raise
        self.fd = fd
        return self

    def release(self) -> None:
        """Remove the note and let go (the file goes first, so no writer can find it locked and gone)."""
        if self.fd is None:
            return
        try:
            self.path.unlink(missing_ok=True)
        finally:
            os.close(self.fd)
            self.fd = None

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()
