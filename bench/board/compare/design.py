"""The group-sequential design of `bench compare`: boundaries, the cap, and its exact operating characteristics.

d = success(A) - success(B) over episodes paired by seed; per pair (A, B) outcomes are (1, 0) with
probability p10 and (0, 1) with p01, so d = p10 - p01. At each look k (after `schedule[k]` episodes per
cell) three score statistics of the paired counts are compared with boundaries fixed before the first
episode:

    A better     zA >= c_k       zA: the exact one-sided McNemar (sign) test of d = 0 on the discordant pairs, as a z
    B better     zB >= c_k       zB: the same for B
    equivalent   zU <= -e_k and zL >= e_k     zU, zL: Tango's score statistics for d = +delta and d = -delta

The design is Jennison & Turnbull's two-sided group-sequential test with early stopping to accept H0
(Group Sequential Methods with Applications to Clinical Trials, 2000, ch. 5 and 7), its boundaries
from error spending (Lan & DeMets 1983, Biometrika 70:659) with the O'Brien-Fleming-type function
f(t) = 2 - 2 Phi(z_{1-a/2} / sqrt t) at the information fractions t_k = schedule[k] / schedule[-1]:

    c_k   one-sided boundaries spending alpha / 2 over the looks (each direction): P(a wrong direction) <= alpha / 2,
          P(naming either policy when d = 0) <= alpha, at whatever look the comparison stops;
    e_k   one-sided boundaries spending beta over the looks for "d >= delta" and for "d <= -delta" (two one-sided
          tests, intersection-union): P(claiming equivalence when |d| >= delta) <= beta.

Both sets are computed by recursive numerical integration of the canonical joint normal law of the score
statistics (Armitage, McPherson & Rowe 1969; Jennison & Turnbull ch. 19), so they hold asymptotically
whatever the nuisance discordance p10 + p01, and the stops for equivalence are non-binding (ignored
when the alpha boundaries are computed). `operating` computes the *exact* probabilities of each answer
and the expected pairs used, for a given (p10, p01), by carrying the law of the counts (b, c) over the
looks (the same convolution as the gate's `bench.board.gate.power`): the benchmark and the tests use it
to check the error rates at small samples, where the normal approximation is least trusted.

The cap: the fewest episodes per cell (a multiple of the batch) at which the chance of naming A when
d = delta is at least 1 - beta, planned at the largest discordance d = delta allows with independent
outcomes (rates 0.5 +- delta / 2: p10 + p01 = 0.5 + delta^2 / 2), the conservative case (common seeds
only add agreement, which shrinks p10 + p01 and the episodes needed). The fixed-N design at equal
errors is the one-look test with the same alpha, beta and plan (`fixed_pairs`); `bench compare`
reports the pairs it used against it.

This is a group-sequential design with alpha spending on the paired difference, not STEP (Snyder et al.
2025, "Is your imitation learning policy better than mine? Policy comparison with near-optimal
stopping", arXiv:2503.10966), which optimises the stopping region for two *unpaired* Bernoulli
batches; ours uses the pairing that common seeds give (fewer episodes when outcomes agree).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from bench.board.gate import power as gate_power
from bench.board.gate import sequential
from bench.scoring import stats as scoring

GRID_STEP = 0.0025  # score-scale grid of the numerical integration (S = Z sqrt(t), S ~ N(0, t) under H0)
GRID_HALF = 10.0
MAX_PAIRS = 20000  # pooled: the sizing gives up beyond (a CI budget this large is not a plan)


def spending(t: float | np.ndarray, level: float) -> np.ndarray:
    """Lan-DeMets O'Brien-Fleming-type error spending: the share of `level` spent by information fraction t."""
    from scipy.special import ndtr, ndtri  # scipy: loaded only when a design is computed

    t = np.clip(np.asarray(t, dtype=float), 1e-12, 1.0)
    return np.asarray(2.0 - 2.0 * ndtr(ndtri(1.0 - level / 2.0) / np.sqrt(t)))


def one_sided_bounds(fractions: tuple[float, ...], level: float) -> list[float]:
    """z boundaries c_k with P0(Z_j < c_j for j < k, Z_k >= c_k) = f(t_k) - f(t_{k-1}) (`spending`).

    Z_k = S_k / sqrt(t_k) with S a standard Brownian motion under H0 (the canonical joint law of score
    statistics at information fractions t_k). Recursive integration on a uniform grid of S; a look whose
    share is nil gets an infinite boundary.
    """
    from scipy.signal import fftconvolve  # scipy: loaded only when a design is computed
    from scipy.special import ndtri  # scipy: loaded only when a design is computed

    xs = np.arange(-GRID_HALF, GRID_HALF + GRID_STEP / 2, GRID_STEP)
    spent = spending(np.array(fractions), level)
    bounds: list[float] = []
    dens: np.ndarray | None = None
    prev_t, prev_spent = 0.0, 0.0
    for t, cum in zip(fractions, spent):
        inc = float(cum) - prev_spent
        dt = t - prev_t
        kernel = np.exp(-0.5 * xs**2 / dt) / math.sqrt(2 * math.pi * dt)
        first = dens is None
        dens = kernel.copy() if dens is None else np.clip(fftconvolve(dens, kernel, mode="same"), 0.0, None) * GRID_STEP
        if first:
            c = float(ndtri(1.0 - inc)) if inc > 0 else math.inf  # first look: exact
        else:
            tail = np.cumsum(dens[::-1])[::-1] * GRID_STEP  # P(S >= xs[i], still running)
            if inc <= 0:
                c = math.inf
            else:
                i = int(np.searchsorted(-tail, -inc))  # first grid point whose tail is <= inc
                i = min(max(i, 1), len(xs) - 1)
                t0, t1 = tail[i - 1], tail[i]
                s = xs[i - 1] + (xs[i] - xs[i - 1]) * ((t0 - inc) / (t0 - t1) if t0 > t1 else 1.0)
                c = float(s / math.sqrt(t))
        bounds.append(c)
        if math.isfinite(c):
            dens = np.where(xs < c * math.sqrt(t), dens, 0.0)
        prev_t, prev_spent = t, float(cum)
    return bounds


def looks_schedule(cap: int, batch: int) -> list[int]:
    """Episodes per cell at each look (the gate's rule: batch, 2 batch, ..., cap; one look when batch is 0)."""
    return sequential.looks_schedule(cap, batch)


@dataclass(frozen=True)
class Design:
    """What a comparison's errors are held to, fixed before the first episode: alpha, beta, delta, the looks."""

    alpha: float = 0.05  # P(naming a better policy when they are equal), over all looks and both directions
    beta: float = 0.2  # P(missing a difference of delta); also bounds a wrong "equivalent within delta"
    delta: float = 0.2  # the difference in success rate that matters
    schedule: tuple[int, ...] = (20,)  # episodes per cell at each look (cumulative)

    @property
    def fractions(self) -> tuple[float, ...]:
        return tuple(n / self.schedule[-1] for n in self.schedule)

    @cached_property
    def efficacy(self) -> list[float]:
        """c_k: zA >= c_k (zB >= c_k) names A (B) better (alpha / 2 spent per direction)."""
        return one_sided_bounds(self.fractions, self.alpha / 2.0)

    @cached_property
    def equivalence(self) -> list[float]:
        """e_k: zU <= -e_k and zL >= e_k claims |d| < delta (beta spent per side)."""
        return one_sided_bounds(self.fractions, self.beta)

    def scaled(self, share: float) -> Design:
        """The same looks with alpha and beta times `share` (a cell's Bonferroni share of the family)."""
        return _scaled(self, share)


@lru_cache(maxsize=64)
def _scaled(design: Design, share: float) -> Design:  # every look of a comparison asks again: boundaries once
    return Design(design.alpha * share, design.beta * share, design.delta, design.schedule)


def statistics(b, c, n, delta: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(zA, zB, zU, zL) of paired counts: b pairs only A succeeded, c only B, n pairs in all (arrays broadcast).

    zA (zB) is the exact one-sided McNemar p-value for A (B) better, P(Bin(b + c, 1/2) >= b (c)), as a normal
    quantile: the sign test on the discordant pairs, exact whatever their share, where McNemar's score z
    (b - c) / sqrt(b + c) overshoots alpha by a tenth when nearly every pair is discordant.
    """
    from scipy.special import bdtrc, ndtri  # scipy: loaded only when a comparison is scored

    bi, ci = np.asarray(b, dtype=np.int64), np.asarray(c, dtype=np.int64)
    m = bi + ci
    with np.errstate(divide="ignore", invalid="ignore"):
        pa = np.where(bi > 0, bdtrc(np.maximum(bi - 1, 0), m, 0.5), 1.0)
        pb = np.where(ci > 0, bdtrc(np.maximum(ci - 1, 0), m, 0.5), 1.0)
        za, zb = -ndtri(pa), -ndtri(pb)
    zu = scoring.paired_score_z(b, c, n, delta)
    zl = -scoring.paired_score_z(c, b, n, delta)  # d = -delta for (b, c) is d = +delta for (c, b)
    return za, zb, zu, zl


def answer(za: float, zb: float, zu: float, zl: float, c: float, e: float) -> str:
    """The answer a look gives: "a_better", "b_better", "equivalent" or "continue"."""
    if za >= c:
        return "a_better"
    if zb >= c:
        return "b_better"
    if zu <= -e and zl >= e:
        return "equivalent"
    return "continue"


@dataclass(frozen=True)
class Operating:
    """Exact probabilities of each answer and the expected pairs (pooled) a design uses, at one (p10, p01)."""

    a_better: float
    b_better: float
    equivalent: float
    inconclusive: float
    expected_pairs: float
    max_pairs: int


def operating(design: Design, p10: float, p01: float, cells: int = 1) -> Operating:
    """The design's exact operating characteristics for pooled pairs, `cells` cells of identical (p10, p01).

    The law of (b, c) is carried from look to look (trinomial batches, `bench.board.gate.power`'s kernel);
    at each look the mass where an answer is reached is taken out.
    """
    from scipy.signal import fftconvolve  # scipy: loaded only when a design is computed

    dist = np.ones((1, 1))
    b0 = c0 = 0
    prev = 0
    got = {"a_better": 0.0, "b_better": 0.0, "equivalent": 0.0}
    expected = 0.0
    pairs = [n * cells for n in design.schedule]
    for k, n in enumerate(pairs):
        if n > prev:
            dist = fftconvolve(dist, gate_power._kernel(n - prev, p10, p01))
            dist[dist < 1e-300] = 0.0  # FFT round-off
            dist, b0, c0 = gate_power._crop(dist, b0, c0)
        prev = n
        b = b0 + np.arange(dist.shape[0])[:, None]
        c = c0 + np.arange(dist.shape[1])[None, :]
        za, zb, zu, zl = statistics(b, c, n, design.delta)
        valid = b + c <= n
        ck, ek = design.efficacy[k], design.equivalence[k]
        regions = {
            "a_better": valid & (za >= ck),
            "b_better": valid & (zb >= ck) & (za < ck),
        }
        regions["equivalent"] = valid & ~regions["a_better"] & ~regions["b_better"] & (zu <= -ek) & (zl >= ek)
        for name, r in regions.items():
            mass = float(dist[r].sum())
            got[name] += mass
            expected += mass * n
            dist = np.where(r, 0.0, dist)
    left = max(0.0, 1.0 - sum(got.values()))
    expected += left * pairs[-1]
    return Operating(got["a_better"], got["b_better"], got["equivalent"], left, expected, pairs[-1])


def planned_pairs(delta: float) -> tuple[float, float]:
    """(p10, p01) the cap is sized for: d = delta at rates 0.5 +- delta/2, outcomes independent (most discordant)."""
    ra, rb = 0.5 + delta / 2.0, 0.5 - delta / 2.0
    return ra * (1.0 - rb), (1.0 - ra) * rb


def size_cap(alpha: float, beta: float, delta: float, cells: int, batch: int) -> tuple[int | None, float]:
    """Fewest episodes per cell (a multiple of `batch`, looks every `batch`) with P(A better | d = delta) >= 1 - beta
    at the plan (`planned_pairs`), and that power; (None, power) when MAX_PAIRS pooled pairs fall short."""
    p10, p01 = planned_pairs(delta)
    # a first guess from the normal approximation of the fixed design, then the exact search
    guess = 1.15 * fixed_pairs_normal(alpha, beta, delta) / max(cells, 1)  # the cap is ~1.2 fixed N
    step = batch if batch > 0 else max(1, math.ceil(guess / 8))

    def pw(k: int) -> float:
        cap = k * step
        d = Design(alpha, beta, delta, tuple(looks_schedule(cap, batch)))
        return operating(d, p10, p01, cells).a_better

    target = 1.0 - beta
    lo, hi = 0, max(1, int(guess // step))
    while pw(hi) < target:
        lo, hi = hi, hi * 2
        if hi * step * cells > MAX_PAIRS:
            return None, pw(lo)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if pw(mid) >= target:
            hi = mid
        else:
            lo = mid
    return hi * step, pw(hi)


def fixed_pairs_normal(alpha: float, beta: float, delta: float) -> float:
    """Pooled pairs of the one-look test by the normal approximation: (z_{1-a/2} + z_{1-b})^2 (p10 + p01) / delta^2."""
    from scipy.special import ndtri  # scipy: loaded only when a design is computed

    p10, p01 = planned_pairs(delta)
    return (float(ndtri(1 - alpha / 2)) + float(ndtri(1 - beta))) ** 2 * (p10 + p01 - delta**2) / delta**2


def fixed_pairs(alpha: float, beta: float, delta: float) -> tuple[int, float]:
    """The fixed-N design at equal errors: fewest pooled pairs whose one-look test (same alpha, beta, plan) has
    P(A better | d = delta) >= 1 - beta (exact), and that power. The smallest n past which power stays above
    target is searched by bisection from the normal guess (power saw-tooths with n by a few thousandths)."""
    p10, p01 = planned_pairs(delta)

    def pw(n: int) -> float:
        return operating(Design(alpha, beta, delta, (n,)), p10, p01).a_better

    target = 1.0 - beta
    lo, hi = 1, max(2, int(fixed_pairs_normal(alpha, beta, delta)))
    while pw(hi) < target:
        lo, hi = hi, hi * 2
        if hi > MAX_PAIRS:
            return hi, pw(hi)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if pw(mid) >= target:
            hi = mid
        else:
            lo = mid
    return hi, pw(hi)
