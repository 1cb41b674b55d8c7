"""The regression gate: pairing, the decision rule and its error rates on synthetic records, and the CLI."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench import scoring
from bench.errors import DataError
from bench.records import EpisodeRecord
from bench.regress import IQM_MIN_PAIRS, decide, evaluate, looks_schedule, pair_records
from bench.suite import episode_seed


def rec(robot: str, episode: int, success: bool, *, seed: int | None = None, error: str | None = None,
        init: str | None = "h", policy: str = "p", split: str = "seen") -> EpisodeRecord:
    return EpisodeRecord(
        run_id="r", job_id=f"Lift/{robot}/default|nominal|{episode}", suite="s", suite_version="1", task="Lift",
        robot=robot, env="default", split=split, condition="nominal", axis=None, level=None, params={},
        episode=episode, seed=episode_seed(0, episode) if seed is None else seed,
        init_state_hash=f"{init}{robot}{episode}" if init else None, success_once=success, success_at_end=success,
        return_=0.0, length=10, steps_to_success=None, error=error, policy=policy, checkpoint_sha256=None,
        backend="b", wall_s=0.0, finished_at=0.0, worker_pid=0)


def cells_from(base: np.ndarray, cand: np.ndarray) -> dict:
    """{cell: [(baseline record, candidate record)]} from (cells, episodes) 0/1 arrays."""
    b = [rec(f"R{c}", e, bool(base[c, e])) for c in range(base.shape[0]) for e in range(base.shape[1])]
    k = [rec(f"R{c}", e, bool(cand[c, e])) for c in range(cand.shape[0]) for e in range(cand.shape[1])]
    return pair_records(k, b)["cells"]


@pytest.mark.parametrize("episodes, batch, want", [(20, 5, [5, 10, 15, 20]), (6, 4, [4, 6]), (10, 0, [10]),
                                                   (3, 5, [3])], ids=["even", "ragged", "single", "batch>episodes"])
def test_looks_schedule(episodes, batch, want):
    assert looks_schedule(episodes, batch) == want


def test_pairing_by_cell_and_episode_counts_errors_as_failures():
    cand = [rec("A", 0, True), rec("A", 1, False, error="boom"), rec("A", 2, True), rec("B", 0, False),
            rec("B", 1, False, error="timeout")]
    base = [rec("A", 0, True), rec("A", 1, True), rec("B", 0, True), rec("B", 1, False, error="timeout")]
    out = pair_records(cand, base)  # A/2 has no twin; B/1 errored on both sides
    assert out["errors"] == {"candidate": 1, "baseline": 0, "both": 1} and out["unpaired"] == 1
    pairs = {k[1]: [(b.success_once, c.success_once) for b, c in v] for k, v in out["cells"].items()}
    assert pairs == {"A": [(True, True), (True, False)], "B": [(True, False)]}


def test_pairing_refuses_different_seeds_or_initial_states():
    with pytest.raises(DataError, match="seeds differ"):
        pair_records([rec("A", 0, True, seed=1)], [rec("A", 0, True, seed=2)])
    with pytest.raises(DataError, match="initial states differ"):
        pair_records([rec("A", 0, True, init="x")], [rec("A", 0, True, init="y")])


def test_identical_outcomes_never_fail_and_pass_once_the_budget_can_certify():
    rng = np.random.default_rng(0)
    outcomes = rng.random((7, 20)) < 0.7
    small = evaluate(cells_from(outcomes[:, :5], outcomes[:, :5]), "success_once", 0.05, 0.99375, rng, 500)
    assert small["mean"]["value"] == 0 and small["decision"] == "continue"  # 35 pairs cannot certify < 0.05
    # with no discordant pair the upper bound is z²/(n + z²), not 0 (a bootstrap would claim certainty)
    assert small["mean"]["ucb"] == pytest.approx(2.4977 ** 2 / (35 + 2.4977 ** 2), rel=1e-3)
    full = evaluate(cells_from(outcomes, outcomes), "success_once", 0.05, 0.99375, rng, 500)
    assert full["decision"] == "no_regression" and full["mean"]["ucb"] < 0.05


def test_clear_regression_is_detected_and_direction_matters():
    rng = np.random.default_rng(1)
    base = np.ones((7, 5), bool)
    cand = np.zeros((7, 5), bool)
    worse = evaluate(cells_from(base, cand), "success_once", 0.05, 0.99375, rng, 500)
    assert worse["decision"] == "regression" and worse["mean"]["lcb"] > 0.5
    better = evaluate(cells_from(cand, base), "success_once", 0.05, 0.99375, rng, 500)
    assert better["decision"] == "no_regression" and better["mean"]["value"] == -1


def test_iqm_bound_does_not_decide_on_a_handful_of_pairs():
    rng = np.random.default_rng(2)
    base, cand = np.ones((1, 2), bool), np.zeros((1, 2), bool)
    look = evaluate(cells_from(base, cand), "success_once", 0.05, 0.975, rng, 500)
    assert look["iqm"]["lcb"] == 1.0 and look["iqm"]["used"] is False  # the bootstrap would be "certain"
    assert look["decision"] == "continue"                                # Tango is not: LCB < 0
    assert IQM_MIN_PAIRS == 10


def test_iqm_bound_can_decide_with_enough_pairs():
    rng = np.random.default_rng(3)
    base = np.ones((7, IQM_MIN_PAIRS), bool)
    cand = base.copy()
    cand[:, : IQM_MIN_PAIRS // 2] = False
    look = evaluate(cells_from(base, cand), "success_once", 0.05, 0.99375, rng, 2000)
    assert look["iqm"]["used"] is True and look["decision"] == "regression"


@pytest.mark.parametrize("strict, want", [(False, ("inconclusive", 0)), (True, ("inconclusive", 1))])
def test_inconclusive_passes_unless_strict(strict, want):
    assert decide([{"decision": "continue"}], strict) == want
    assert decide([{"decision": "regression"}], strict) == ("regression", 1)
    assert decide([{"decision": "no_regression"}], strict) == ("no_regression", 0)


def test_false_alarm_rate_at_the_margin_is_at_most_alpha():
    """Candidate exactly `margin` worse (the worst case the gate must still pass): alarms <= alpha."""
    rng = np.random.default_rng(4)
    alarms, reps, level = 0, 400, 1 - 0.05 / 2  # one look, two statistics
    p_base = np.array([0.9, 0.7, 0.5])
    for _ in range(reps):
        u = rng.random((3, 8))
        v = np.where(rng.random((3, 8)) < 0.5, u, rng.random((3, 8)))  # half the pairs share the initial state
        base, cand = u < p_base[:, None], v < (p_base - 0.05)[:, None]  # true drop = margin exactly
        look = evaluate(cells_from(base, cand), "success_once", 0.05, level, rng, 200)
        alarms += look["decision"] == "regression"
    assert alarms / reps <= 0.05 + 0.02


def test_tango_bound_matches_closed_form_with_no_discordant_pairs():
    z = 1.6448536
    assert scoring.paired_score_bound(0, 0, 10, 0.95, "upper") == pytest.approx(z * z / (10 + z * z), rel=1e-4)
    assert scoring.paired_score_bound(0, 0, 10, 0.95, "lower") == pytest.approx(-z * z / (10 + z * z), rel=1e-4)


# -- CLI ----------------------------------------------------------------------------------------
def _bench(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench", *args], capture_output=True, text=True, cwd=cwd, timeout=600)


def _one_line_error(res: subprocess.CompletedProcess, match: str) -> None:
    assert res.returncode == 2, res.stderr[-1500:]
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and match in lines[0], res.stderr


@pytest.mark.parametrize("args, match", [
    (["candidate=random"], "baseline= is required"),
    (["candidate=random", "baseline=scripted", "policy=x"], "key 'policy' is not valid for bench regress"),
    (["candidate=random", "baseline=scripted", "margn=0.1"], "unknown key 'margn'"),
    (["candidate=randm", "baseline=scripted"], "Did you mean 'random'"),
    (["candidate=random", "baseline=scripted", "margin=1.5"], "margin=1.5"),
    (["candidate=random", "baseline=nope/run"], "no such file or directory"),
], ids=["no-baseline", "policy-key", "typo-key", "typo-policy", "bad-margin", "missing-dir"])
def test_bad_arguments_exit_2(tmp_path: Path, args, match):
    _one_line_error(_bench("regress", *args, f"runs={tmp_path / 'runs'}", cwd=tmp_path), match)
    assert not (tmp_path / "runs").exists()


def test_foreign_or_corrupt_json_baseline_exits_2(tmp_path: Path):
    foreign = tmp_path / "foreign.json"
    foreign.write_text(json.dumps({"hello": "world"}))
    _one_line_error(_bench("regress", "candidate=random", f"baseline={foreign}", cwd=tmp_path), "not a checkpoint")
    run = tmp_path / "brokenrun"
    run.mkdir()
    (run / "run.json").write_text("{not json")
    _one_line_error(_bench("regress", "candidate=random", f"baseline={run}", cwd=tmp_path), "not valid JSON")
    (run / "run.json").write_text(json.dumps({"schema": "something/else"}))
    _one_line_error(_bench("regress", "candidate=random", f"baseline={run}", cwd=tmp_path), "not a bench run.json")


def test_gate_detects_random_policy_against_expert(tmp_path: Path):
    """1 robot x 6 paired episodes: the expert succeeds, random never does -> regression, exit 1."""
    res = _bench("regress", "candidate=random", "baseline=scripted", "robots=[Panda]", "episodes=6", "batch=0",
                 "horizon=70", "workers=1", f"runs={tmp_path}", "run_id=g", cwd=tmp_path)
    assert res.returncode == 1, res.stderr[-2000:]
    v = json.loads((tmp_path / "g" / "verdict.json").read_text())
    assert v["verdict"] == "regression" and v["looks"][-1]["baseline_only"] == 6
    assert v["cells"][0]["baseline"] == 1.0 and v["cells"][0]["candidate"] == 0.0
    # both sides are ordinary runs with the same episode seeds
    seeds = [sorted(json.loads(line)["seed"] for line in (tmp_path / "g" / f"g-{s}" / "episodes.jsonl").open())
             for s in ("candidate", "baseline")]
    assert seeds[0] == seeds[1] == sorted(episode_seed(0, e) for e in range(6))


def test_gate_reuses_a_recorded_baseline_run(tmp_path: Path):
    base = _bench("run", "policy=scripted", "robots=[Panda]", "episodes=2", "horizon=70", "workers=1", "seed=3",
                  "run_id=base", f"out={tmp_path}", cwd=tmp_path)
    assert base.returncode == 0, base.stderr[-2000:]
    before = (tmp_path / "base" / "episodes.jsonl").read_bytes()
    res = _bench("regress", "candidate=scripted", f"baseline={tmp_path / 'base'}", "workers=1", f"runs={tmp_path}",
                 "run_id=g", f"out={tmp_path / 'v.json'}", cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]  # 2 identical pairs: inconclusive, passes (not strict)
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["baseline"]["reused"] is True and v["seed"] == 3 and v["verdict"] == "inconclusive"
    assert v["looks"][-1]["baseline_only"] == v["looks"][-1]["candidate_only"] == 0
    assert not (tmp_path / "g" / "g-baseline").exists()
    assert (tmp_path / "base" / "episodes.jsonl").read_bytes() == before
    # a different seed than the recorded baseline's is refused (the episodes would not pair)
    _one_line_error(_bench("regress", "candidate=scripted", f"baseline={tmp_path / 'base'}", "seed=4",
                           f"runs={tmp_path}", cwd=tmp_path), "seed=4 differs from the baseline run")
