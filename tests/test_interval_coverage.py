"""The coverage tables of the intervals the harness prints (issue 38, item 0), at test size.

`benchmarks/bench_interval_coverage.py` simulates runs with known per-cell rates, computes each interval with the
function the harness calls and counts how often it contains the truth; it prints the full tables (2000 runs per
row). Here: 400 simulated runs per row on the scenarios that broke the replaced methods (rates near 0 and 1, many
cells, few episodes) and one near 0.5, and the regression gate's bounds. At 0.95 nominal a row's Monte-Carlo standard error is about 0.011, so the
floor of 0.92 fails an interval that covers 0.90 or less (as the replaced aggregate did: 0.43 to 0.65).
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.bench_interval_coverage import (
    Scenario,
    aggregate,
    coverage,
    gap,
    gate_iqm,
    gate_pooled_upper,
    interaction,
    paired_drop,
    per_cell,
    returns_gap,
    returns_mean,
)

REPS = 400
FLOOR = 0.92

EDGES = (Scenario(0.02, 12, 5), Scenario(0.98, 12, 20), Scenario(0.98, 12, 5, 1.0), Scenario(0.5, 2, 10))
DROPS = (Scenario(0.98, 12, 10, 0.0, 0.3), Scenario(0.1, 2, 10, 0.0, 0.05), Scenario(0.5, 12, 10, 0.0, 0.2))


@pytest.mark.parametrize("sc", EDGES, ids=Scenario.label)
def test_per_cell_wilson_covers(sc):
    assert coverage(per_cell, sc, REPS, 1)[0] >= FLOOR


@pytest.mark.parametrize("statistic", ["mean", "iqm"])
@pytest.mark.parametrize("sc", EDGES, ids=Scenario.label)
def test_aggregate_of_cell_rates_covers(sc, statistic):
    now, before = coverage(aggregate(statistic), sc, REPS, 2)
    assert now >= FLOOR, (now, before)


def test_the_replaced_aggregate_did_not_cover():
    """The table can fail: the replaced method (Jeffreys draws per cell, widened to the estimate) covers the mean
    of 12 cells at 0.98 over 20 episodes well under the floor."""
    now, before = coverage(aggregate("mean"), Scenario(0.98, 12, 20), REPS, 3)
    assert before is not None and before < 0.8 < FLOOR <= now


@pytest.mark.parametrize("sc", DROPS, ids=Scenario.label)
def test_gap_and_paired_drop_and_gate_bound_cover(sc):
    assert coverage(gap, sc, REPS, 4)[0] >= FLOOR
    assert coverage(paired_drop, sc, REPS, 5)[0] >= FLOOR
    assert coverage(gate_pooled_upper, sc, REPS, 6)[0] >= FLOOR


@pytest.mark.parametrize("sc", (Scenario(0.5, 12, 5), Scenario(0.5, 1, 20), Scenario(0.5, 2, 10)), ids=Scenario.label)
def test_mean_return_covers_with_few_episodes_per_cell(sc):
    """Skewed (lognormal) returns: the skewness-corrected t over few episodes or few cells."""
    now, before = coverage(returns_mean, sc, REPS, 7)
    assert now >= FLOOR, (now, before)


def test_return_gap_covers():
    now, _ = coverage(returns_gap, Scenario(0.5, 12, 5, 1.0, 0.3), REPS, 11)
    assert now >= FLOOR, now


def test_combined_axes_interaction_covers():
    assert coverage(interaction, Scenario(0.9, 12, 10, 0.0, 0.1), 200, 8)[0] >= FLOOR


GATE_IQM = (
    ("upper", Scenario(0.1, 4, 10, 0.0, 0.05)),
    ("upper", Scenario(0.05, 12, 20, 0.0, 0.05)),
    ("upper", Scenario(0.98, 12, 10, 0.0, 0.3)),
    ("lower", Scenario(0.5, 12, 10, 1.0, 0.2)),
    ("lower", Scenario(0.9, 4, 10, 1.0, 0.1)),
)


@pytest.mark.parametrize(("side", "sc"), GATE_IQM, ids=[f"{side} {sc.label()}" for side, sc in GATE_IQM])
def test_gate_iqm_bounds_cover(side, sc):
    """The gate's IQM bounds (smoothed Bayesian bootstrap of the pairs) at rates near 0, 0.5 and 1."""
    now, before = coverage(gate_iqm(side), sc, REPS, 9)
    assert now >= FLOOR, (now, before)


def test_the_replaced_gate_iqm_bound_did_not_cover():
    """The plain bootstrap of pairs has no spread in a cell where no pair disagrees: at 0.05 -> 0 over 4 cells its
    upper bound sits on the estimate half of the time."""
    now, before = coverage(gate_iqm("upper"), Scenario(0.05, 4, 10, 0.0, 0.05), REPS, 10)
    assert before is not None and before < 0.8 < FLOOR <= now


def test_skewness_corrected_t_is_welchs_on_symmetric_returns_and_longer_on_the_skewed_side():
    """Hall's correction vanishes when the returns' third moment does (the t interval of scipy), and stretches the
    interval toward the long tail otherwise."""
    from scipy import stats as sps

    from bench.scoring import stats

    rng = np.random.default_rng(0)
    symmetric = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0])
    est = stats.aggregate([symmetric], rng, stats.Boot("mean", 100, 0.95, binary=False))
    lo, hi = sps.t.interval(0.95, len(symmetric) - 1, symmetric.mean(), sps.sem(symmetric))
    assert (est.lo, est.hi) == pytest.approx((lo, hi), rel=1e-9)
    skewed = np.array([1.0, 1.1, 1.2, 1.3, 1.5, 2.0, 9.0])
    est = stats.aggregate([skewed], rng, stats.Boot("mean", 100, 0.95, binary=False))
    lo, hi = sps.t.interval(0.95, len(skewed) - 1, skewed.mean(), sps.sem(skewed))
    assert est.hi - est.value > hi - skewed.mean() and est.value - est.lo < skewed.mean() - lo
    assert est.lo < est.value < est.hi
    mirrored = stats.aggregate([-skewed], rng, stats.Boot("mean", 100, 0.95, binary=False))
    assert (mirrored.lo, mirrored.hi) == pytest.approx((-est.hi, -est.lo), rel=1e-9)
