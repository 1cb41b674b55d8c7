"""Exact tests of two unpaired batches of 0/1 outcomes: Boschloo's and Barnard's unconditional tests, Fisher's.

Two batches are unpaired when their episodes did not start from the same states (other seeds, other
cells): McNemar's test and Tango's interval, which need pairs, do not apply. Fisher's exact test
conditions on the total successes, which makes it conservative; an *unconditional* exact test instead
takes the largest p-value over the unknown common success rate pi under H0 (p1 = p2 = pi):

    p = max over pi in [0, 1] of  sum over tables (y1, y2) at least as extreme as the observed one of
        Bin(y1; n1, pi) * Bin(y2; n2, pi)

Barnard (1945) orders tables by the pooled-variance Wald (score) statistic; Boschloo (1970) by Fisher's
one-sided p-value, which makes it uniformly more powerful than Fisher's test at the same level (Lydersen,
Fagerland & Laake 2009 recommend it). Both are what `scipy.stats.barnard_exact(pooled=True)` and
`scipy.stats.boschloo_exact` compute (`tests/test_exact.py` checks them to 1e-6 on a grid of small
tables); here the maximum over pi is a dense grid refined by bounded Brent steps around the best points
rather than scipy's 32-point `shgo`, and the functions take counts (successes and episodes per batch).
scipy's take 0.02-0.4 s per table at 10-200 episodes a batch, which is fast enough for one report; these
are comparable and need no table assembly.

Sides: "greater" asks whether batch 1 succeeds more often than batch 2, "less" the reverse;
"two-sided" is Barnard's |Wald| ordering, and for Boschloo twice the smaller one-sided p-value (scipy's
definition).
"""

from __future__ import annotations

import math

import numpy as np

GRID = 96  # nuisance rates tried before refinement (the p-value is a smooth polynomial in pi)
ALTERNATIVES = ("two-sided", "greater", "less")


def _log_comb(n: int) -> np.ndarray:
    from scipy.special import gammaln  # scipy: loaded only when an exact test is computed

    k = np.arange(n + 1)
    return gammaln(n + 1) - gammaln(k + 1) - gammaln(n - k + 1)


def _max_over_nuisance(y1: np.ndarray, y2: np.ndarray, n1: int, n2: int, extreme: np.ndarray) -> float:
    """max over pi of P_pi(the table is in `extreme`), y1/y2 the (broadcast) success counts of the tables."""
    from scipy.optimize import minimize_scalar  # scipy: loaded only when an exact test is computed

    if not extreme.any():
        return 0.0
    s = (y1 + y2)[extreme].astype(float)
    logc = (_log_comb(n1)[y1] + _log_comb(n2)[y2])[extreme]
    n = n1 + n2

    def logp(pi: float) -> float:
        if pi <= 0.0 or pi >= 1.0:  # the table with 0 (n) successes has probability 1
            edge = 0 if pi <= 0.0 else n
            return 0.0 if np.any(s == edge) else -np.inf
        t = logc + s * math.log(pi) + (n - s) * math.log1p(-pi)
        m = float(t.max())
        return m + math.log(float(np.exp(t - m).sum()))

    grid = np.linspace(0.0, 1.0, GRID + 1)
    inner = grid[1:-1]
    t = logc[:, None] + s[:, None] * np.log(inner) + (n - s)[:, None] * np.log1p(-inner)
    m = t.max(axis=0)
    vals = np.concatenate([[logp(0.0)], m + np.log(np.exp(t - m).sum(axis=0)), [logp(1.0)]])
    best = float(vals.max())
    for i in np.argsort(vals)[::-1][:4]:  # refine around the four best grid points
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, GRID)]
        r = minimize_scalar(lambda p: -logp(p), bounds=(lo, hi), method="bounded", options={"xatol": 1e-12})
        best = max(best, -float(r.fun))
    return float(min(math.exp(best), 1.0))


def _check(x1: int, n1: int, x2: int, n2: int, alternative: str) -> None:
    if alternative not in ALTERNATIVES:
        raise ValueError(f"alternative={alternative!r}; valid: {', '.join(ALTERNATIVES)}")
    if n1 < 1 or n2 < 1 or not (0 <= x1 <= n1 and 0 <= x2 <= n2):
        raise ValueError(f"counts {x1}/{n1}, {x2}/{n2}: each batch needs >= 1 episode and 0 <= successes <= episodes")


def barnard(x1: int, n1: int, x2: int, n2: int, alternative: str = "two-sided") -> float:
    """Barnard's unconditional exact test of p1 = p2 (pooled-variance Wald ordering): its p-value.

    Args:
        x1, n1: successes and episodes of batch 1; x2, n2: of batch 2.
        alternative: "greater" (p1 > p2), "less" (p1 < p2) or "two-sided".
    """
    _check(x1, n1, x2, n2, alternative)
    y1 = np.arange(n1 + 1).reshape(-1, 1)
    y2 = np.arange(n2 + 1).reshape(1, -1)
    p1, p2 = y1 / n1, y2 / n2
    pooled = (y1 + y2) / (n1 + n2)
    var = pooled * (1 - pooled) * (1 / n1 + 1 / n2)
    with np.errstate(divide="ignore", invalid="ignore"):
        wald = np.divide(p1 - p2, np.sqrt(var))
    wald[np.broadcast_to(p1 == p2, wald.shape)] = 0.0
    obs = wald[x1, x2]
    extreme = {
        "two-sided": np.abs(wald) >= abs(obs),
        "greater": wald >= obs,
        "less": wald <= obs,
    }[alternative]
    return _max_over_nuisance(np.broadcast_to(y1, wald.shape), np.broadcast_to(y2, wald.shape), n1, n2, extreme)


def fisher(x1: int, n1: int, x2: int, n2: int, alternative: str = "two-sided") -> float:
    """Fisher's exact test of p1 = p2 (conditional on the total successes): its p-value (scipy's)."""
    from scipy.stats import fisher_exact  # scipy: loaded only when an exact test is computed

    _check(x1, n1, x2, n2, alternative)
    return float(fisher_exact([[x1, x2], [n1 - x1, n2 - x2]], alternative=alternative).pvalue)


def boschloo(x1: int, n1: int, x2: int, n2: int, alternative: str = "two-sided") -> float:
    """Boschloo's unconditional exact test of p1 = p2 (tables ordered by Fisher's one-sided p-value): its p-value.

    Args as `barnard`; "two-sided" is twice the smaller one-sided p-value, capped at 1.
    """
    from scipy.stats import hypergeom  # scipy: loaded only when an exact test is computed

    _check(x1, n1, x2, n2, alternative)
    if alternative == "two-sided":
        return min(1.0, 2.0 * min(boschloo(x1, n1, x2, n2, "greater"), boschloo(x1, n1, x2, n2, "less")))
    y1 = np.arange(n1 + 1).reshape(-1, 1)
    y2 = np.arange(n2 + 1).reshape(1, -1)
    total = y1 + y2
    if alternative == "greater":  # Fisher's p for p1 > p2: P(Y2 <= y2 | total), batch 2 as the drawn column
        fisher_p = hypergeom.cdf(y2, n1 + n2, total, n2)
    else:
        fisher_p = hypergeom.cdf(y1, n1 + n2, total, n1)
    extreme = fisher_p <= fisher_p[x1, x2] * (1 + 1e-13)  # scipy's guard against round-off ties
    return _max_over_nuisance(np.broadcast_to(y1, total.shape), np.broadcast_to(y2, total.shape), n1, n2, extreme)
