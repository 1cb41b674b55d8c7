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
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bench.core.errors import ConfigError
from bench.protocols.suite import Condition
from bench.records import EpisodeRecord
from bench.sims.perturb.combine import SEP

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
    """Firth-penalised logistic regression of y on [1, z]: (a, b, deviance of the unpenalised likelihood).
    Newton steps on the modified score X'(y - p + h (1/2 - p)), the 2x2 algebra written out."""
    a = b = 0.0
    for _ in range(_MAX_ITER):
        p = 1.0 / (1.0 + np.exp(-(a + b * z)))
        w = np.clip(p * (1.0 - p), 1e-12, None)
        s0, s1, s2 = float(w.sum()), float(w @ z), float(w @ (z * z))  # the information X'WX
        det = s0 * s2 - s1 * s1 + 1e-18
        h = w * (s2 - 2.0 * s1 * z + s0 * z * z) / det  # hat values of W^1/2 X
        r = y - p + h * (0.5 - p)
        u0, u1 = float(r.sum()), float(r @ z)
        da = min(max((s2 * u0 - s1 * u1) / det, -5.0), 5.0)  # damped: a separated sample's first steps are large
        db = min(max((s0 * u1 - s1 * u0) / det, -5.0), 5.0)
        a, b = a + da, b + db
        if max(abs(da), abs(db)) < 1e-8:
            break
    p = np.clip(1.0 / (1.0 + np.exp(-(a + b * z))), 1e-12, 1 - 1e-12)
    deviance = float(-2.0 * np.sum(y * np.log(p) + (1 - y) * np.log(1 - p)))
    return a, b, deviance


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


def curves_of(
    records: Sequence[EpisodeRecord],
    rng: np.random.Generator,
    metric: str = "success_once",
    n_boot: int = 1000,
    confidence: float = 0.95,
) -> list[dict[str, object]]:
    """A curve for every range condition of a run (a factor drawn per episode: `uniform` / `loguniform`), pooled
    over its cells, against the nominal success of the same cells: one entry per condition, in name order.
    `records` as a summary holds them (`bench.records.dedupe`d: one per job)."""
    by_cond: dict[str, list[EpisodeRecord]] = defaultdict(list)
    for r in records:
        if r.error is None:
            by_cond[r.condition].append(r)
    out: list[dict[str, object]] = []
    for name in sorted(by_cond):
        recs = by_cond[name]
        axis = recs[0].axis
        if axis is None or "~" not in name or "~from(" in name or SEP in name:  # a combination: its part's curve
            continue
        drawn = [(r, v) for r in recs if isinstance(v := r.params.get(axis), (int, float)) and not isinstance(v, bool)]
        cells = {(r.task, r.robot, r.env) for r, _ in drawn}
        ref = [bool(getattr(r, metric)) for r in by_cond.get("nominal", []) if (r.task, r.robot, r.env) in cells]
        entry: dict[str, object] = {"condition": name, "axis": axis, "metric": metric}
        if not ref:
            out.append({**entry, "n": len(drawn), "curve": None, "reason": "no nominal episode of the same cells"})
            continue
        x = [float(v) for _, v in drawn]
        y = [float(bool(getattr(r, metric))) for r, _ in drawn]
        out.append({**entry, **curve(x, y, float(np.mean(ref)), rng, n_boot=n_boot, confidence=confidence)})
    return out


def breaking_sentence(entry: dict[str, object]) -> str:
    """One line for the console and the report: where the policy breaks along the axis, or why no point is given."""
    name, metric, point = entry["condition"], entry["metric"], entry.get("breaks_at")
    if not isinstance(point, (int, float)):
        return f"{name}: no breaking point ({entry.get('reason')})"
    ci = entry.get("ci")
    lo, hi = ci if isinstance(ci, list) and len(ci) == 2 else (None, None)
    nominal = entry.get("nominal")
    nom = float(nominal) if isinstance(nominal, (int, float)) else math.nan
    confidence = entry.get("confidence")
    conf = int(round(float(confidence) * 100)) if isinstance(confidence, (int, float)) else 95
    iv = f"[{'below the range' if lo is None else f'{lo:.3g}'}, {'beyond the range' if hi is None else f'{hi:.3g}'}]"
    return (
        f"{name}: this policy breaks at {entry['axis']} {point:.3g} {iv} ({conf}% bootstrap): there its fitted "
        f"{metric} falls to half of nominal ({nom * 100:.0f}% -> {nom * 50:.0f}%), over {entry['n']} draws"
    )


def check_curves(conditions: Sequence[Condition], draws: int) -> None:
    """A curve asked for (`perturb.AXIS.curve=uniform(a,b)`) with fewer than `MIN_DRAWS` draws (the run's
    episodes x cells) is refused: a logistic fit and its bootstrap need more (ConfigError naming the axis)."""
    for cond in conditions:
        if cond.spec.get("curve") and draws < MIN_DRAWS:
            raise ConfigError(
                f"perturb.{cond.axis}.curve: {draws} draws (episodes x cells); a curve needs at least {MIN_DRAWS}: "
                "more episodes= or cells, or a plain range (perturb.AXIS=uniform(a,b)) scored as a pooled drop"
            )
