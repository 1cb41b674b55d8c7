"""`policy=remote` against a real server that is slow to set up or hangs (tests/slow_server.py, a subprocess on
127.0.0.1): a server's set-up (its first request, building a cell) is bounded by `warmup_s`, not by the per-answer
`timeout_s`; the run says what it waits for; a server that never answers fails with one line."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from bench import api
from bench.records import EPISODES, read_records

REPO = Path(__file__).resolve().parents[1]
TOY = "tests.toy_suite:ToySuite"
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


@contextmanager
def slow_server(*args: str) -> Iterator[int]:
    """tests/slow_server.py with `args`, in its own process group; yields its port."""
    proc = subprocess.Popen(
        [sys.executable, str(REPO / "tests" / "slow_server.py"), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=ENV,
        start_new_session=True,
    )
    try:
        line = proc.stdout.readline() if proc.stdout else ""
        assert line.startswith("listening on 127.0.0.1:"), line
        yield int(line.rsplit(":", 1)[1])
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def bench_cli(args: list[str], timeout: float) -> subprocess.CompletedProcess:
    """`bench ARGS` in a fresh interpreter, stdout and stderr captured (not a terminal, as in CI)."""
    return subprocess.run(
        [sys.executable, "-m", "bench", *args], cwd=REPO, env=ENV, capture_output=True, text=True, timeout=timeout
    )


def outcomes(records: list) -> list[tuple]:
    return sorted((r.job_id, r.success_once, r.success_at_end, r.length, r.init_state_hash) for r in records)


def two_robots(tmp_path, policy: str, **keys) -> api.RunConfig:
    """Two episodes on each of the toy suite's robots a and b with `policy` (the run is named after it)."""
    return api.RunConfig(
        suite=TOY,
        policy=policy,
        robots=["a", "b"],
        episodes=2,
        workers=1,
        n_boot=200,
        out=str(tmp_path),
        run_id=policy,
        **keys,
    )


def test_set_up_is_bounded_by_warmup_s_not_by_timeout_s(tmp_path):
    """A server whose set-up (2 s per connection, 2 s more per new cell) exceeds timeout_s=0.5 passes."""
    with slow_server("--first", "2", "--change", "2") as port:
        res = api.run(two_robots(tmp_path, "remote", policy_options={"port": port, "timeout_s": 0.5}))
    local = api.run(two_robots(tmp_path, "scripted"))
    assert [r.error for r in res.records] == [None] * 4
    assert outcomes(res.records) == outcomes(local.records)
    assert all(r.extras["policy"]["requests"] > 0 for r in res.records)


@pytest.mark.slow
def test_a_server_taking_20_s_to_warm_up_and_20_s_per_cell_change_passes_with_default_settings(tmp_path):
    with slow_server("--first", "20", "--change", "20") as port:
        t0 = time.monotonic()
        res = bench_cli(
            [
                "run",
                f"suite={TOY}",
                "policy=remote",
                f"port={port}",
                "robots=[a,b]",
                "episodes=2",
                "workers=1",
                "n_boot=200",
                f"out={tmp_path}",
                "run_id=slow",
            ],
            timeout=900,
        )
        wall = time.monotonic() - t0
    assert res.returncode == 0, res.stderr[-3000:]
    records = read_records(tmp_path / "slow" / EPISODES)
    assert len(records) == 4 and [r.error for r in records] == [None] * 4, [r.error for r in records]
    assert wall > 60  # the check (20 s), cell a (20 s), cell b (20 + 20 s): the sleeps really happened
    # the log says what the run waits for, before the run (on stderr) and during it (the progress lines)
    assert f"waiting for the policy server at 127.0.0.1:{port} to warm up" in res.stderr, res.stderr[-3000:]
    assert "errored" not in res.stdout


@pytest.mark.parametrize(
    "hang, message",
    [
        ("connect", "accepted the connection but did not answer the websocket handshake within warmup_s=3 s"),
        ("request", "did not answer within warmup_s=3 s"),
    ],
)
def test_a_server_that_hangs_fails_with_one_line(tmp_path, hang, message):
    with slow_server("--hang", hang) as port:
        t0 = time.monotonic()
        res = bench_cli(
            ["run", f"suite={TOY}", "policy=remote", f"port={port}", "warmup_s=3", f"out={tmp_path}", "run_id=hung"],
            timeout=120,
        )
        wall = time.monotonic() - t0
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2, res.stderr
    assert lines[-1].startswith("error: policy=remote: ") and message in lines[-1], lines
    assert all(ln.startswith("waiting for the policy server") for ln in lines[:-1]), lines  # nothing else
    assert "Traceback" not in res.stderr and wall < 60
    assert not (tmp_path / "hung").exists()
