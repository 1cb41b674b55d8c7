"""One writer per run directory (bench.execution.run_lock): two `bench run` processes started together on one
run_id, a killed run's lock taken over, another host's lock left alone, resume, and any executor under the lock."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from bench import api
from bench.execution.run_lock import LOCK, RunLock, RunLocked
from bench.records import read_records

REPO = Path(__file__).resolve().parents[1]
TOY = "suite=tests.toy_suite:ToySuite"


def bench_run(out: Path, run_id: str, *extra: str) -> subprocess.Popen:
    args = [sys.executable, "-m", "bench", "run", TOY, "episodes=4", "workers=1", f"out={out}", f"run_id={run_id}"]
    return subprocess.Popen(
        [*args, *extra], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env()
    )


def _env() -> dict[str, str]:
    return {**os.environ, "BENCH_TRACEBACK": "1", "COLUMNS": "200"}


def dead_pid() -> int:
    """The PID of a process that has exited (and been reaped)."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_two_runs_started_together_one_writes_the_other_names_it(tmp_path):
    # 12 episodes of 30 steps at 20 ms: ~7 s of writing, so the second surely finds the first at work
    procs = [bench_run(tmp_path, "same", "step_delay=0.02") for _ in range(2)]
    outs = [(p, *p.communicate(timeout=300)) for p in procs]
    codes = sorted(p.returncode for p, _, _ in outs)
    assert codes == [0, 2], [(p.returncode, err[-600:]) for p, _, err in outs]
    (winner, _, _), (loser, _, err) = sorted(outs, key=lambda o: o[0].returncode)
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert re.search(rf"being written by PID {winner.pid} on {re.escape(socket.gethostname())} since ", lines[0])
    assert lines[0].startswith("error: out=") and "Traceback" not in err
    records = read_records(tmp_path / "same" / "episodes.jsonl")
    assert len(records) == 12 and len({r.job_id for r in records}) == 12  # every job once
    assert {r.worker_pid for r in records} == {winner.pid}
    assert not (tmp_path / "same" / LOCK).exists()  # released at the end


def test_a_killed_runs_lock_is_taken_over_and_said(tmp_path):
    run_dir = tmp_path / "stale"
    run_dir.mkdir()
    gone = dead_pid()
    note = {"pid": gone, "host": socket.gethostname(), "started_at": "2020-01-01T00:00:00+0000", "start_tick": 1}
    (run_dir / LOCK).write_text(json.dumps(note))
    proc = bench_run(tmp_path, "stale")
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-600:]
    assert f"took over the lock of PID {gone} on {socket.gethostname()}" in out + err
    assert len(read_records(run_dir / "episodes.jsonl")) == 12
    assert not (run_dir / LOCK).exists()


def test_a_live_holder_is_refused_before_anything_is_written(tmp_path):
    run_dir = tmp_path / "held"
    with RunLock(run_dir):  # this process holds it, as a running `bench run` would
        before = sorted(p.name for p in run_dir.iterdir())
        proc = bench_run(tmp_path, "held")
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 2
        assert f"being written by PID {os.getpid()}" in err and len(err.strip().splitlines()) == 1
        assert sorted(p.name for p in run_dir.iterdir()) == before  # nothing written or changed
        with pytest.raises(RunLocked, match=f"PID {os.getpid()} on "):
            RunLock(run_dir).acquire()  # another open of the lock: flock refuses it even in-process
    assert not (run_dir / LOCK).exists()


def test_another_hosts_lock_is_not_taken_over(tmp_path):
    run_dir = tmp_path / "remote"
    run_dir.mkdir()
    note = {"pid": dead_pid(), "host": "elsewhere.example", "started_at": "2020-01-01T00:00:00+0000"}
    (run_dir / LOCK).write_text(json.dumps(note))
    with pytest.raises(RunLocked, match=r"on elsewhere\.example since .* if it has ended, remove"):
        RunLock(run_dir).acquire()
    assert json.loads((run_dir / LOCK).read_text()) == note  # left as it was


def test_resume_after_the_first_run_finished(tmp_path):
    cfg = api.RunConfig(suite="tests.toy_suite:ToySuite", episodes=2, workers=1, out=str(tmp_path), run_id="r")
    first = api.run(cfg)
    again = api.run(cfg)
    assert (first.ran, again.ran, again.resumed) == (6, 0, 6)
    assert not (tmp_path / "r" / LOCK).exists()


class _Probe:
    """An executor that checks, while it executes, that the run directory is locked by this process."""

    capabilities: frozenset[str] = frozenset()

    def __init__(self, run_dir: Path):
        self.run_dir, self.seen = run_dir, None

    def execute(self, jobs, spec, on_record) -> None:
        self.seen = json.loads((self.run_dir / LOCK).read_text())["pid"] == os.getpid()
        with pytest.raises(RunLocked):
            RunLock(self.run_dir).acquire()

    def close(self) -> None:
        pass


def test_any_executor_runs_under_the_parents_lock(tmp_path):
    cfg = api.RunConfig(suite="tests.toy_suite:ToySuite", episodes=1, workers=1, out=str(tmp_path), run_id="x")
    probe = _Probe(tmp_path / "x")
    api.run(cfg, executor=probe, summarize=False)
    assert probe.seen is True
    assert not (tmp_path / "x" / LOCK).exists()
