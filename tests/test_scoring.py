"""Scoring math against values computed by hand."""

import math

import numpy as np
import pytest

from bench.scoring import stats as scoring


def test_wilson_matches_hand_computation():
    # p = 0.7, n = 10, z = 1.959964: denom = 1 + z^2/n = 1.384146;
    # centre = (p + z^2/2n)/denom = 0.644492; half = z*sqrt(p(1-p)/n + z^2/4n^2)/denom = 0.247715
    est = scoring.wilson(7, 10)
    assert est.value == pytest.approx(0.7)
    assert est.lo == pytest.approx(0.644492 - 0.247715, abs=1e-5)
    assert est.hi == pytest.approx(0.644492 + 0.247715, abs=1e-5)


@pytest.mark.parametrize("confidence", [0.8, 0.9, 0.95, 0.99, 0.999])
def test_wilson_is_scipys_to_the_last_bit_away_from_the_edge_counts(confidence):
    """`wilson` computes scipy's Wilson interval without importing scipy.stats: the same floats, every k <= n <= 60,
    except the bound Brown, Cai & DasGupta replace for 1..x* successes (failures; x* = 2 up to 50 trials, 3 above):
    the Poisson one, always lower."""
    from scipy.stats import binomtest, chi2

    for n in range(1, 61):
        edge = 2 if n <= 50 else 3
        for k in range(n + 1):
            ci = binomtest(k, n).proportion_ci(confidence_level=confidence, method="wilson")
            est = scoring.wilson(k, n, confidence)
            low = chi2.ppf(1 - confidence, 2 * k) / 2 / n if 1 <= k <= edge else float(ci.low)
            high = 1 - chi2.ppf(1 - confidence, 2 * (n - k)) / 2 / n if 1 <= n - k <= edge else float(ci.high)
            assert est.lo == pytest.approx(min(low, float(ci.low)), abs=1e-12), (k, n)
            assert est.hi == pytest.approx(max(high, float(ci.high)), abs=1e-12), (k, n)
            if not (1 <= k <= edge or 1 <= n - k <= edge):
                assert (est.lo, est.hi) == (float(ci.low), float(ci.high)), (k, n)


def test_iqm_is_scipys_trim_mean_to_the_last_bit():
    from scipy.stats import trim_mean

    rng = np.random.default_rng(0)
    for shape in [(1,), (3,), (4,), (7,), (12,), (5, 9), (200, 13), (3, 4, 17)]:
        for values in (
            rng.normal(size=shape),
            rng.integers(0, 2, size=shape),
            rng.uniform(size=shape).astype(np.float32),
        ):
            for axis in range(-1, -values.ndim - 1, -1):
                ours, theirs = scoring.iqm(values, axis=axis), trim_mean(values, 0.25, axis=axis)
                assert ours.dtype == theirs.dtype and np.array_equal(ours, theirs), (shape, values.dtype, axis)


def test_wilson_extremes_and_empty():
    zero = scoring.wilson(0, 10)  # lower bound exactly 0, upper z^2/(n+z^2) = 3.8415/13.8415 = 0.27753
    assert zero.lo == pytest.approx(0.0, abs=1e-12) and zero.hi == pytest.approx(0.27753, abs=1e-4)
    empty = scoring.wilson(0, 0)
    assert empty.value is None and empty.to_dict() == {"value": None, "ci": None, "reason": "no completed episodes"}


def test_aggregate_and_gap_points():
    rng = np.random.default_rng(0)
    seen = [np.array([1, 1, 1, 0]), np.array([1, 0])]  # cell rates 0.75, 0.5 -> mean 0.625
    unseen = [np.array([0, 0]), np.array([1, 0, 0, 0])]  # cell rates 0.0, 0.25 -> mean 0.125
    agg = scoring.aggregate(seen, rng)
    assert agg.value == pytest.approx(0.625)
    assert 0.0 <= agg.lo <= 0.625 <= agg.hi <= 1.0
    g = scoring.gap(seen, unseen, rng)
    assert g.value == pytest.approx(0.5)
    assert g.lo < 0.5 < g.hi


def test_iqm_by_hand():
    # 8 values sorted: 0 .1 .2 .3 .4 .5 .6 1.0 -> drop 2 from each end -> mean(.2,.3,.4,.5) = .35
    x = np.array([0.5, 0.1, 1.0, 0.3, 0.0, 0.6, 0.2, 0.4])
    assert float(scoring.iqm(x)) == pytest.approx(0.35)


def test_all_success_cells_keep_their_uncertainty():
    rng = np.random.default_rng(1)
    est = scoring.aggregate([np.ones(10), np.ones(10)], rng)
    # 10/10 twice: point 1.0; the lower bound is Wilson's for 20/20 (0.8389), not 1
    assert est.value == 1.0 and est.hi == 1.0
    assert est.lo == pytest.approx(scoring.wilson(20, 20).lo)
    more = scoring.aggregate([np.ones(200), np.ones(200)], rng)
    assert more.lo > est.lo  # more episodes, tighter interval


def test_paired_gap_by_hand():
    rng = np.random.default_rng(2)
    ref = np.array([1, 1, 0, 1])
    tgt = np.array([0, 1, 0, 0])  # differences 1, 0, 0, 1 -> 0.5
    est = scoring.paired_gap(ref, tgt, rng)
    assert est.value == pytest.approx(0.5)
    # 0/1 outcomes: Tango's two-sided score interval (2 discordant pairs of 4 do not exclude 0)
    assert (est.lo, est.hi) == (
        pytest.approx(scoring.paired_score_bound(2, 0, 4, 0.975, "lower")),
        pytest.approx(scoring.paired_score_bound(2, 0, 4, 0.975, "upper")),
    )
    assert est.lo < 0.0 < 0.5 < est.hi < 1.0
    same = scoring.paired_gap(np.ones(6), np.zeros(6), rng)
    assert same.value == 1.0 and same.hi == 1.0 and 0.2 < same.lo < 0.5  # 6 of 6 is not proof of 1
    returns = scoring.paired_gap(np.array([2.0, 1.5, 0.5]), np.array([1.0, 1.5, 0.0]), rng)  # not 0/1: bootstrap
    assert returns.value == pytest.approx(0.5) and 0.0 <= returns.lo <= 0.5 <= returns.hi <= 1.0
    with pytest.raises(ValueError, match="differ in shape"):
        scoring.paired_gap(np.ones(3), np.ones(4), rng)


def test_bootstrap_interval_covers_truth_about_95_percent():
    rng = np.random.default_rng(3)
    hits = 0
    reps = 200
    for _ in range(reps):
        cells = [rng.binomial(1, 0.5, size=40) for _ in range(4)]
        est = scoring.aggregate(cells, rng, scoring.Boot(n_boot=500))
        hits += est.lo <= 0.5 <= est.hi
    assert 0.88 <= hits / reps <= 0.995


def test_no_nan_anywhere():
    rng = np.random.default_rng(4)
    for est in (scoring.aggregate([], rng), scoring.gap([np.ones(2)], [], rng), scoring.paired_gap([], [], rng)):
        d = est.to_dict()
        assert d["value"] is None and d["reason"]
        assert not any(isinstance(v, float) and math.isnan(v) for v in d.values())
