"""Curves and breaking points (bench.scoring.curves): a logistic fit of success against a drawn factor, Firth's
penalty for separated outcomes, and the factor where success falls to half of nominal with a bootstrap interval
— checked against data drawn from a known curve (the interval's coverage over repeated samples), against
separated and flat outcomes, and for too few draws."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.scoring.curves import MIN_DRAWS, curve, fit

TRUE_BREAK = 0.4  # success = sigmoid(4 (log x - log 0.4)): half of a nominal 1.0 at x = 0.4


def _sample(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    x = np.exp(rng.uniform(math.log(0.1), math.log(3.0), n))
    p = 1.0 / (1.0 + np.exp(-4.0 * (np.log(x) - math.log(TRUE_BREAK))))
    return x, (rng.random(n) < p).astype(float)


def test_the_breaking_point_interval_covers_the_true_one():
    """Over 40 samples of 100 episodes from a known curve, the 95% interval holds the true breaking point in at
    least 85% of them (measured: 97.5%), and the estimates centre on it."""
    rng = np.random.default_rng(0)
    hits, points = 0, []
    for r in range(40):
        x, y = _sample(rng, 100)
        c = curve(x, y, 1.0, np.random.default_rng(r), n_boot=200)
        lo, hi = c["ci"]
        hits += (lo is None or lo <= TRUE_BREAK) and (hi is None or hi >= TRUE_BREAK)
        points.append(c["breaks_at"])
    assert hits >= 34, hits
    assert abs(np.median(points) - TRUE_BREAK) < 0.05


def test_fit_recovers_the_log_curve_and_band_brackets_it():
    rng = np.random.default_rng(1)
    x, y = _sample(rng, 2000)
    f = fit(x, y)
    assert f.log and f.crossing(0.5) == pytest.approx(TRUE_BREAK, rel=0.1)
    c = curve(x, y, 1.0, np.random.default_rng(2), n_boot=100)
    band = c["band"]
    assert len(band) == 21 and all(b["lo"] <= b["p"] <= b["hi"] for b in band)
    assert band[0]["x"] == pytest.approx(c["range"][0]) and c["scale"] == "log"


def test_separated_outcomes_still_give_a_finite_breaking_point():
    x = np.linspace(0.1, 3.0, 30)
    y = (x > 1.0).astype(float)  # a threshold: maximum likelihood would give an infinite slope
    c = curve(x, y, 1.0, np.random.default_rng(0), n_boot=200)
    assert 0.9 < c["breaks_at"] < 1.2


def test_a_curve_that_never_reaches_half_of_nominal_is_censored_with_a_reason():
    x = np.linspace(0.1, 3.0, 30)
    c = curve(x, np.ones(30), 1.0, np.random.default_rng(0), n_boot=100)
    assert c["breaks_at"] is None and c["reason"] == "success stays above half of nominal over the drawn range"
    c = curve(x, np.zeros(30), 1.0, np.random.default_rng(0), n_boot=100)
    assert c["breaks_at"] is None and "below half of nominal" in c["reason"]


def test_too_few_draws_make_no_curve():
    c = curve(np.arange(1, MIN_DRAWS), np.ones(MIN_DRAWS - 1), 1.0, np.random.default_rng(0))
    assert c["curve"] is None and c["reason"] == f"{MIN_DRAWS - 1} draws; a curve needs at least {MIN_DRAWS}"


def _run(tmp_n: int = 60) -> list:
    """A run's records: 20 nominal episodes (all succeed) and a friction range drawn per episode whose success
    follows the known curve."""
    from tests.fixtures import record

    rng = np.random.default_rng(3)
    recs = [record(True, episode=i, seed=i) for i in range(20)]
    x, y = _sample(rng, tmp_n)
    name = "friction~logU(0.1,3)"
    recs += [
        record(bool(s), condition=name, axis="friction", level=[0.1, 3.0], params={"friction": float(v)}, episode=i)
        for i, (v, s) in enumerate(zip(x, y))
    ]
    recs += [record(False, condition="friction~from(cal@12345678)", axis="friction", level=[0, 9], episode=0)]
    return recs


def test_a_run_summary_carries_its_curves_the_leaderboard_and_the_report_show_them(tmp_path):
    from bench.board.leaderboard import entry_from_summary
    from bench.board.report.figures import fig_curves
    from bench.core.schema import validate
    from bench.scoring.curves import breaking_sentence, curves_of
    from bench.scoring.summary import build
    from tests.fixtures import provenance

    recs = _run()
    meta = {
        "run_id": "r",
        "suite": {"name": "s", "version": "1", "manifest": {}},
        "policy": {"name": "p", "checkpoint": None, "checkpoint_sha256": None},
        "config": {"seed": 0, "n_boot": 200, "confidence": 0.95},
        "expected_episodes": len(recs),
        "provenance": provenance(episode_seeds=[1], started_at="t"),
    }
    summary = build(recs, run_meta=meta).to_json()
    assert validate(summary) == "bench.summary/1"
    (c,) = summary["curves"]  # the range only: a from(...) condition draws no factor
    assert c["condition"] == "friction~logU(0.1,3)" and c["n"] == 60 and c["nominal"] == 1.0
    assert c["ci"][0] is not None and c["ci"][0] <= c["breaks_at"] <= c["ci"][1]
    again = curves_of(recs, np.random.default_rng([0, 7919, 2]), n_boot=200)
    assert again == summary["curves"]  # seeded from the run seed: the same curve every time
    assert breaking_sentence(c).startswith("friction~logU(0.1,3): this policy breaks at friction ")
    entry = entry_from_summary(summary, "r")
    assert entry["curves"] == [{k: c[k] for k in ("condition", "axis", "n", "breaks_at", "ci")}]
    assert fig_curves(summary, tmp_path / "curves.png") == 1 and (tmp_path / "curves.png").stat().st_size > 1000


def test_a_curve_asked_for_with_too_few_draws_is_refused(tmp_path):
    from bench.cli import main

    out = tmp_path / "runs"
    argv = ["run", "suite=held_out_robots", "robots=[Panda]", "episodes=3", f"out={out}"]
    assert main([*argv, "perturb.friction.curve=loguniform(0.01,1)"]) == 2
    assert main([*argv, "perturb.friction.curve=[0.1,1]"]) == 2
    assert not out.exists()
