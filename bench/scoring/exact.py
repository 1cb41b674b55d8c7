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

`chan` tests the difference p1 - p2 against a margin (non-inferiority, or a drop beyond the margin) with the
same unconditional construction on the boundary p1 = p2 + margin (Chan 1998; below); `bench regress
paired=false` uses it per cell (`bench.board.gate.unpaired`).
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


# --- a margin on the difference: Chan's (1998) exact unconditional test (Röhmel & Mansmann 1999) ---------------
#
# H0: p1 - p2 >= margin vs H1: p1 - p2 < margin ("less": batch 2 is non-inferior to batch 1 within `margin`), or
# H0: p1 - p2 <= margin vs H1: p1 - p2 > margin ("greater": batch 2 is worse than batch 1 by more than `margin`).
# Tables are ordered by Farrington & Manning's (1990) score statistic
#     Z = (p1^ - p2^ - margin) / sqrt(p1~ (1 - p1~) / n1 + p2~ (1 - p2~) / n2)
# with (p1~, p2~) the maximum-likelihood rates restricted to p1 - p2 = margin (closed form, Miettinen & Nurminen
# 1985's cubic); the p-value is the largest probability of the tables at least as extreme over the nuisance rate on
# the boundary p2 = pi, p1 = pi + margin, pi in [0, 1 - margin] (a grid of GRID + 1 points refined by bounded Brent
# steps around the four best, as `barnard`). With margin 0 the restricted rates are the pooled rate and this is
# Barnard's pooled-variance test (`barnard`, scipy's `barnard_exact(pooled=True)`). No Berger-Boos restriction.


def restricted_rates(x1, n1: int, x2, n2: int, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Maximum-likelihood (p1, p2) of two binomial batches under p1 - p2 = margin in (-1, 1) (Farrington-Manning).

    `x1`, `x2` may be arrays (broadcast); returns arrays of their broadcast shape.
    """
    p1 = np.asarray(x1, dtype=float) / n1
    p2 = np.asarray(x2, dtype=float) / n2
    d, theta = float(margin), n2 / n1
    a = 1.0 + theta
    b = -(1.0 + theta + p1 + theta * p2 + d * (theta + 2.0))
    c = d * d + d * (2.0 * p1 + theta + 1.0) + p1 + theta * p2
    e = -p1 * d * (1.0 + d)
    v = b**3 / (3.0 * a) ** 3 - b * c / (6.0 * a * a) + e / (2.0 * a)
    u = np.sign(v) * np.sqrt(np.maximum(b * b / (3.0 * a) ** 2 - c / (3.0 * a), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(u == 0.0, 0.0, v / u**3)
    w = (math.pi + np.arccos(np.clip(ratio, -1.0, 1.0))) / 3.0
    r1 = np.clip(2.0 * u * np.cos(w) - b / (3.0 * a), max(d, 0.0), min(1.0, 1.0 + d))
    return r1, r1 - d


def margin_z(x1, n1: int, x2, n2: int, margin: float) -> np.ndarray:
    """Farrington-Manning score statistic of p1 - p2 against `margin` (0 where the numerator is 0)."""
    p1 = np.asarray(x1, dtype=float) / n1
    p2 = np.asarray(x2, dtype=float) / n2
    r1, r2 = restricted_rates(x1, n1, x2, n2, margin)
    num = p1 - p2 - margin
    var = r1 * (1.0 - r1) / n1 + r2 * (1.0 - r2) / n2
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.divide(num, np.sqrt(var))
    return np.where(np.abs(num) < 1e-12, 0.0, z)


def boundary_probability(y1: np.ndarray, y2: np.ndarray, n1: int, n2: int, margin: float, pi) -> np.ndarray:
    """P(tables (y1, y2)) summed, at the boundary rates p2 = pi, p1 = pi + margin (pi a scalar or an array)."""
    from scipy.special import logsumexp, xlog1py, xlogy  # scipy: loaded only when an exact test is computed

    pi = np.atleast_1d(np.asarray(pi, dtype=float))[None, :]
    logc = (_log_comb(n1)[y1] + _log_comb(n2)[y2])[:, None]
    y1, y2 = y1[:, None].astype(float), y2[:, None].astype(float)
    q = np.minimum(pi + margin, 1.0)
    t = logc + xlogy(y1, q) + xlog1py(n1 - y1, -q) + xlogy(y2, pi) + xlog1py(n2 - y2, -pi)
    return np.exp(logsumexp(t, axis=0))


def _max_on_boundary(y1: np.ndarray, y2: np.ndarray, n1: int, n2: int, margin: float) -> float:
    from scipy.optimize import minimize_scalar  # scipy: loaded only when an exact test is computed

    if y1.size == 0:
        return 0.0
    top = 1.0 - margin
    grid = np.linspace(0.0, top, GRID + 1)
    vals = boundary_probability(y1, y2, n1, n2, margin, grid)
    best = float(vals.max())
    for i in np.argsort(vals)[::-1][:4]:  # refine around the four best grid points
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, GRID)]
        r = minimize_scalar(
            lambda p: -float(boundary_probability(y1, y2, n1, n2, margin, p)[0]),
            bounds=(lo, hi),
            method="bounded",
            options={"xatol": 1e-12},
        )
        best = max(best, -float(r.fun))
    return float(min(best, 1.0))


def chan(x1: int, n1: int, x2: int, n2: int, margin: float = 0.0, alternative: str = "less") -> float:
    """Chan's exact unconditional test of the difference p1 - p2 against `margin`: its p-value.

    Args:
        x1, n1: successes and episodes of batch 1 (the baseline); x2, n2: of batch 2 (the candidate).
        margin: the tolerated difference p1 - p2, in [0, 1).
        alternative: "less" (H1: p1 - p2 < margin: batch 2 is non-inferior) or "greater"
            (H1: p1 - p2 > margin: batch 2 is worse by more than the margin).
    """
    if alternative not in ("less", "greater"):
        raise ValueError(f"alternative={alternative!r}; valid: less, greater")
    if not 0.0 <= margin < 1.0:
        raise ValueError(f"margin={margin}: must be in [0, 1)")
    _check(x1, n1, x2, n2, alternative)
    y1 = np.arange(n1 + 1).reshape(-1, 1)
    y2 = np.arange(n2 + 1).reshape(1, -1)
    z = margin_z(y1, n1, y2, n2, margin)
    obs = z[x1, x2]
    tol = 1e-10 * max(1.0, abs(float(obs))) if np.isfinite(obs) else 0.0  # round-off ties count as extreme
    extreme = z <= obs + tol if alternative == "less" else z >= obs - tol
    yy1, yy2 = np.nonzero(extreme)
    return _max_on_boundary(yy1, yy2, n1, n2, margin)
