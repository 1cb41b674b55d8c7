"""Boschloo's and Barnard's unconditional exact tests (`bench.scoring.exact`) against scipy's, to 1e-6."""

from __future__ import annotations

import pytest

from bench.scoring import exact

SIZES = [(1, 1), (3, 5), (6, 4), (8, 8), (10, 7)]


@pytest.mark.parametrize("n1,n2", SIZES, ids=[f"{a}v{b}" for a, b in SIZES])
@pytest.mark.parametrize("alternative", exact.ALTERNATIVES)
def test_matches_scipy_on_every_table(n1, n2, alternative):
    from scipy.stats import barnard_exact, boschloo_exact

    for x1 in range(n1 + 1):
        for x2 in range(n2 + 1):
            table = [[x1, x2], [n1 - x1, n2 - x2]]
            assert exact.barnard(x1, n1, x2, n2, alternative) == pytest.approx(
                barnard_exact(table, alternative).pvalue, abs=1e-6
            ), (x1, n1, x2, n2)
            assert exact.boschloo(x1, n1, x2, n2, alternative) == pytest.approx(
                boschloo_exact(table, alternative).pvalue, abs=1e-6
            ), (x1, n1, x2, n2)


def test_boschloo_is_never_above_fisher_one_sided():
    for x1 in range(11):
        for x2 in range(11):
            assert exact.boschloo(x1, 10, x2, 10, "greater") <= exact.fisher(x1, 10, x2, 10, "greater") + 1e-9


def test_bad_counts_and_sides_are_refused():
    with pytest.raises(ValueError, match="each batch needs"):
        exact.boschloo(3, 2, 0, 1)
    with pytest.raises(ValueError, match="alternative='two'"):
        exact.barnard(1, 2, 0, 1, "two")


# --- Chan's exact unconditional test of a difference against a margin (`exact.chan`) -----------------------------


@pytest.mark.parametrize(
    "x1,n1,x2,n2,margin",
    [
        (7, 10, 3, 12, 0.1),
        (0, 5, 5, 5, 0.2),
        (10, 10, 0, 8, 0.3),
        (4, 9, 6, 9, 0.05),
        (2, 9, 8, 9, -0.7),
        (7, 10, 3, 12, -0.1),
    ],
)
def test_restricted_rates_maximise_the_likelihood_on_the_boundary(x1, n1, x2, n2, margin):
    from scipy.optimize import minimize_scalar
    from scipy.special import xlog1py, xlogy

    def nll(p2):
        p1 = p2 + margin
        return -(xlogy(x1, p1) + xlog1py(n1 - x1, -p1) + xlogy(x2, p2) + xlog1py(n2 - x2, -p2))

    best = minimize_scalar(
        nll, bounds=(max(0.0, -margin), min(1.0, 1.0 - margin)), method="bounded", options={"xatol": 1e-12}
    ).x
    r1, r2 = exact.restricted_rates(x1, n1, x2, n2, margin)
    assert float(r2) == pytest.approx(best, abs=1e-6)
    assert float(r1) - float(r2) == pytest.approx(margin, abs=1e-12)


@pytest.mark.parametrize("n1,n2", SIZES, ids=[f"{a}v{b}" for a, b in SIZES])
@pytest.mark.parametrize("alternative", ["less", "greater"])
def test_chan_at_margin_zero_is_scipys_pooled_barnard(n1, n2, alternative):
    """Equal to scipy's one-sided pooled Barnard test, except where another table's statistic ties the observed one
    mathematically but not in floating point: scipy then leaves the tied table out by round-off, `chan` counts it
    (its p-value is then the larger, never the smaller)."""
    import numpy as np
    from scipy.stats import barnard_exact

    z = exact.margin_z(np.arange(n1 + 1)[:, None], n1, np.arange(n2 + 1)[None, :], n2, 0.0)
    compared = 0
    for x1 in range(n1 + 1):
        for x2 in range(n2 + 1):
            table = [[x1, x2], [n1 - x1, n2 - x2]]
            want = barnard_exact(table, alternative, pooled=True).pvalue
            got = exact.chan(x1, n1, x2, n2, 0.0, alternative)
            gap = np.abs(z - z[x1, x2])
            if np.any((gap > 0) & (gap < 1e-9)):
                assert got >= want - 1e-6, (x1, n1, x2, n2)
            else:
                assert got == pytest.approx(want, abs=1e-6), (x1, n1, x2, n2)
                compared += 1
    assert compared >= (n1 + 1) * (n2 + 1) // 2


@pytest.mark.parametrize("n1,n2,margin", [(10, 10, 0.1), (8, 12, 0.2), (12, 6, 0.05)])
@pytest.mark.parametrize("alternative", ["less", "greater"])
def test_chan_size_on_the_boundary_is_at_most_alpha(n1, n2, margin, alternative):
    """Exact size: the probability of the rejection region {p <= alpha}, enumerated at 201 boundary points."""
    import numpy as np

    alpha = 0.05
    p = np.array([[exact.chan(x1, n1, x2, n2, margin, alternative) for x2 in range(n2 + 1)] for x1 in range(n1 + 1)])
    y1, y2 = np.nonzero(p <= alpha)
    assert y1.size > 0  # the test can reject at all: the size check is not vacuous
    pis = np.linspace(0.0, 1.0 - margin, 201)
    size = exact.boundary_probability(y1, y2, n1, n2, margin, pis)
    assert size.max() <= alpha + 1e-9, (float(size.max()), float(pis[size.argmax()]))
    assert size.max() > alpha / 4  # and not absurdly conservative


def test_chan_p_grows_with_the_margin_it_must_exceed():
    ps = [exact.chan(18, 20, 9, 20, m, "greater") for m in (0.0, 0.1, 0.2, 0.3, 0.4)]
    assert ps == sorted(ps) and ps[0] < 0.01 < ps[-1]
    qs = [exact.chan(15, 20, 14, 20, m, "less") for m in (0.0, 0.1, 0.2, 0.3, 0.4)]
    assert qs == sorted(qs, reverse=True) and qs[-1] < 0.05 < qs[0]


def test_chan_refuses_bad_margin_and_side():
    with pytest.raises(ValueError, match="margin=1.0"):
        exact.chan(1, 2, 0, 1, 1.0)
    with pytest.raises(ValueError, match="valid: less, greater"):
        exact.chan(1, 2, 0, 1, 0.1, "two-sided")
