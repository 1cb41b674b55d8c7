"""Trends across runs: a weighted least-squares slope with an interval from a paired bootstrap.

Used by experiments that train several policies on nested training sets and evaluate them on
the same cells with the same episode seeds (e.g. the coverage sweep, `baselines/coverage_sweep.py`):
`SeriesBootstrap` draws replicates that resample episodes jointly across points (common random
numbers) and training seeds per point; `slope_with_interval` refits the slope on every replicate.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np


def wls_slope(
    x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray, var: Sequence[float] | np.ndarray
) -> tuple[float, float]:
    """Weighted least-squares line y = a + b x with weights 1/var; returns (slope b, intercept a)."""
    xa, ya, w = np.asarray(x, float), np.asarray(y, float), 1.0 / np.asarray(var, float)
    if len(xa) < 2 or np.ptp(xa) == 0:
        raise ValueError("a slope needs at least two distinct x values")
    xm, ym = np.sum(w * xa) / w.sum(), np.sum(w * ya) / w.sum()
    b = np.sum(w * (xa - xm) * (ya - ym)) / np.sum(w * (xa - xm) ** 2)
    return float(b), float(ym - b * xm)


class SeriesBootstrap:
    """Bootstrap replicates for models evaluated on the same cells with the same episode seeds.

    A point is one training set; it has one outcome dict per training seed (cell key -> 0/1
    outcomes by episode index). A replicate resamples (a) episode indices within each cell,
    jointly for every point and seed, since they share initial states (common random numbers
    cancel in differences and slopes), and (b) the training seeds of each point independently,
    so every interval also carries the seed-to-seed spread of training, which for closed-loop
    behaviour cloning is as large as the evaluation noise. Missing outcomes (errored episodes)
    are NaN and skipped. With one seed per point (b) is a no-op.
    """

    def __init__(
        self,
        points: Sequence[Sequence[dict[str, np.ndarray]]],
        rng: np.random.Generator,
        n_boot: int = 2000,
        confidence: float = 0.95,
    ):
        self.points = [[{k: np.asarray(v, float) for k, v in seed.items()} for seed in pt] for pt in points]
        if not self.points or any(len(pt) == 0 for pt in self.points):
            raise ValueError("every point needs at least one seed's outcomes")
        n_by_cell: dict[str, int] = {}
        for pt in self.points:
            for seed in pt:
                for k, v in seed.items():
                    n_by_cell[k] = max(n_by_cell.get(k, 0), len(v))
        self.n_boot, self.confidence = int(n_boot), float(confidence)
        self.ep_idx = {k: rng.integers(0, n, (n_boot, n)) for k, n in sorted(n_by_cell.items()) if n}
        self.seed_idx = [rng.integers(0, len(pt), (n_boot, len(pt))) for pt in self.points]
        self.n_by_cell = n_by_cell

    def _padded(self, outcomes: np.ndarray, key: str) -> np.ndarray:
        x = np.full(self.n_by_cell[key], np.nan)
        x[: len(outcomes)] = outcomes
        return x

    def mean(self, k: int, keys: Sequence[str]) -> tuple[float | None, np.ndarray | None]:
        """Point value and replicates of the mean over seeds of the mean over `keys` of point k's cell rates."""
        seeds = self.points[k]
        keys = [key for key in keys if all(len(s.get(key, ())) for s in seeds)]
        if not keys:
            return None, None
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            point = float(np.mean([np.mean([np.nanmean(s[key]) for key in keys]) for s in seeds]))
            per_seed = np.stack(
                [
                    np.nanmean(
                        [np.nanmean(self._padded(s[key], key)[self.ep_idx[key]], axis=1) for key in keys], axis=0
                    )
                    for s in seeds
                ]
            )  # (S, n_boot)
        reps = per_seed[self.seed_idx[k], np.arange(self.n_boot)[:, None]].mean(axis=1)
        return point, reps

    def interval(self, reps: np.ndarray) -> list[float]:
        a = (1 - self.confidence) / 2
        lo, hi = np.nanquantile(reps, [a, 1 - a])
        return [round(float(lo), 6), round(float(hi), 6)]

    def estimate(self, point: float | None, reps: np.ndarray | None, reason: str = "no completed episodes") -> dict:
        """{"value", "ci"} (or value None with a reason): the JSON form of `bench.scoring.stats.Estimate`."""
        if point is None or reps is None:
            return {"value": None, "ci": None, "reason": reason}
        return {"value": round(point, 6), "ci": self.interval(reps)}


def _smoothed_var(p: float, n: int) -> float:
    """Binomial variance of a rate from n outcomes, Laplace-smoothed so it is never 0."""
    q = (p * n + 1) / (n + 2)
    return q * (1 - q) / max(n, 1)


def slope_with_interval(
    x: Sequence[float],
    values: Sequence[float],
    reps: Sequence[np.ndarray],
    n_outcomes: Sequence[int],
    confidence: float = 0.95,
) -> dict[str, object]:
    """WLS slope of `values` against `x` with a percentile interval from bootstrap replicates.

    Weights are 1/variance per point: the replicates' variance, floored by the smoothed binomial
    variance of its `n_outcomes` so that a point at 0% or 100% cannot take all the weight. The
    weights stay fixed; the slope is refitted on every replicate (rows of `reps` line up across
    points because the replicates were drawn together, see `SeriesBootstrap`).
    """
    x = [float(v) for v in x]
    if len(x) < 2 or len(set(x)) < 2:
        return {"value": None, "ci": None, "reason": "a slope needs at least two points with distinct coverage"}
    if any(v is None for v in values) or any(r is None for r in reps):
        return {"value": None, "ci": None, "reason": "a point has no completed episodes"}
    rep_mat = np.stack([np.asarray(r, float) for r in reps], axis=1)  # (n_boot, K)
    var = [max(float(np.nanvar(rep_mat[:, k])), _smoothed_var(values[k], n_outcomes[k])) for k in range(len(x))]
    b, a = wls_slope(x, values, var)
    boot = np.array([wls_slope(x, row, var)[0] for row in rep_mat if np.all(np.isfinite(row))])
    lo, hi = np.quantile(boot, [(1 - confidence) / 2, 1 - (1 - confidence) / 2])
    return {
        "value": round(b, 6),
        "ci": [round(float(lo), 6), round(float(hi), 6)],
        "intercept": round(a, 6),
        "method": "weighted least squares (1/var), percentile bootstrap over training seeds and episodes",
        "points": [{"x": xx, "y": round(yy, 6), "var": round(vv, 8)} for xx, yy, vv in zip(x, values, var)],
    }
