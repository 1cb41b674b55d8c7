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
