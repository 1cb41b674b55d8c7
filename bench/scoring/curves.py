"""Success as a function of a continuous perturbation: a fitted curve, and the factor where the policy breaks.

A range condition (`perturb.friction=uniform(0.1,3)`) draws its factor per episode, so its episodes hold
(factor, success) pairs. They are fitted with a logistic curve, p(x) = 1 / (1 + exp(-(a + b g(x)))), with g the
factor or its log (the one with the lower deviance; the log only for a range of positive factors), by Firth's
penalised likelihood — the Jeffreys-prior penalty that keeps the slope finite when the outcomes separate, as
they do when a policy fails below a threshold and succeeds above it (Firth 1993; Heinze & Schemper 2002). The
**breaking point** is the factor where the fitted success falls to half of the nominal success (the run's
nominal episodes of the same cells). Its interval, and the band around the curve, come from a bootstrap over
episodes (pairs resampled with replacement, the curve refitted): percentiles of the refitted breaking points.
A breaking point outside the drawn range is censored: the curve never reaches half of nominal within it (or is
below it at both ends); a bootstrap draw that is censored counts as beyond that end, so an interval may be
open on one side (null).

Entries are JSON-able with no NaN: what cannot be computed is null with a reason.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

MIN_DRAWS = 10  # fewer draws than this make no curve: two parameters and a bootstrap need more
GRID = 21  # points of the band
_MAX_ITER = 50


@dataclass(frozen=True)
class Fit:
    """A logistic fit on a standardised g(x): p = sigmoid(a + b (g(x) - centre) / spread)."""

    a: float
    b: float
    log: bool
    centre: float
    spread: float
    deviance: float

    def g(self, x: np.ndarray) -> np.ndarray:
        return ((np.log(x) if self.log else x) - self.centre) / self.spread

    def p(self, x: np.ndarray) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-(self.a + self.b * self.g(x))))

    def crossing(self, target: float) -> float | None:
        """The factor where p = target (None without a slope)."""
        if abs(self.b) < 1e-9 or not 0.0 < target < 1.0:
            return None
        z = (math.log(target / (1.0 - target)) - self.a) / self.b
        g = z * self.spread + self.centre
        if self.log:
            return math.exp(g) if g < 700 else math.inf
        return g


def _firth(z: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Firth-penalised logistic regression of y on [1, z]: (a, b, deviance of the unpenalised likelihood)."""
    X = np.column_stack([np.ones_like(z), z])
    beta = np.zeros(2)
    for _ in range(_MAX_ITER):
        p = 1.0 / (1.0 + np.exp(-(X @ beta)))
        w = np.clip(p * (1.0 - p), 1e-12, None)
        info = X.T @ (X * w[:, None])
        inv = np.linalg.inv(info + 1e-12 * np.eye(2))
        h = np.einsum("ij,jk,ik->i", X, inv, X) * w  # hat values of W^1/2 X
        step = inv @ (X.T @ (y - p + h * (0.5 - p)))
        step = np.clip(step, -5.0, 5.0)  # damped: the first steps of a separated sample are large
        beta = beta + step
        if np.max(np.abs(step)) < 1e-8:
            break
    p = np.clip(1.0 / (1.0 + np.exp(-(X @ beta))), 1e-12, 1 - 1e-12)
    deviance = float(-2.0 * np.sum(y * np.log(p) + (1 - y) * np.log(1 - p)))
    return float(beta[0]), float(beta[1]), deviance


def fit(x: np.ndarray, y: np.ndarray, log: bool | None = None) -> Fit:
    """The logistic curve of outcomes y (0/1) against factors x; `log` None: the factor or its log, whichever
    fits better (the log only when every factor is positive)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    options = [False, True] if log is None else [log]
    if np.any(x <= 0):
        options = [o for o in options if not o] or [False]
    best: Fit | None = None
    for use_log in options:
        g = np.log(x) if use_log else x
        centre, spread = float(np.mean(g)), float(np.std(g)) or 1.0
        a, b, dev = _firth((g - centre) / spread, y)
        cand = Fit(a, b, use_log, centre, spread, dev)
        if best is None or cand.deviance < best.deviance - 1e-9:
            best = cand
    assert best is not None  # options is never empty
    return best


def _censor(x: float | None, low: float, high: float) -> float:
    """A crossing outside [low, high] as -inf / +inf (the side it lies on); no crossing at all (a flat curve) as
    +inf: in neither case does success reach half of nominal within the drawn range."""
    if x is not None and low <= x <= high:
        return x
    return -math.inf if x is not None and x < low else math.inf


def curve(
    x: Sequence[float],
    y: Sequence[float],
    nominal: float,
    rng: np.random.Generator,
    n_boot: int = 1000,
    confidence: float = 0.95,
) -> dict[str, object]:
    """The fitted curve of success `y` against drawn factors `x`, its bootstrap band and the breaking point
    (the factor where success falls to half of `nominal`) with its percentile interval."""
    xs, ys = np.asarray(x, float), np.asarray(y, float)
    n = len(xs)
    if n < MIN_DRAWS:
        return {"n": n, "curve": None, "reason": f"{n} draws; a curve needs at least {MIN_DRAWS}"}
    low, high = float(xs.min()), float(xs.max())
    if high <= low:
        return {"n": n, "curve": None, "reason": "every draw has the same factor"}
    best = fit(xs, ys)
    target = nominal / 2.0
    grid = np.exp(np.linspace(math.log(low), math.log(high), GRID)) if best.log else np.linspace(low, high, GRID)
    boots_p = np.empty((n_boot, GRID))
    boots_x = np.empty(n_boot)
    for k in range(n_boot):
        idx = rng.integers(0, n, n)
        f = fit(xs[idx], ys[idx], log=best.log)
        pg = f.p(grid)
        boots_p[k] = pg
        boots_x[k] = _censor(f.crossing(target), low, high)
    alpha = (1.0 - confidence) / 2.0
    band_lo, band_hi = np.quantile(boots_p, [alpha, 1.0 - alpha], axis=0)
    p_grid = best.p(grid)
    point = _censor(best.crossing(target), low, high)
    # order statistics, not interpolation: censored draws are infinite
    lo = float(np.quantile(boots_x, alpha, method="lower"))
    hi = float(np.quantile(boots_x, 1.0 - alpha, method="higher"))
    out: dict[str, object] = {
        "n": n,
        "scale": "log" if best.log else "linear",
        "range": [round(low, 6), round(high, 6)],
        "successes": int(ys.sum()),
        "nominal": round(nominal, 6),
        "band": [
            {"x": round(float(g), 6), "p": round(float(p), 6), "lo": round(float(a), 6), "hi": round(float(b), 6)}
            for g, p, a, b in zip(grid, p_grid, band_lo, band_hi)
        ],
        "breaks_at": round(point, 6) if math.isfinite(point) else None,
        "ci": [round(v, 6) if math.isfinite(v) else None for v in (lo, hi)],
        "confidence": confidence,
    }
    if nominal <= 0:
        out["reason"] = "the nominal success is 0: there is no half of it to fall to"
    elif not math.isfinite(point):
        stays = p_grid.min() >= target
        out["reason"] = (
            "success stays above half of nominal over the drawn range"
            if stays
            else "success is below half of nominal over the whole drawn range"
        )
    return out
