"""The runner on the pure-numpy toy suite (tests/toy_suite.py, loaded as suite=tests.toy_suite:ToySuite):
workers, resume after kill -9, timeouts, envs that raise or return NaN, action chunks, plugin keys."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench import api
from bench.cli import main
from bench.core.errors import ConfigError, RegistryError
from bench.core.schema import validate
from bench.protocols import registry
from bench.records import comparable, read_records

REPO = Path(__file__).resolve().parents[1]
TOY = "suite=tests.toy_suite:ToySuite"


def run(tmp_path: Path, run_id: str, *extra: str) -> int:
    given = {e.split("=", 1)[0] for e in extra}
    defaults = [d for d in ("episodes=4", "workers=1") if d.split("=")[0] not in given]
    return main(["run", TOY, *defaults, f"out={tmp_path}", f"run_id={run_id}", *extra])


def records(tmp_path: Path, run_id: str) -> list:
    return sorted(read_records(tmp_path / run_id / "episodes.jsonl"), key=lambda r: r.job_id)


def test_runs_out_of_tree_suite_with_its_own_key(tmp_path):
    assert run(tmp_path, "a", "goal=0.9") == 0
    recs = records(tmp_path, "a")
    assert len(recs) == 12 and all(r.error is None for r in recs)
    meta = json.loads((tmp_path / "a" / "run.json").read_text())
    assert meta["config"]["goal"] == 0.9 and meta["suite"]["goal"] == 0.9 and meta["suite"]["name"] == "toy"
    assert run(tmp_path, "b", "goal=-0.9") == 0
    assert [r.return_ for r in records(tmp_path, "a")] != [r.return_ for r in records(tmp_path, "b")]


def test_two_workers_give_the_records_of_one(tmp_path):
    # episodes slow enough (0.15 s) that both spawned workers get some, whatever the machine's load
    assert run(tmp_path, "one", "episodes=6", "step_delay=0.005") == 0
    assert run(tmp_path, "two", "episodes=6", "workers=2", "step_delay=0.005") == 0
    one, two = records(tmp_path, "one"), records(tmp_path, "two")
    assert [comparable(r) for r in one] == [comparable(r) for r in two]
    assert len({r.worker_pid for r in two}) == 2  # two spawned processes really ran episodes


def test_resume_after_kill_9(tmp_path):
    """Kill the whole process group mid-run; the rerun finishes it, and equals an uninterrupted run."""
    args = [
        sys.executable,
        "-m",
        "bench",
        "run",
        TOY,
        "episodes=20",
        "workers=2",
        "step_delay=0.01",
        f"out={tmp_path}",
        "run_id=k",
    ]
    proc = subprocess.Popen(
        args, cwd=REPO, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    path = tmp_path / "k" / "episodes.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline and (not path.exists() or len(path.read_bytes().splitlines()) < 8):
        time.sleep(0.1)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done = len(read_records(path))
    assert 8 <= done < 60, done
    res = subprocess.run(args, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert f"resuming {tmp_path / 'k'}: {done} of 60 episodes already recorded" in " ".join(res.stderr.split())
    resumed = records(tmp_path, "k")
    assert len(resumed) == 60 and len({r.job_id for r in resumed}) == 60
    assert run(tmp_path, "whole", "episodes=20") == 0
    assert [comparable(r) for r in resumed] == [comparable(r) for r in records(tmp_path, "whole")]


def test_a_hanging_env_times_out_and_the_run_goes_on(tmp_path):
    assert run(tmp_path, "t", "fault=hang", "timeout=0.3", "episodes=2") == 3  # cell c measured nothing
    recs = records(tmp_path, "t")
    hung = [r for r in recs if r.robot == "c"]
    assert len(hung) == 2 and all(r.error.startswith("timeout after 0.3 s at step 2") for r in hung)
    assert all(r.error is None for r in recs if r.robot != "c")


@pytest.mark.parametrize(
    "fault, message",
    [
        ("raise", "RuntimeError: toy env exploded (toy_suite.py:"),
        ("nan_reward", "non-finite reward (nan) at step 2"),
        ("nan_obs", "non-finite observation 'state' at step 3"),
    ],
)
def test_env_faults_are_recorded_and_the_run_goes_on(tmp_path, fault, message, capsys):
    assert run(tmp_path, "f", f"fault={fault}") == 3  # every episode of cell c failed: it measured nothing
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith(f"nothing measured: run f ({tmp_path / 'f'}): 1 of 3 cells completed no episode ")
    assert f"(reach/c/line) while the others did; error: {message}" in last
    recs = records(tmp_path, "f")
    bad = [r for r in recs if r.robot == "c"]
    assert len(bad) == 4 and all(r.error and r.error.startswith(message) for r in bad), bad[0].error
    assert all(r.error is None for r in recs if r.robot != "c")
    summary = json.loads((tmp_path / "f" / "summary.json").read_text())  # no NaN anywhere: it validates
    assert validate(summary) == "bench.summary/1" and summary["counts"]["errors"] == 4
    unseen = summary["splits"].get("unseen")
    assert unseen is None  # every unseen episode failed: no rate, and no NaN pretending to be one


def test_non_finite_action_is_recorded(tmp_path):
    assert run(tmp_path, "n", "policy=tests.toy_suite:nan_policy", "episodes=1") == 3  # no episode completed
    assert all(r.error == "policy returned a non-finite action at step 1" for r in records(tmp_path, "n"))


def test_action_chunks_run_open_loop(tmp_path):
    assert run(tmp_path, "c", "policy=tests.toy_suite:chunk_policy", "robots=[a]") == 0
    recs = records(tmp_path, "c")
    assert all(r.error is None and r.length == 30 for r in recs) and any(r.success_once for r in recs)


def test_policy_obs_keys_are_checked_before_anything_is_written(tmp_path, capsys):
    assert run(tmp_path, "cam", "policy=tests.toy_suite:NeedsCamera") == 2
    err = capsys.readouterr().err
    assert (
        "policy 'tests.toy_suite:NeedsCamera' needs observation keys ['rgb.front']; suite 'toy' cell "
        "reach/a/line provides state(2) float32" in err
    )
    assert not (tmp_path / "cam").exists()


def test_keys_nobody_owns_are_refused(tmp_path, capsys):
    assert run(tmp_path, "k", "env_id=X") == 2
    err = capsys.readouterr().err
    assert "unknown key 'env_id'" in err and "suite tests.toy_suite:ToySuite: goal, fault" in err
    assert run(tmp_path, "k", "fault=boom") == 2
    assert "fault='boom': valid: none, raise" in capsys.readouterr().err
    assert not (tmp_path / "k").exists()


def test_entry_point_name_must_equal_suite_name(monkeypatch):
    from importlib.metadata import EntryPoint

    ep = EntryPoint(name="toy2", value="tests.toy_suite:ToySuite", group=registry.SUITES)
    monkeypatch.setattr(registry, "group_entry_points", lambda group: {"toy2": ep})
    with pytest.raises(
        RegistryError,
        match=r"suite='toy2': the entry point loads tests.toy_suite.ToySuite, whose "
        r"name is 'toy'; an entry-point name must equal its Suite.name",
    ):
        registry.suite_class("toy2")


def test_typed_api(tmp_path):
    cfg = api.RunConfig(
        suite="tests.toy_suite:ToySuite",
        policy="scripted",
        episodes=3,
        workers=1,
        out=str(tmp_path),
        run_id="api",
        suite_options={"goal": 0.2},
    )
    result = api.run(cfg)
    assert result.ran == 9 and result.resumed == 0 and len(result.records) == 9
    assert result.summary["splits"]["seen"]["success_once"]["mean"]["value"] == 1.0
    again = api.run(cfg)  # the same config again: everything resumes
    assert again.ran == 0 and again.resumed == 9
    assert api.score(tmp_path / "api") == again.summary
    with pytest.raises(ConfigError, match="unknown key 'goals' for suite tests.toy_suite:ToySuite; valid: goal"):
        api.plan(api.RunConfig(suite="tests.toy_suite:ToySuite", suite_options={"goals": 1}))


def test_progress_bar_counts_successes_or_shows_the_mean_return(tmp_path, capsys, monkeypatch):
    """The bar shows what the run is scored by: successes, or the mean return of completed episodes."""
    monkeypatch.setenv("COLUMNS", "200")  # a captured stream is not a terminal: rich would crop the bar at 80
    assert run(tmp_path, "s", "episodes=1") == 0
    assert f"successes {sum(r.success_once for r in records(tmp_path, 's'))}," in capsys.readouterr().err
    assert run(tmp_path, "r", "episodes=1", "metric=return") == 0
    returns = [r.return_ for r in records(tmp_path, "r")]
    err = capsys.readouterr().err
    assert f"mean return {sum(returns) / len(returns):.2f}" in err and "successes" not in err


def test_a_partly_failed_run_counts_its_errors_per_cell_in_its_last_line(tmp_path, capsys):
    """Some episodes of a cell errored, every cell has a completed one: exit 0, the last line counts them."""
    assert run(tmp_path, "p", "episodes=2") == 0
    path = tmp_path / "p" / "episodes.jsonl"
    recs = [json.loads(line) for line in path.read_text().splitlines()]
    for r in recs:
        if r["robot"] in ("a", "b") and r["episode"] == 1:
            r.update(error="RuntimeError: lost", success_once=False, success_at_end=False)
    path.write_text("".join(json.dumps(r) + "\n" for r in recs))
    capsys.readouterr()
    assert main(["score", str(tmp_path / "p")]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out[-1] == (
        "2 of 6 episodes errored or timed out (reach/a/line 1 of 2, reach/b/line 1 of 2); see 'error' in episodes.jsonl"
    )
    path.write_text("")  # no record at all
    assert main(["score", str(tmp_path / "p")]) == 3
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"nothing measured: {tmp_path / 'p'}: episodes.jsonl holds no episode record"
    )


def test_a_log_that_is_not_a_terminal_gets_a_progress_line_while_nothing_finishes(tmp_path, capsys, monkeypatch):
    """CI logs: a plain progress line at least every PERIOD_S seconds (here 0.2 s), also between episodes."""
    from bench.execution import progress

    monkeypatch.setattr(progress, "PERIOD_S", 0.2)
    assert run(tmp_path, "slow", "robots=[a]", "episodes=2", "horizon=30", "step_delay=0.05") == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if f"] {TOY[6:]}: " in ln]
    assert len(lines) >= 10, lines  # 2 episodes x 30 steps x 50 ms = 3 s
    assert any(": 0/2 episodes, successes 0, errors 0, elapsed " in ln for ln in lines)
    assert lines[-1].endswith("eta 0:00:00") and ": 2/2 episodes" in lines[-1]


def test_until_the_first_episode_ends_the_progress_says_the_workers_are_starting(tmp_path, capsys, monkeypatch):
    """A newcomer's first run spends its first seconds importing and building envs: the progress says so
    (at once, and in each plain line until an episode ends), not only `0/N ... eta ?`."""
    from bench.execution import progress

    monkeypatch.setattr(progress, "PERIOD_S", 0.2)
    assert run(tmp_path, "st", "robots=[a]", "episodes=1", "horizon=30", "step_delay=0.05") == 0
    err = capsys.readouterr().err.splitlines()
    starting = progress.starting_text(1)
    assert starting == "starting 1 worker: importing the simulator and the policy, building envs"
    head = next(i for i, ln in enumerate(err) if ln.startswith("run st: "))
    assert err[head + 1] == starting, err
    lines = [ln for ln in err if f"] {TOY[6:]}: " in ln]
    before = [ln for ln in lines if ": 0/1 episodes" in ln]  # 1.5 s of episode, a line every 0.2 s
    assert before and all(ln.endswith(f"eta ?; {starting}") for ln in before), lines
    assert lines[-1].endswith("eta 0:00:00"), lines  # the first record ended the start
    assert progress.starting_text(3, ray=True).startswith("starting 3 Ray actors: ")
