"""Scores with intervals: success rates, aggregates across cells, transfer gaps.

Conventions:
- A per-cell rate carries a Wilson score interval (`scipy.stats.binomtest(...).proportion_ci`).
- Aggregates over cells (mean, IQM) and gaps between groups of cells carry a
  stratified bootstrap interval (strata = cells): each cell's rate is redrawn from its
  Jeffreys posterior (the Bayesian bootstrap of its 0/1 outcomes), so an all-success
  cell still carries its uncertainty instead of a [1, 1] interval.
- Paired gaps (same episode seeds under two conditions) resample episode indices
  jointly, so the shared initial state cancels out.
- Anything that cannot be computed is `None` plus a reason: never NaN.
All randomness comes from a generator the caller seeds (from the run seed).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypedDict

import numpy as np

if TYPE_CHECKING:
    from typing_extensions import NotRequired  # typing's own from Python 3.11


class EstimateJSON(TypedDict):
    """An estimate as summaries hold it (`Estimate.to_dict`)."""

    value: float | None
    ci: list[float] | None
    reason: NotRequired[str]


@dataclass(frozen=True)
class Estimate:
    """A point estimate with a two-sided interval, or None with the reason why."""

    value: float | None
    lo: float | None = None
    hi: float | None = None
    reason: str | None = None

    def to_dict(self) -> EstimateJSON:
        """As summaries hold it: {"value", "ci": [low, high]} (and "reason"), or value None with the reason."""
        if self.value is None:
            return {"value": None, "ci": None, "reason": self.reason or "not computable"}
        ci = None if self.lo is None or self.hi is None else [round(self.lo, 6), round(self.hi, 6)]
        out: EstimateJSON = {"value": round(self.value, 6), "ci": ci}
        if self.reason:
            out["reason"] = self.reason
        return out


def wilson(successes: int, trials: int, confidence: float = 0.95) -> Estimate:
    """Success rate with a Wilson score interval.

    The closed form of `scipy.stats.binomtest(k, n).proportion_ci(confidence, method="wilson")`, term for
    term (Newcombe 1998), so the numbers are scipy's to the last bit (`tests/test_scoring.py` checks) without
    importing scipy.stats (~0.35 s, paid by every command that scores).
    """
    if trials <= 0:
        return Estimate(None, reason="no completed episodes")
    from scipy.special import ndtri  # scipy: loaded only when this estimate is computed (and cheap)

    k, n = int(successes), int(trials)
    p = k / n
    z = ndtri(0.5 + 0.5 * confidence)
    denom = 2 * (n + z**2)
    center = (2 * n * p + z**2) / denom
    delta = z / denom * math.sqrt(4 * n * p * (1 - p) + z**2)
    low = 0.0 if k == 0 else center - delta
    high = 1.0 if k == n else center + delta
    return Estimate(successes / trials, float(low), float(high))


def iqm(values: np.ndarray, axis: int = -1) -> np.ndarray:
    """Interquartile mean: the mean of the middle 50% (25% trimmed from each end, rounded down).

    `scipy.stats.trim_mean(values, 0.25, axis)` step for step (partition, slice, mean), so the same floats
    (`tests/test_scoring.py` checks) without importing scipy.stats (~0.35 s, paid by every command that scores).
    """
    a = np.asarray(values)
    if a.size == 0:
        return np.asarray(np.nan)
    nobs = a.shape[axis]
    low = int(0.25 * nobs)
    kept = np.partition(a, (low, nobs - low - 1), axis)
    sl = [slice(None)] * kept.ndim
    sl[axis] = slice(low, nobs - low)
    trimmed = kept[tuple(sl)]
    if not np.issubdtype(trimmed.dtype, np.floating):
        trimmed = trimmed.astype(np.float64)
    return np.mean(trimmed, axis=axis)


STATISTICS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "mean": lambda x: np.mean(x, axis=-1),
    "iqm": iqm,
}


def _resampled_rates(cells: Sequence[np.ndarray], rng: np.random.Generator, n_boot: int) -> np.ndarray:
    """(n_boot, n_cells) plausible success rates, drawn independently per cell (strata = cells).

    Each cell's rate is drawn from its Jeffreys posterior Beta(k + 1/2, n - k + 1/2): the
    Bayesian bootstrap of 0/1 outcomes. It behaves like resampling episodes within the cell
    but, unlike the percentile bootstrap, does not collapse to a single point when a cell is
    all successes or all failures (10/10 is not proof of 100%).
    """
    out = np.empty((n_boot, len(cells)))
    for j, outcomes in enumerate(cells):
        outcomes = np.asarray(outcomes, dtype=float)
        k, n = float(outcomes.sum()), float(len(outcomes))
        out[:, j] = rng.beta(k + 0.5, n - k + 0.5, size=n_boot)
    return out


def _resampled_means(cells: Sequence[np.ndarray], rng: np.random.Generator, n_boot: int, binary: bool) -> np.ndarray:
    """(n_boot, n_cells) resampled cell means: Jeffreys draws for 0/1 outcomes, else episodes
    resampled with replacement within each cell (strata = cells), for continuous values (returns)."""
    if binary:
        return _resampled_rates(cells, rng, n_boot)
    out = np.empty((n_boot, len(cells)))
    for j, values in enumerate(cells):
        values = np.asarray(values, dtype=float)
        idx = rng.integers(0, len(values), size=(n_boot, len(values)))
        out[:, j] = values[idx].mean(axis=1)
    return out


def _interval(samples: np.ndarray, confidence: float) -> tuple[float, float]:
    alpha = (1.0 - confidence) / 2.0
    lo, hi = np.quantile(samples, [alpha, 1.0 - alpha])
    return float(lo), float(hi)


def _with_episodes(cells: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The cells that have completed episodes, as float arrays."""
    return [np.asarray(c, dtype=float) for c in cells if len(c)]


def _of_means(stat: Callable[[np.ndarray], np.ndarray], cells: list[np.ndarray]) -> float:
    """`stat` over the cells' mean outcomes."""
    return float(stat(np.array([c.mean() for c in cells])))


def _covering(point: float, boot: np.ndarray, confidence: float) -> Estimate:
    """`point` with the bootstrap interval of `boot`, widened to contain it.

    As for the Jeffreys interval at k = 0 or k = n: the interval always contains the observed value."""
    lo, hi = _interval(boot, confidence)
    return Estimate(point, min(lo, point), max(hi, point))


@dataclass(frozen=True)
class Boot:
    """How `aggregate` and `gap` estimate: the statistic over cells, its stratified bootstrap, the outcomes."""

    statistic: str = "mean"  # mean | iqm of the per-cell means
    n_boot: int = 2000  # bootstrap replicates
    confidence: float = 0.95  # interval coverage
    binary: bool = True  # 0/1 outcomes (success); False: returns


def aggregate(cells: Sequence[np.ndarray], rng: np.random.Generator, boot: Boot = Boot()) -> Estimate:
    """Mean or IQM of per-cell success rates (or mean returns), with a stratified bootstrap interval.

    Args:
        cells: one array of outcomes per cell (episodes of that cell): 0/1, or returns with binary=False.
    """
    cells = _with_episodes(cells)
    if not cells:
        return Estimate(None, reason="no cell has completed episodes")
    stat = STATISTICS[boot.statistic]
    boots = stat(_resampled_means(cells, rng, boot.n_boot, boot.binary))
    return _covering(_of_means(stat, cells), boots, boot.confidence)


def gap(
    reference: Sequence[np.ndarray], target: Sequence[np.ndarray], rng: np.random.Generator, boot: Boot = Boot()
) -> Estimate:
    """Transfer gap = stat(reference cells) - stat(target cells), independent stratified bootstrap."""
    reference, target = _with_episodes(reference), _with_episodes(target)
    if not reference or not target:
        side = "reference" if not reference else "target"
        return Estimate(None, reason=f"the {side} group has no completed episodes")
    stat = STATISTICS[boot.statistic]
    point = _of_means(stat, reference) - _of_means(stat, target)
    n, binary = boot.n_boot, boot.binary
    diffs = stat(_resampled_means(reference, rng, n, binary)) - stat(_resampled_means(target, rng, n, binary))
    return _covering(point, diffs, boot.confidence)


def paired_gap(
    reference: np.ndarray,
    target: np.ndarray,
    rng: np.random.Generator,
    n_boot: int = 2000,
    confidence: float = 0.95,
) -> Estimate:
    """Mean of (reference - target) over episodes paired by seed, with a paired bootstrap interval.

    Args:
        reference, target: (n_cells, n_episodes) or (n_episodes,) outcome arrays whose
            entries at the same position share an initial state (same seed, same cell).
    """
    ref, tgt = np.atleast_2d(np.asarray(reference, float)), np.atleast_2d(np.asarray(target, float))
    if ref.shape != tgt.shape:
        raise ValueError(f"paired arrays differ in shape: {ref.shape} vs {tgt.shape}")
    if ref.size == 0:
        return Estimate(None, reason="no paired episodes")
    diff = ref - tgt  # (cells, episodes)
    point = float(diff.mean())
    n = diff.shape[1]
    idx = rng.integers(0, n, size=(n_boot, n))
    boot = diff[:, idx].mean(axis=(0, 2))  # same resampled seeds in every cell
    lo, hi = _interval(boot, confidence)
    return Estimate(point, lo, hi)


def paired_score_z(b, c, n, delta) -> np.ndarray:
    """Tango's score statistic for H0: p10 - p01 = delta over n paired binary outcomes (vectorised).

    b: pairs where the first outcome is 1 and the second 0; c: the reverse; n: all pairs.
    Large positive values speak for p10 - p01 > delta. Arguments broadcast (numpy arrays of
    counts), so a test over every possible (b, c) is one call (the gate's power calculation).
    """
    b, c, n, delta = (np.asarray(x, dtype=float) for x in (b, c, n, delta))
    a_ = 2.0 * n
    b_ = -b - c + (2.0 * n - b + c) * delta
    c_ = -c * delta * (1.0 - delta)
    q = (np.sqrt(np.maximum(b_ * b_ - 4.0 * a_ * c_, 0.0)) - b_) / (2.0 * a_)  # constrained MLE of p01
    var = n * (2.0 * q + delta * (1.0 - delta))
    num = b - c - n * delta
    with np.errstate(divide="ignore", invalid="ignore"):
        z = num / np.sqrt(var)
        return np.where(var > 0, z, np.where(num == 0, 0.0, np.sign(num) * np.inf))


def _tango_z(b: int, c: int, n: int, delta: float) -> float:
    """Tango's score statistic for H0: p10 - p01 = delta (paired binary outcomes), as a float."""
    return float(paired_score_z(b, c, n, delta))


def paired_score_bound(b: int, c: int, n: int, confidence: float = 0.95, side: str = "lower") -> float:
    """One-sided bound on p10 - p01 for n paired binary outcomes (Tango's score interval).

    Unlike a percentile bootstrap it stays honest when few pairs disagree: with no
    discordant pair out of n the upper bound is z²/(n + z²), not 0.

    Args:
        b: pairs where the first outcome is 1 and the second 0.
        c: pairs where the first outcome is 0 and the second 1.
        n: all pairs (concordant included).
        confidence: one-sided level, e.g. 0.95.
        side: "lower" or "upper".
    """
    from scipy.optimize import brentq  # scipy: loaded only when this estimate is computed
    from scipy.stats import norm  # scipy: loaded only when this estimate is computed

    if n <= 0:
        raise ValueError("paired_score_bound needs n >= 1 pairs")
    z = float(norm.ppf(confidence))
    est, eps = (b - c) / n, 1e-12
    if side == "upper":
        f = lambda d: _tango_z(b, c, n, d) + z  # noqa: E731 - decreasing in d
        if f(1.0 - eps) >= 0:
            return 1.0
        return float(brentq(f, est, 1.0 - eps)) if f(est) > 0 else est
    if side != "lower":
        raise ValueError(f"side={side!r}; valid: lower, upper")
    f = lambda d: _tango_z(b, c, n, d) - z  # noqa: E731
    if f(-1.0 + eps) <= 0:
        return -1.0
    return float(brentq(f, -1.0 + eps, est)) if f(est) < 0 else est


def paired_binary_stat_samples(
    counts: np.ndarray,
    rng: np.random.Generator,
    statistic: str = "mean",
    n_boot: int = 2000,
) -> tuple[float, np.ndarray]:
    """Point value and bootstrap samples of stat(reference cell rates) - stat(target cell rates) for
    paired 0/1 outcomes, from counts: O(n_boot) per cell.

    Resampling a cell's n pairs with replacement (the same episode indices on both sides) is drawing
    multinomial counts of the four pair types, so nothing needs the episodes themselves (the
    regression gate's simulations run it thousands of times).

    Args:
        counts: (n_cells, 4) pairs per cell that are (1, 1), (1, 0), (0, 1), (0, 0) as
            (reference, target); every cell needs at least one pair.

    Returns:
        stat(reference cell rates) - stat(target cell rates), and `n_boot` resampled values of it.
    """
    stat = STATISTICS[statistic]
    k = np.asarray(counts, dtype=np.int64).reshape(-1, 4)
    n = k.sum(axis=1)
    if len(k) == 0 or (n <= 0).any():
        raise ValueError("every cell needs at least one pair")
    p = k / n[:, None]
    point = float(stat((k[:, 0] + k[:, 1]) / n) - stat((k[:, 0] + k[:, 2]) / n))
    # multinomial(n, p) per cell and resample, as a chain of binomials (vectorised over cells)
    left = np.broadcast_to(n, (n_boot, len(k))).copy()
    mass = np.ones(len(k))
    drawn = []
    for j in range(3):
        share = np.divide(p[:, j], mass, out=np.zeros(len(k)), where=mass > 1e-12).clip(0.0, 1.0)
        x = rng.binomial(left, share)
        drawn.append(x)
        left -= x
        mass = mass - p[:, j]
    ref = (drawn[0] + drawn[1]) / n
    tgt = (drawn[0] + drawn[2]) / n
    return point, stat(ref) - stat(tgt)
