"""Prediction-powered inference of a real success rate from simulated episodes and a few real trials.

The estimand is the policy's real success rate over the strata (cell x condition) the real trials cover,
each stratum weighted by its share of the simulated episodes (equal shares in a `bench run`: the mean of
cell rates, as `bench run` reports). In stratum c, with real outcomes Y, the simulated outcome S of the same
initial state where a real trial is paired with a sim episode (same cell, condition and seed), and the mean
S̄ of the sim episodes no real trial is paired with (Angelopoulos et al. 2023, "Prediction-powered
inference", Science 382; PPI++: Angelopoulos, Duchi & Zrnic 2023, "PPI++: efficient prediction-powered
inference", arXiv:2311.01453):

    θ̂_c(λ) = Ȳ_c + λ · (n_p / n) · (S̄_c − S̄_p)        (Ȳ_c: every real trial; S̄_p: the paired ones' sims)

that is λ·S̄ plus the rectifier mean(Y − λS) over the paired trials, and unpaired trials entering as real-only
data. It is unbiased for every λ when the real trials are a random sample of the stratum's initial states.
λ is PPI++'s power tuning: the value that minimises the estimated variance, clipped to [0, 1], so a simulator
that carries no information (or anti-correlates) gets λ → 0 and the estimate falls back to the real-only one.

Its variance, one λ over the strata with weights w_c, a_c the variance of S̄_c:

    V(λ) = Σ w_c² [λ² (n_p/n)² a_c + (n_p Var(Y − λS) + n_u Var(Y_u)) / n²]

The moments of the paired 2x2 table carry Agresti & Min's (2005, Biometrics 61:515) half-count in each cell,
so a handful of concordant pairs cannot claim a perfect simulator (a zero-variance rectifier and a zero-width
interval). For binary outcomes this makes the rectifier's variance that of the paired real-sim differences
Y − S with Agresti-Min's correction when λ = 1. The interval is Wilson's score interval (`stats.score_interval`)
at θ̂ over the effective number of real trials n_eff = n_ref · V(0) / V(λ), where n_ref is the real-only
interval's own (n for one stratum, 1/Σ w_c²/n_c for several: the stratified Wilson of `bench run`): at λ = 0
it is exactly the real-only Wilson interval. `benchmarks/bench_predict.py` measures its coverage by
simulation at sim-real correlations from negative to one; `tests/test_predict.py` holds a smaller table.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bench.scoring.stats import score_interval

AGRESTI_MIN = 0.5  # pseudo-count added to each cell of the paired 2x2 table (binary outcomes)
MAX_TRIALS = 10_000_000  # the largest number of real trials `trials_for_width` searches


@dataclass(frozen=True)
class Stratum:
    """One stratum's data: real outcomes (paired with a sim episode or not) and the other sim episodes."""

    key: str
    weight: float  # its share of the estimand (sim episodes of the stratum / all of the covered strata)
    y_paired: np.ndarray  # real outcomes of trials paired with a sim episode
    s_paired: np.ndarray  # the paired sim episodes' outcomes
    y_unpaired: np.ndarray  # real outcomes without a sim partner
    sim_mean: float | None  # mean outcome of the sim episodes no real trial is paired with (None: none)
    sim_var_of_mean: float  # variance of sim_mean (0 when the simulated rate is given without trial counts)
    sim_n: float  # those sim episodes (inf for a rate given without counts)

    @property
    def n(self) -> int:
        return len(self.y_paired) + len(self.y_unpaired)


@dataclass(frozen=True)
class _Parts:
    """Per-stratum pieces of V(λ) = Σ w² [λ² A + B − 2λ K + λ² C] and of θ̂(λ) = Σ w [Ȳ + λ D]."""

    w: np.ndarray
    A: np.ndarray
    B: np.ndarray
    K: np.ndarray
    C: np.ndarray
    ybar: np.ndarray
    D: np.ndarray
    n: np.ndarray
    npaired: np.ndarray


def _moments(y: np.ndarray, s: np.ndarray, pseudo: float) -> tuple[float, float, float]:
    """Var(Y), Var(S), Cov(Y, S) of paired outcomes with `pseudo` added at each corner of the 2x2 table (with
    pseudo=0: sample moments, ddof=1)."""
    if pseudo > 0:
        y = np.concatenate([y, [1.0, 1.0, 0.0, 0.0]])
        s = np.concatenate([s, [1.0, 0.0, 1.0, 0.0]])
        wt = np.concatenate([np.ones(len(y) - 4), np.full(4, pseudo)])
        m = wt.sum()
        yc, sc = y - (wt @ y) / m, s - (wt @ s) / m
        return float(wt @ (yc * yc) / m), float(wt @ (sc * sc) / m), float(wt @ (yc * sc) / m)
    if len(y) < 2:
        return 0.0, 0.0, 0.0
    cov = np.cov(np.vstack([y, s]), ddof=1)
    return float(cov[0, 0]), float(cov[1, 1]), float(cov[0, 1])


def _var(y: np.ndarray, pseudo: float) -> float:
    """Var(Y) of real-only outcomes, with the same pseudo-counts the paired table gets (one at 1, one at 0)."""
    if pseudo > 0:
        return _moments(y, y, pseudo)[0]
    return float(np.var(y, ddof=1)) if len(y) >= 2 else 0.0


def _parts(strata: Sequence[Stratum], pseudo: float) -> _Parts:
    rows = []
    for st in strata:
        yp, sp, yu = (np.asarray(a, dtype=float) for a in (st.y_paired, st.s_paired, st.y_unpaired))
        if st.sim_mean is None or len(yp) == 0:  # no sim episode left to rectify: the pairs are real-only data
            yu, yp, sp = np.concatenate([yu, yp]), yp[:0], sp[:0]
        n_p, n_u = len(yp), len(yu)
        n = n_p + n_u
        vy_p, vs_p, k_p = _moments(yp, sp, pseudo) if n_p else (0.0, 0.0, 0.0)
        vy_u = _var(yu, pseudo) if n_u else 0.0
        share = n_p / n
        correction = share * (float(st.sim_mean or 0.0) - float(sp.mean())) if n_p else 0.0  # n_p > 0: sim_mean set
        rows.append(
            (
                st.weight,
                share**2 * st.sim_var_of_mean,
                (n_p * vy_p + n_u * vy_u) / n**2,
                n_p * k_p / n**2,
                n_p * vs_p / n**2,
                float(np.concatenate([yp, yu]).mean()),
                correction,
                n,
                n_p,
            )
        )
    cols = [np.array(c, dtype=float) for c in zip(*rows)]
    return _Parts(*cols)


def _tuned(p: _Parts, scale: float = 1.0) -> float:
    """PPI++'s λ: the minimiser of V(λ), clipped to [0, 1]; `scale` = n'/n rescales the real-trial terms (a
    design with n' real trials in the same proportions)."""
    w2 = p.w**2
    den = float(w2 @ (p.A + p.C / scale))
    if den <= 0:
        return 0.0
    return float(np.clip(float(w2 @ (p.K / scale)) / den, 0.0, 1.0))


def _variance(p: _Parts, lam: float, scale: float = 1.0) -> float:
    w2 = p.w**2
    return float(w2 @ (lam**2 * p.A + (p.B - 2 * lam * p.K + lam**2 * p.C) / scale))


@dataclass(frozen=True)
class Prediction:
    """The prediction-powered estimate and the real-only one it is measured against."""

    value: float  # θ̂, clipped to [0, 1]
    lo: float
    hi: float
    lam: float  # PPI++'s power-tuning weight on the simulator (0: real-only)
    n_eff: float  # effective real trials of the interval
    real_value: float  # real-only estimate (mean of the strata's real rates, weighted)
    real_lo: float
    real_hi: float
    n_ref: float  # the real-only interval's effective trials
    n_paired: int
    n_unpaired: int
    sim_n: float  # sim episodes not paired with a real trial (inf: a rate given without counts)
    confidence: float

    @property
    def width(self) -> float:
        return self.hi - self.lo

    @property
    def real_width(self) -> float:
        return self.real_hi - self.real_lo


def _gain(p: _Parts, confidence: float, scale: float = 1.0) -> tuple[float, float]:
    """(λ, n_eff / n_ref): PPI++'s λ and the variance ratio V(0)/V(λ) it buys, shrunk by (z / t)² at the paired
    trials' degrees of freedom (λ and the rectifier's variance are estimated from those few pairs: the
    small-sample allowance a t interval makes). A gain that does not survive the shrinking is no gain: λ = 0."""
    from scipy.special import ndtri, stdtrit  # scipy: loaded only when a prediction is computed (and cheap)

    lam = _tuned(p, scale)
    v0, vl = _variance(p, 0.0, scale), _variance(p, lam, scale)
    if lam <= 0 or vl <= 0 or v0 <= 0:
        return 0.0, 1.0
    pairs = float(p.npaired.sum()) * scale
    if pairs < 2:
        return 0.0, 1.0
    q = 0.5 + 0.5 * confidence
    gain = v0 / vl * (float(ndtri(q)) / float(stdtrit(pairs - 1, q))) ** 2
    return (lam, gain) if gain > 1 else (0.0, 1.0)


def _n_ref(p: _Parts, unit: bool, real_value: float, v0: float, scale: float = 1.0) -> float:
    """Effective real trials of the real-only interval: Kish's 1/Σ w²/n (episodes), or for a mean of rates
    (unit=True) the number of Bernoulli trials with the variance the rates show."""
    if unit:
        if v0 <= 0:
            return float(p.n.sum()) * scale
        return max(real_value * (1 - real_value) / (v0 / scale), 1e-9)
    return scale / float(np.sum(p.w**2 / p.n))


def predict(
    strata: Sequence[Stratum], confidence: float = 0.95, pseudo: float = AGRESTI_MIN, unit: bool = False
) -> Prediction:
    """The real success rate with a prediction-powered interval, and the real-only Wilson interval.

    Args:
        strata: the strata with at least one real trial each (their weights sum to 1).
        confidence: two-sided coverage of both intervals.
        pseudo: Agresti-Min pseudo-count per cell of the paired table (0 for outcomes that are rates).
        unit: the outcomes are per-unit rates (a mean over units, e.g. policy x task), not 0/1 episodes.
    """
    p = _parts(strata, pseudo)
    real_value = float(p.w @ p.ybar)
    v0 = _variance(p, 0.0)
    n_ref = _n_ref(p, unit, real_value, v0)
    sim_n = float(sum(st.sim_n for st in strata if st.sim_mean is not None and len(st.y_paired)))
    lam, gain = _gain(p, confidence)
    theta = float(p.w @ (p.ybar + lam * p.D))
    n_eff = min(n_ref * gain, n_ref + sim_n)
    value = min(max(theta, 0.0), 1.0)
    lo, hi = score_interval(value, n_eff, confidence)
    rlo, rhi = score_interval(real_value, n_ref, confidence)
    return Prediction(
        value=value,
        lo=lo,
        hi=hi,
        lam=lam,
        n_eff=n_eff,
        real_value=real_value,
        real_lo=rlo,
        real_hi=rhi,
        n_ref=n_ref,
        n_paired=int(sum(len(st.y_paired) for st in strata)),
        n_unpaired=int(sum(len(st.y_unpaired) for st in strata)),
        sim_n=sim_n,
        confidence=confidence,
    )


def trials_for_width(
    strata: Sequence[Stratum], width: float, confidence: float = 0.95, pseudo: float = AGRESTI_MIN, unit: bool = False
) -> tuple[int | None, int | None]:
    """Real trials needed for an interval of `width`: (with the simulator, real-only).

    The design is this one scaled: n' real trials in the same strata, the same share of them paired, the same
    sim episodes, and the moments, estimate and λ's rule as measured now (λ re-tuned for n'). None when even
    MAX_TRIALS would not do.
    """
    p = _parts(strata, pseudo)
    now = float(p.n.sum())
    theta = min(max(float(p.w @ (p.ybar + _gain(p, confidence)[0] * p.D)), 0.0), 1.0)
    real_value = float(p.w @ p.ybar)
    v0_now = _variance(p, 0.0)

    def widths(n_new: int) -> tuple[float, float]:
        scale = n_new / now
        n_ref = _n_ref(p, unit, real_value, v0_now, scale)
        lo, hi = score_interval(theta, n_ref * _gain(p, confidence, scale)[1], confidence)
        rlo, rhi = score_interval(real_value, n_ref, confidence)
        return hi - lo, rhi - rlo

    return _smallest(lambda n: widths(n)[0] <= width), _smallest(lambda n: widths(n)[1] <= width)


def _smallest(ok) -> int | None:
    """The smallest n in [1, MAX_TRIALS] with ok(n), for ok monotone in n (bisection)."""
    if not ok(MAX_TRIALS):
        return None
    lo, hi = 1, MAX_TRIALS
    while lo < hi:
        mid = (lo + hi) // 2
        if ok(mid):
            hi = mid
        else:
            lo = mid + 1
    return lo
