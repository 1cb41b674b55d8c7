"""Scores with intervals: success rates, aggregates across cells, transfer gaps.

Conventions (each interval's coverage is measured by simulation: `benchmarks/interval_coverage.py` prints the
tables, `tests/test_interval_coverage.py` holds them):
- A per-cell rate carries a Wilson score interval (`scipy.stats.binomtest(...).proportion_ci`).
- The mean of per-cell success rates carries a stratified Wilson interval: Wilson's score interval at the
  mean rate with the effective number of episodes C² / Σ 1/n_c (all episodes when the cells are of one
  size). The cells are the benchmark's, fixed: the interval is for the mean of these cells' true rates,
  and differing rates across cells only make it conservative. The IQM of per-cell rates takes the same
  interval over the cells it keeps (the middle half by observed rate; every cell below 4 cells).
  Unlike a bootstrap of per-cell draws, neither edge sits on the estimate away from 0 and 1.
- A gap between two groups of cells (seen - unseen) carries Newcombe's MOVER interval, the two groups'
  intervals above combined (Newcombe 1998, method 10; Zou & Donner 2008).
- A paired gap (same episode seeds under two conditions: per-axis drops) of 0/1 outcomes carries Tango's
  score interval for paired proportions (Tango 1998), whose bounds stay honest when few pairs disagree.
- Returns (outcomes that are not 0/1): the mean (IQM) of cell means and gaps between groups carry a stratified
  t interval (the cells' variances of their means summed, Welch-Satterthwaite degrees of freedom); a percentile
  bootstrap, episodes resampled within each cell, where a cell has a single episode, and for paired gaps (pairs
  resampled jointly).
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
    k, n = int(successes), int(trials)
    low, high = _score_interval(k / n, n, confidence)
    return Estimate(successes / trials, low, high)


def _score_interval(p: float, n: float, confidence: float) -> tuple[float, float]:
    """Wilson's score interval for a proportion `p` seen over `n` trials (`n` may be an effective, fractional size),
    with Brown, Cai & DasGupta's modification near the edges.

    Ends at exactly 0 (1) when `p` is 0 (1), as scipy's does. Wilson's coverage dips well below nominal when
    the successes (failures) number 1 to 3 (at p = 0.02 over 5 episodes, 0.90 for 0.95):
    for x = p * n in (0, x*] successes, x* = 2 up to 50 trials and 3 above, the lower bound is the Poisson one,
    ½ χ²(2x) quantile at 1 - confidence over n (Brown, Cai & DasGupta 2001, Statistical Science 16:101, §4.1.1),
    and the upper bound likewise for failures. Elsewhere the floats are scipy's `binomtest(...).proportion_ci(
    method="wilson")` term for term (tests/test_scoring.py checks both)."""
    from scipy.special import gammaincinv, ndtri  # scipy: loaded only when an estimate is computed (and cheap)

    z = ndtri(0.5 + 0.5 * confidence)
    denom = 2 * (n + z**2)
    center = (2 * n * p + z**2) / denom
    delta = z / denom * math.sqrt(max(4 * n * p * (1 - p) + z**2, 0.0))
    low = 0.0 if p <= 0 else center - delta
    high = 1.0 if p >= 1 else center + delta
    edge = 2.0 if n <= 50 else 3.0
    alpha = 1.0 - confidence
    if 0 < p * n <= edge + 1e-9:
        low = min(low, float(gammaincinv(p * n, alpha)) / n)
    if 0 < (1 - p) * n <= edge + 1e-9:
        high = max(high, 1.0 - float(gammaincinv((1 - p) * n, alpha)) / n)
    return float(max(low, 0.0)), float(min(high, 1.0))


def score_interval(p: float, n: float, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson's score interval (with the edge correction above) for a rate `p` over an effective, possibly
    fractional, number of trials `n`: what `wilson` and `stratified_wilson` compute, for estimators whose
    variance is stated as an effective sample size (prediction-powered inference, `bench.scoring.predict`)."""
    return _score_interval(min(max(float(p), 0.0), 1.0), float(n), confidence)


def kept_cells(rates: np.ndarray) -> np.ndarray:
    """Indices of the cells the IQM of `rates` averages: the middle half by rate (`iqm`'s trimming)."""
    nobs = len(rates)
    low = int(0.25 * nobs)
    return np.argsort(rates, kind="stable")[low : nobs - low]


def stratified_wilson(cells: Sequence[np.ndarray], confidence: float = 0.95, statistic: str = "mean") -> Estimate:
    """Mean (or IQM) of per-cell success rates with a stratified Wilson interval (see the module docstring).

    Args:
        cells: one array of 0/1 outcomes per cell, each with at least one episode.
    """
    rates = np.array([np.mean(c) for c in cells], dtype=float)
    sizes = np.array([len(c) for c in cells], dtype=float)
    keep = kept_cells(rates) if statistic == "iqm" else np.arange(len(rates))
    point = float(STATISTICS[statistic](rates))
    n_eff = len(keep) ** 2 / float(np.sum(1.0 / sizes[keep]))
    low, high = _score_interval(float(rates[keep].mean()), n_eff, confidence)
    return Estimate(point, min(low, point), max(high, point))


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


def _resampled_means(cells: Sequence[np.ndarray], rng: np.random.Generator, n_boot: int) -> np.ndarray:
    """(n_boot, n_cells) resampled cell means of returns: episodes resampled with replacement within each
    cell (strata = cells)."""
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

    A percentile interval of a skewed statistic can miss the observed value; the reported one never does."""
    lo, hi = _interval(boot, confidence)
    return Estimate(point, min(lo, point), max(hi, point))


@dataclass(frozen=True)
class Boot:
    """How `aggregate` and `gap` estimate: the statistic over cells, its stratified bootstrap, the outcomes."""

    statistic: str = "mean"  # mean | iqm of the per-cell means
    n_boot: int = 2000  # bootstrap replicates
    confidence: float = 0.95  # interval coverage
    binary: bool = True  # 0/1 outcomes (success); False: returns


def _cell_variances(cells: Sequence[np.ndarray], statistic: str) -> tuple[float, np.ndarray, np.ndarray] | None:
    """stat of the cell means, and per kept cell its mean's variance share and degrees of freedom (None when a
    kept cell has fewer than 2 episodes: no variance to estimate)."""
    means = np.array([np.mean(c) for c in cells], dtype=float)
    keep = kept_cells(means) if statistic == "iqm" else np.arange(len(means))
    if any(len(cells[i]) < 2 for i in keep):
        return None
    shares = np.array([np.var(cells[i], ddof=1) / len(cells[i]) for i in keep]) / len(keep) ** 2
    return float(STATISTICS[statistic](means)), shares, np.array([len(cells[i]) - 1.0 for i in keep])


def _welch(point: float, shares: np.ndarray, dof: np.ndarray, confidence: float) -> Estimate:
    """point ± t · sqrt(Σ shares), t at Welch-Satterthwaite's degrees of freedom."""
    from scipy.special import stdtrit  # scipy: loaded only when an estimate is computed (and cheap)

    var = float(shares.sum())
    if var <= 0:
        return Estimate(point, point, point)
    df = var**2 / float(np.sum(shares**2 / dof))
    half = float(stdtrit(df, 0.5 + 0.5 * confidence)) * math.sqrt(var)
    return Estimate(point, point - half, point + half)


def aggregate(cells: Sequence[np.ndarray], rng: np.random.Generator, boot: Boot = Boot()) -> Estimate:
    """Mean or IQM of per-cell success rates (stratified Wilson interval), or of mean returns (stratified t).

    Args:
        cells: one array of outcomes per cell (episodes of that cell): 0/1, or returns with binary=False.
    """
    cells = _with_episodes(cells)
    if not cells:
        return Estimate(None, reason="no cell has completed episodes")
    if boot.binary:
        return stratified_wilson(cells, boot.confidence, boot.statistic)
    parts = _cell_variances(cells, boot.statistic)
    if parts is not None:
        return _welch(*parts, boot.confidence)
    stat = STATISTICS[boot.statistic]
    boots = stat(_resampled_means(cells, rng, boot.n_boot))
    return _covering(_of_means(stat, cells), boots, boot.confidence)


def bootstrap_aggregate(cells: Sequence[np.ndarray], rng: np.random.Generator, boot: Boot = Boot()) -> Estimate:
    """Mean or IQM of cell means with a percentile bootstrap (episodes resampled within each cell): unlike the t
    interval it stays within the values' range, for bounded measurements (an action difference >= 0)."""
    cells = _with_episodes(cells)
    if not cells:
        return Estimate(None, reason="no cell has completed episodes")
    stat = STATISTICS[boot.statistic]
    return _covering(_of_means(stat, cells), stat(_resampled_means(cells, rng, boot.n_boot)), boot.confidence)


def mover(first: Estimate, second: Estimate) -> Estimate:
    """first - second with Newcombe's MOVER interval from the two estimates' own (independent) intervals."""
    if first.value is None or second.value is None:
        return Estimate(None, reason=first.reason if first.value is None else second.reason)
    assert first.lo is not None and first.hi is not None and second.lo is not None and second.hi is not None
    d = first.value - second.value
    lo = d - math.hypot(first.value - first.lo, second.hi - second.value)
    hi = d + math.hypot(first.hi - first.value, second.value - second.lo)
    return Estimate(d, max(lo, -1.0), min(hi, 1.0))


def gap(
    reference: Sequence[np.ndarray], target: Sequence[np.ndarray], rng: np.random.Generator, boot: Boot = Boot()
) -> Estimate:
    """Transfer gap = stat(reference cells) - stat(target cells): MOVER over the two stratified Wilson
    intervals for success, a stratified t (Welch) for returns."""
    reference, target = _with_episodes(reference), _with_episodes(target)
    if not reference or not target:
        side = "reference" if not reference else "target"
        return Estimate(None, reason=f"the {side} group has no completed episodes")
    if boot.binary:
        return mover(
            stratified_wilson(reference, boot.confidence, boot.statistic),
            stratified_wilson(target, boot.confidence, boot.statistic),
        )
    ref_parts, tgt_parts = _cell_variances(reference, boot.statistic), _cell_variances(target, boot.statistic)
    if ref_parts is not None and tgt_parts is not None:
        return _welch(
            ref_parts[0] - tgt_parts[0],
            np.concatenate([ref_parts[1], tgt_parts[1]]),
            np.concatenate([ref_parts[2], tgt_parts[2]]),
            boot.confidence,
        )
    stat = STATISTICS[boot.statistic]
    point = _of_means(stat, reference) - _of_means(stat, target)
    diffs = stat(_resampled_means(reference, rng, boot.n_boot)) - stat(_resampled_means(target, rng, boot.n_boot))
    return _covering(point, diffs, boot.confidence)


def paired_gap(
    reference: np.ndarray,
    target: np.ndarray,
    rng: np.random.Generator,
    n_boot: int = 2000,
    confidence: float = 0.95,
) -> Estimate:
    """Mean of (reference - target) over episodes paired by seed: Tango's score interval when every outcome
    is 0 or 1, a paired bootstrap (same resampled seeds in every cell) otherwise.

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
    if np.isin(ref, (0.0, 1.0)).all() and np.isin(tgt, (0.0, 1.0)).all():
        b, c, n = int((diff > 0).sum()), int((diff < 0).sum()), int(diff.size)
        side = 1.0 - (1.0 - confidence) / 2.0
        return Estimate(point, paired_score_bound(b, c, n, side, "lower"), paired_score_bound(b, c, n, side, "upper"))
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
