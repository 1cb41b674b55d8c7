"""The processes a run started: found, waited for and, if they linger, ended, so a run leaves none behind.

A local Ray cluster (`ray_address=local`) starts daemons and worker processes below this one; `ray.shutdown()`
signals them but does not wait. `descendants` lists them (from /proc, on Linux) before the shutdown and
`reap` waits for them afterwards, ending the ones still there. Elsewhere (no /proc) both do nothing.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

PROC = Path("/proc")


def _parents() -> dict[int, int]:
    """pid -> parent pid of every process visible in /proc (empty without /proc)."""
    out: dict[int, int] = {}
    if not PROC.is_dir():
        return out
    for entry in PROC.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:  # gone meanwhile
            continue
        fields = stat.rsplit(")", 1)[-1].split()  # after "pid (comm)": state, ppid, ...
        if len(fields) > 1 and fields[1].isdigit():
            out[int(entry.name)] = int(fields[1])
    return out


def descendants(pid: int | None = None) -> list[int]:
    """Every process below `pid` (default: this one), children and their children, from /proc."""
    root = os.getpid() if pid is None else pid
    parents = _parents()
    children: dict[int, list[int]] = {}
    for child, parent in parents.items():
        children.setdefault(parent, []).append(child)
    out, todo = [], list(children.get(root, []))
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, []))
    return sorted(out)


def alive(pid: int) -> bool:
    """Running (a zombie has exited: it only waits to be reaped by its parent). Without /proc: the process
    exists (`kill(pid, 0)`; another user's counts)."""
    if not PROC.is_dir():
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        return True
    try:
        stat = (PROC / str(pid) / "stat").read_text()
    except OSError:
        return False
    state = stat.rsplit(")", 1)[-1].split()[:1]
    return bool(state) and state[0] not in ("Z", "X")


def reap(pids: list[int], timeout: float = 10.0) -> list[int]:
    """Wait up to `timeout` s for `pids` to exit, then SIGKILL those still running; returns those killed.

    Our own children are reaped (waitpid) so none is left a zombie; others are reaped by their parents.
    """
    deadline = time.monotonic() + timeout
    left = list(pids)
    while left:
        for pid in list(left):
            try:
                if os.waitpid(pid, os.WNOHANG)[0]:
                    left.remove(pid)
                    continue
            except ChildProcessError:  # not our child (or already reaped)
                pass
            if not alive(pid):
                left.remove(pid)
        if not left or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    for pid in left:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            continue
    for pid in left:
        try:
            os.waitpid(pid, 0)
        except ChildProcessError:
            pass
    return left
