"""The gate's statistics (bench.board.gate.sequential): alpha spending, weighted Holm, per-cell tests, bounds; the power calculation."""

from __future__ import annotations

import numpy as np
import pytest

from bench.board.gate import power, sequential
from bench.scoring import stats as scoring

SEVEN = tuple(
    ("Lift", r, "default", "nominal", s)
    for r, s in (
        ("Panda", "seen"),
        ("Sawyer", "seen"),
        ("IIWA", "seen"),
        ("UR5e", "unseen"),
        ("Kinova3", "unseen"),
        ("Jaco", "unseen"),
        ("XArm7", "unseen"),
    )
)


def design(episodes: int = 20, batch: int = 5, cells=SEVEN, **kw) -> sequential.Design:
    return sequential.Design(schedule=tuple(sequential.looks_schedule(episodes, batch)), cells=tuple(cells), **kw)


@pytest.mark.parametrize(
    "episodes, batch, want",
    [(20, 5, [5, 10, 15, 20]), (6, 4, [4, 6]), (10, 0, [10]), (3, 5, [3])],
    ids=["even", "ragged", "single", "batch>episodes"],
)
def test_looks_schedule(episodes, batch, want):
    assert sequential.looks_schedule(episodes, batch) == want


@pytest.mark.parametrize(
    "episodes, batch, cell_alpha", [(20, 5, 0.5), (10, 5, 0.5), (5, 0, 0.5), (40, 5, 0.3), (20, 5, 0.0)]
)
def test_alpha_spent_over_tests_and_looks_sums_to_alpha(episodes, batch, cell_alpha):
    d = design(episodes, batch, cell_alpha=cell_alpha)
    assert sum(sum(t.values()) for t in d.thresholds) == pytest.approx(0.05)
    for look, t in enumerate(d.thresholds):  # a Tango test is made only where it can reach its threshold
        for h, thr in t.items():
            if h != "iqm":
                n = sequential.planned_pairs(d, look)[h]
                assert sequential.min_p(n, 0.05) < thr
    if cell_alpha == 0:
        assert not any(h.startswith("cell:") for t in d.thresholds for h in t)


def test_cells_spend_their_alpha_only_where_they_can_reject():
    d = design(20, 5)
    cells = [[h for h in t if h.startswith("cell:")] for t in d.thresholds]
    assert [len(c) for c in cells] == [0, 0, 7, 7]  # 5 or 10 pairs out of 5 or 10 lost cannot reach the threshold
    # spent in proportion to the episodes each look has seen: 15 and 20 of 35
    assert d.thresholds[2]["cell:Lift/Panda/default"] == pytest.approx(0.05 * 0.5 / 7 * 15 / 35)
    assert d.thresholds[3]["cell:Lift/Panda/default"] == pytest.approx(0.05 * 0.5 / 7 * 20 / 35)
    assert [t["pooled"] for t in d.thresholds] == pytest.approx([0.05 * 0.25 * n / 50 for n in (5, 10, 15, 20)])
    # with 5 episodes no cell test is ever possible: the aggregate tests get all of alpha
    small = design(5, 0)
    assert set(small.thresholds[0]) == {"pooled", "split:seen", "split:unseen"}
    assert sum(small.thresholds[0].values()) == pytest.approx(0.05)


def test_holm_recycles_the_alpha_of_rejected_tests():
    t = {"a": 0.01, "b": 0.01, "c": 0.01}  # Bonferroni thresholds; the look's alpha is 0.03
    out = sequential.holm({"a": 0.001, "b": 0.014, "c": 0.5}, t)
    assert out["a"] == (True, pytest.approx(0.01))
    assert out["b"] == (True, pytest.approx(0.015))  # rejected only thanks to Holm (0.014 > Bonferroni 0.01)
    assert out["c"][0] is False and out["c"][1] == pytest.approx(0.03)
    # weights: a test with a larger share is held to a larger threshold; order is by p / threshold
    out = sequential.holm({"a": 0.004, "b": 0.004}, {"a": 0.005, "b": 0.001})
    assert out["a"] == (True, pytest.approx(0.005)) and out["b"] == (True, pytest.approx(0.006))


def counts_for(rates_base, rates_cand, n, rng, rho=0.5):
    u = rng.random((len(rates_base), n))
    v = np.where(rng.random(u.shape) < rho, u, rng.random(u.shape))
    return {k: sequential.pairs_of(u[i] < rates_base[i], v[i] < rates_cand[i]) for i, k in enumerate(SEVEN)}


def test_one_cell_collapse_names_that_cell_with_its_drop_and_bounds():
    rng = np.random.default_rng(0)
    base = np.array([0.9, 0.8, 0.7, 0.6, 0.5, 0.95, 0.3])
    cand = base.copy()
    cand[0] = 0.0
    d = design(20, 5)
    counts = counts_for(base, cand, 20, rng)
    look = sequential.evaluate_look(counts, d, 3, rng, sequential.n_boot_needed(d, 2000))
    assert look["decision"] == "regression"
    assert "cell:Lift/Panda/default" in look["regressed"]
    assert not any(h.startswith("cell:") and h != "cell:Lift/Panda/default" for h in look["regressed"])
    rows = {r["robot"]: r for r in sequential.cell_rows(counts, look)}
    panda = rows["Panda"]
    assert panda["regressed"] and panda["drop_lcb"] > 0.05 and panda["drop"] == counts[SEVEN[0]].drop
    assert panda["drop_lcb"] <= panda["drop"] <= panda["drop_ucb"]


@pytest.mark.parametrize("seed", range(6))
def test_a_bound_above_the_margin_is_exactly_a_rejection(seed):
    """A test's reported lower bound exceeds the margin iff Holm rejected it (bounds agree with decisions)."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(0.3, 1.0, 7)
    cand = np.clip(base - rng.choice([0.0, 0.1, 0.4, 0.7], 7), 0, 1)
    d = design(20, 5)
    look = sequential.evaluate_look(counts_for(base, cand, 20, rng), d, 3, rng, sequential.n_boot_needed(d, 2000))
    for t in look["tests"]:
        if t["tested"]:
            assert (t["lcb"] > 0.05) == t["rejected"], t


def test_identical_outcomes_never_fail_and_pass_once_the_budget_can_certify():
    """Identical outcomes: never a regression; certified once the pooled and IQM bounds both fall below the margin."""
    rng = np.random.default_rng(0)
    outcomes = rng.random((7, 20)) < 0.7
    same = {k: sequential.pairs_of(outcomes[i], outcomes[i]) for i, k in enumerate(SEVEN)}
    d = design(20, 5)
    small = sequential.evaluate_look(
        {k: sequential.pairs_of(outcomes[i, :5], outcomes[i, :5]) for i, k in enumerate(SEVEN)}, d, 0, rng, 500
    )
    assert small["mean"]["value"] == 0 and small["decision"] == "continue" and not small["regressed"]
    # with no discordant pair the upper bound is z²/(n + z²), not 0 (a bootstrap would claim certainty)
    z = 2.2414  # certification: one-sided at 1 - 0.05 / 4 looks (the IQM is not used with 5 pairs per cell)
    assert small["mean"]["ucb"] == pytest.approx(z * z / (35 + z * z), rel=2e-3)
    full = sequential.evaluate_look(same, d, 3, rng, sequential.n_boot_needed(d, 2000))
    # 20 pairs per cell certify the pooled drop, not the IQM's: its bound counts one pseudo-pair lost and one won
    # per cell (the smoothed bootstrap), as honest as Tango's on the 5 kept cells' 100 pairs (0.059)
    assert full["mean"]["ucb"] < 0.05 < full["iqm"]["ucb"] and full["decision"] == "continue"
    d40 = design(40, 10)
    more = rng.random((7, 40)) < 0.7
    same40 = {k: sequential.pairs_of(more[i], more[i]) for i, k in enumerate(SEVEN)}
    full = sequential.evaluate_look(same40, d40, 3, rng, sequential.n_boot_needed(d40, 2000))
    assert full["decision"] == "no_regression" and max(full["mean"]["ucb"], full["iqm"]["ucb"]) < 0.05


def test_better_candidate_is_never_a_regression():
    rng = np.random.default_rng(1)
    base, cand = np.zeros((7, 20), bool), np.ones((7, 20), bool)
    d = design(20, 5)
    look = sequential.evaluate_look(
        {k: sequential.pairs_of(base[i], cand[i]) for i, k in enumerate(SEVEN)}, d, 3, rng, 2000
    )
    assert look["decision"] == "no_regression" and look["mean"]["value"] == -1 and not look["regressed"]


def test_iqm_does_not_decide_on_a_handful_of_pairs_or_cells():
    rng = np.random.default_rng(2)
    d = design(20, 5)
    lost = {k: sequential.Pairs(n10=5) for k in SEVEN}
    look = sequential.evaluate_look(lost, d, 0, rng, 2000)
    iqm = next(t for t in look["tests"] if t["id"] == "iqm")
    assert iqm["tested"] is False and look["iqm"]["used"] is False  # 5 pairs per cell < IQM_MIN_PAIRS
    assert (
        sequential.iqm_used([10] * 4) and not sequential.iqm_used([10] * 3) and not sequential.iqm_used([9] + [10] * 6)
    )


def test_false_alarm_rate_at_the_margin_is_at_most_alpha():
    """Every cell exactly `margin` worse (the least favourable case the gate must pass): alarms <= alpha."""
    rng = np.random.default_rng(4)
    cells = SEVEN[:3]
    d = design(8, 0, cells=cells)
    p_base = np.array([0.9, 0.7, 0.5])
    alarms, reps = 0, 600
    for _ in range(reps):
        u = rng.random((3, 8))
        v = np.where(rng.random((3, 8)) < 0.5, u, rng.random((3, 8)))
        counts = {k: sequential.pairs_of(u[i] < p_base[i], v[i] < p_base[i] - 0.05) for i, k in enumerate(cells)}
        alarms += sequential.evaluate_look(counts, d, 0, rng, 200, bounds=False)["decision"] == "regression"
    assert alarms / reps <= 0.05 + 0.02


@pytest.mark.parametrize("strict, want", [(False, ("inconclusive", 0)), (True, ("inconclusive", 1))])
def test_inconclusive_passes_unless_strict(strict, want):
    assert sequential.decide([{"decision": "continue"}], strict) == want
    assert sequential.decide([{"decision": "regression"}], strict) == ("regression", 1)
    assert sequential.decide([{"decision": "no_regression"}], strict) == ("no_regression", 0)


# -- scoring helpers the gate relies on ---------------------------------------------------------
def test_vectorised_tango_statistic_matches_the_scalar_bound():
    b, c = np.meshgrid(np.arange(12), np.arange(12), indexing="ij")
    ok = b + c <= 11
    z = scoring.paired_score_z(b[ok], c[ok], 11, 0.05)
    assert np.allclose(z, [scoring._tango_z(int(x), int(y), 11, 0.05) for x, y in zip(b[ok], c[ok])])
    # the bound solves z(bound) = z_level: a lower bound above the margin <=> z(margin) above z_level
    for x, y in ((9, 0), (6, 2), (3, 3)):
        lcb = scoring.paired_score_bound(x, y, 11, 0.99, "lower")
        assert (lcb > 0.05) == (scoring._tango_z(x, y, 11, 0.05) > 2.3263)


def resampled_episodes(reference, target, rng, statistic, n_boot):
    """The plain bootstrap of pairs: each resample draws episode indices within every cell and applies them to
    both sides (cell j of both holds the same episodes' outcomes)."""
    stat = scoring.STATISTICS[statistic]
    pairs = [(np.asarray(r, float), np.asarray(t, float)) for r, t in zip(reference, target)]
    point = float(stat(np.array([r.mean() for r, _ in pairs])) - stat(np.array([t.mean() for _, t in pairs])))
    ref_b, tgt_b = np.empty((n_boot, len(pairs))), np.empty((n_boot, len(pairs)))
    for j, (r, t) in enumerate(pairs):
        idx = rng.integers(0, len(r), size=(n_boot, len(r)))
        ref_b[:, j], tgt_b[:, j] = r[idx].mean(axis=1), t[idx].mean(axis=1)
    return point, stat(ref_b) - stat(tgt_b)


def test_smoothed_bayesian_bootstrap_matches_resampling_episodes_when_pairs_are_many():
    """With many discordant pairs in every cell the prior's pseudo-pairs weigh nothing: the Dirichlet draws of the
    pair types spread as the bootstrap of episodes does."""
    rng = np.random.default_rng(5)
    base = rng.random((5, 300)) < 0.7
    cand = rng.random((5, 300)) < 0.5
    counts = np.array([sequential.pairs_of(b, c).as_row() for b, c in zip(base, cand)])
    p1, s1 = resampled_episodes(base, cand, rng, "iqm", 20000)
    p2, s2 = scoring.paired_binary_stat_samples(counts, rng, "iqm", 20000)
    assert p1 == pytest.approx(p2)
    assert np.quantile(s1, [0.05, 0.5, 0.95]) == pytest.approx(np.quantile(s2, [0.05, 0.5, 0.95]), abs=0.006)
    assert s1.std() == pytest.approx(s2.std(), rel=0.05)


def test_smoothed_bayesian_bootstrap_spreads_where_no_pair_disagrees_and_keeps_the_estimate():
    """The plain bootstrap has no spread in a cell without a discordant pair (its bound sat on the estimate, the
    coverage failure near rates 0 and 1); the pseudo-pairs give one, and the recentring moves no estimate."""
    rng = np.random.default_rng(6)
    counts = np.array([[0, 0, 0, 10]] * 3 + [[0, 2, 0, 8]])  # rate 0 everywhere but one cell's 2 lost pairs
    point, samples = scoring.paired_binary_stat_samples(counts, rng, "mean", 40000)
    assert point == pytest.approx(0.05)
    assert samples.mean() == pytest.approx(point, abs=0.002)  # recentred: no shrinkage toward 0
    assert np.quantile(samples, 0.95) > 0.1 and np.quantile(samples, 0.05) < 0.0
    baseline = np.arange(10) < counts[:, 1:2]  # the same outcomes as episodes: cell j's first n10 pairs lost
    _, plain = resampled_episodes(baseline, np.zeros((4, 10)), rng, "mean", 4000)
    assert np.quantile(plain, 0.95) < np.quantile(samples, 0.95)
    with pytest.raises(ValueError, match="at least one pair"):
        scoring.paired_binary_stat_samples(np.array([[0, 0, 0, 0]]), rng)


# -- the power calculation (plan=true) ----------------------------------------------------------
def test_exact_power_of_one_look_matches_enumerating_the_trinomial():
    from scipy.stats import multinomial, norm

    n, p10, p01, thr = 9, 0.5, 0.1, 0.01
    want = 0.0
    for b in range(n + 1):
        for c in range(n + 1 - b):
            if norm.sf(scoring._tango_z(b, c, n, 0.05)) < thr:
                want += multinomial.pmf([b, c, n - b - c], n, [p10, p01, 1 - p10 - p01])
    assert power.sequential_power([n], [thr], p10, p01, 0.05) == pytest.approx(want, rel=1e-9)


def test_exact_sequential_power_matches_monte_carlo():
    rng = np.random.default_rng(6)
    pairs, thr, p10, p01 = [5, 10, 15, 20], [0.0, 0.004, 0.004, 0.004], 0.55, 0.05
    exact = power.sequential_power(pairs, thr, p10, p01, 0.05)
    from scipy.stats import norm

    draws = rng.choice(3, p=[p10, p01, 1 - p10 - p01], size=(20000, 20))
    hit = np.zeros(20000, bool)
    for n, t in zip(pairs, thr):
        if t > 0:
            b, c = (draws[:, :n] == 0).sum(1), (draws[:, :n] == 1).sum(1)
            hit |= norm.sf(scoring.paired_score_z(b, c, n, 0.05)) < t
    assert exact == pytest.approx(hit.mean(), abs=0.015)


def test_episodes_needed_is_the_smallest_budget_reaching_the_power():
    d = sequential.Design()
    need, got = power.episodes_needed("cell", power.Budget(0.8, 0.9, 0.6, 7, 5, d, 0))
    assert need is not None and need % 5 == 0 and got >= 0.8
    assert power.scenario_power("cell", need - 5, power.Budget(0.8, 0.9, 0.6, 7, 5, d, 0)) < 0.8
    never, _ = power.episodes_needed("cell", power.Budget(0.99, 0.2, 0.06, 7, 5, d, 0))
    assert never is None  # a 1-point excess over the margin in one of 7 cells: no CI budget finds it
