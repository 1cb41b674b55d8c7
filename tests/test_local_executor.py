"""The local executor and the job queue both executors share: cell-major with warm cells first,
bounded retries of episodes whose worker died, the parent working while children start,
and the same records whatever the number of workers (toy suite, tests/toy_suite.py)."""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench import api
from bench.core.errors import ConfigError
from bench.execution import run_config
from bench.execution.scheduling import JobQueue, given_up_message
from bench.protocols.suite import Cell, Condition, expand_jobs
from bench.records import comparable
from tests.ray_scenarios import session_processes

REPO = Path(__file__).resolve().parents[1]

TOY = "tests.toy_suite:ToySuite"


def jobs(cells: str = "ab", episodes: int = 3):
    return expand_jobs([Cell("toy", "reach", r, "line", "seen") for r in cells], [Condition()], episodes, 0)


def test_queue_is_cell_major_and_prefers_a_warm_cell_then_a_cell_nobody_started():
    q = JobQueue(jobs("abcd", 2))
    assert q.take().cell.robot == "a"
    assert q.take(warm={"reach/a/line"}).cell.robot == "a"  # a worker that built a stays on a
    assert q.take().cell.robot == "b"  # a cold worker starts a cell nobody started, not a's last job
    assert q.take(warm={"reach/a/line"}).cell.robot == "c"  # a is done: the next cell nobody started
    assert q.take(warm={"reach/c/line"}).cell.robot == "c"
    assert q.take(warm={"reach/c/line"}).cell.robot == "d"
    assert q.take().cell.robot == "b"  # every cell started: the first with jobs left, in cell-major order
    assert q.take(warm={"reach/d/line"}).cell.robot == "d" and q.take() is None and not q


def test_a_lost_job_goes_first_and_is_given_up_after_bounded_retries():
    q = JobQueue(jobs("ab", 2), max_retries=2)
    first = q.take()
    q.take(warm={"reach/a/line"})
    assert q.lost(first, "worker 1 died") and q.take(warm={"reach/b/line"}) == first  # retried before all else
    assert q.lost(first, "worker 2 died") and q.take() == first
    assert not q.lost(first, "worker 3 died")  # third loss: given up, not queued again
    assert q.attempts(first) == ["worker 1 died", "worker 2 died", "worker 3 died"]
    assert given_up_message(q.attempts(first)) == "worker lost on each of 3 attempts (last: worker 3 died)"
    assert [j.cell.robot for j in iter(q.take, None)] == ["b", "b"]


def cfg(run_id: str, tmp_path, **kw) -> api.RunConfig:
    return api.RunConfig(suite=TOY, policy="scripted", out=str(tmp_path), run_id=run_id, **kw)


def _dead(pid: int) -> bool:
    """The process has exited (a zombie not yet reaped, or gone): its end of every pipe is closed."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] in "ZX"
    except (FileNotFoundError, ProcessLookupError):
        return True


@pytest.mark.parametrize("await_death", [False, True], ids=["kill", "kill-then-feed-the-dead"])
def test_a_killed_worker_process_loses_no_episode(tmp_path, await_death):
    """SIGKILL a child mid-run: its in-flight episodes run again elsewhere, once, noting why.

    With `await_death` the kill completes before the dispatcher feeds that child its next job, so
    the send meets a closed pipe (CI once died here with BrokenPipeError)."""
    killed: list[int] = []

    def kill_first_child(record):
        if not killed and record.worker_pid != os.getpid():
            killed.append(record.worker_pid)
            os.kill(record.worker_pid, signal.SIGKILL)
            while await_death and not _dead(record.worker_pid):
                time.sleep(0.01)

    slow = {"step_delay": 0.02}
    res = api.run(cfg("k", tmp_path, episodes=6, workers=2, suite_options=slow), on_record=kill_first_child)
    ref = api.run(cfg("one", tmp_path, episodes=6, workers=1))  # step_delay changes no record
    assert killed and len(res.records) == 18 and len({r.job_id for r in res.records}) == 18
    retried = [r for r in res.records if "retries" in r.extras]
    assert retried and all(
        r.extras["retries"] == [f"worker process {killed[0]} was killed by signal 9"] for r in retried
    )
    assert all(r.worker_pid != killed[0] for r in retried) and all(r.error is None for r in res.records)

    def same(r):
        d = comparable(r)
        d.pop("extras", None)
        return d

    assert sorted(map(same, res.records), key=lambda d: d["job_id"]) == sorted(
        map(same, ref.records), key=lambda d: d["job_id"]
    )


def test_parent_and_children_share_the_work(tmp_path):
    res = api.run(cfg("w3", tmp_path, episodes=4, workers=3, suite_options={"step_delay": 0.01}))
    pids = {r.worker_pid for r in res.records}
    assert os.getpid() in pids and len(pids) == 3  # the parent ran episodes while the two children started


def _marks(folder: Path, n: int, timeout: float = 120.0) -> set[int]:
    """The pids that left a preload mark in `folder`, once `n` have (or at `timeout`)."""
    deadline = time.time() + timeout
    while len(list(folder.iterdir())) < n and time.time() < deadline:
        time.sleep(0.05)
    return {int(f.name) for f in folder.iterdir()}


def test_workers_start_while_the_plan_finishes_and_run_its_episodes(tmp_path, monkeypatch):
    """`plan_with_workers` starts the children as soon as the job count is known; they preload (the toy
    suite's `preload` leaves its pid) before `run` is called, and then run episodes."""
    (marks := tmp_path / "marks").mkdir()
    monkeypatch.setenv("TOY_PRELOAD_MARK", str(marks))
    p, executor = api.plan_with_workers(cfg("pre", tmp_path, episodes=4, workers=3, suite_options={"step_delay": 0.01}))
    assert not (tmp_path / "pre").exists()  # the plan wrote nothing
    pids = _marks(marks, 2)
    assert len(pids) == 2 and os.getpid() not in pids  # two children preloaded before the run began
    res = api.run(p, executor=executor)
    assert {r.worker_pid for r in res.records} == {os.getpid(), *pids} and len(res.records) == 12
    assert mp.active_children() == []


def test_no_more_workers_start_than_there_are_jobs(tmp_path, monkeypatch):
    (marks := tmp_path / "marks").mkdir()
    monkeypatch.setenv("TOY_PRELOAD_MARK", str(marks))
    p, executor = api.plan_with_workers(cfg("few", tmp_path, episodes=1, workers=8))  # 3 jobs: 2 children
    assert len(_marks(marks, 2)) == 2 and len(_marks(marks, 3, timeout=2.0)) == 2  # and no third, 2 s later
    res = api.run(p, executor=executor)
    assert len(res.records) == 3 and mp.active_children() == []


def test_a_plan_that_fails_stops_the_workers_it_started(tmp_path, monkeypatch):
    """The calibration is checked after the workers started (after the policy's preflight): the error
    comes out as usual, the children are gone and nothing was written."""
    with pytest.raises(ConfigError, match="calibration"):
        api.plan_with_workers(cfg("bad", tmp_path, workers=3, calibration=str(tmp_path / "none.json")))
    assert mp.active_children() == [] and not (tmp_path / "bad").exists()


def test_workers_started_for_a_finished_run_are_stopped(tmp_path):
    api.run(cfg("done", tmp_path, episodes=2, workers=1))
    p, executor = api.plan_with_workers(cfg("done", tmp_path, episodes=2, workers=3))  # resume: nothing to do
    res = api.run(p, executor=executor)
    assert res.ran == 0 and res.resumed == 6 and mp.active_children() == []


@pytest.mark.parametrize(
    "argv, message",
    [
        (["executor=dask"], "executor='dask': valid: local, ray"),
        (["actors=2"], "actors=2 applies to executor=ray; add executor=ray or leave it out"),
        (["ray_env=pip"], "ray_env='pip' applies to executor=ray"),
        (["executor=ray", "workers=2"], "workers=2 applies to executor=local; with executor=ray give actors="),
        (["executor=ray", "ray_address=somewhere"], "ray_address='somewhere': give auto, local or HOST:PORT"),
        (["executor=ray", "ray_env=conda"], "ray_env='conda': valid: code, pip, installed"),
        (["executor=ray", "actor_cpus=0"], "actor_cpus=0: must be in (0, 1024]"),
    ],
)
def test_executor_keys_are_checked_before_anything_runs(tmp_path, argv, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        api.plan(api.config_from_argv([f"suite={TOY}", f"out={tmp_path}", "run_id=x", *argv]))
    assert not (tmp_path / "x").exists()


def test_executor_keys_may_change_on_resume():
    where_and_how = {"executor", "ray_address", "actors", "actor_cpus", "actor_gpus", "ray_env", "workers"}
    assert where_and_how <= run_config.RESUMABLE_KEYS


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="lists processes from /proc (Linux)")
def test_a_run_with_workers_leaves_no_process_behind(tmp_path):
    """The moment `bench run workers=2` has exited, nothing of it is left in its session: no child, and no
    multiprocessing resource tracker (which spawned children start, and which outlived the run by a moment)."""
    for i in range(3):
        with open(tmp_path / "err", "w") as err:  # not a pipe: waiting for its end would wait for its holders
            proc = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "bench",
                    "run",
                    "suite=tests.toy_suite:ToySuite",
                    "episodes=4",
                    "workers=2",
                    "n_boot=200",
                    f"out={tmp_path}",
                    f"run_id=r{i}",
                ],
                cwd=REPO,
                env={**os.environ, "PYTHONPATH": str(REPO)},
                stdout=subprocess.DEVNULL,
                stderr=err,
                start_new_session=True,
            )
            assert proc.wait(timeout=300) == 0, (tmp_path / "err").read_text()[-2000:]
        assert session_processes(proc.pid) == []
        assert "12 episodes in" in (tmp_path / "err").read_text()
