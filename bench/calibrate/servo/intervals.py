"""Honest intervals for a servo fit: the Jacobian's (noise only), a jackknife over whole training runs (model error:
how much a parameter moves when one run the model explains badly is left out) and, for quantities in N·m, the
declared torque scale's own spread (kt/R is declared, not fitted: every torque scales with it).

Jacobian intervals assume the model is right and only the noise differs between logs; on real servo logs the
residual is mostly model error, correlated over whole runs, and those intervals exclude the known truth (XL330: kp 800
fitted 787.9 [783.8, 792.1]). Leaving out each training run in turn and refitting (warm-started from the full fit,
few evaluations) gives the delete-one jackknife variance (n-1)/n sum (theta_i - mean)^2, which captures that
run-to-run model error; the reported sd is the root of the sum of the three variances, and the interval takes
Student's t at the Welch-Satterthwaite degrees of freedom (the jackknife's variance rests on n - 1 of them: with the
STS3250's 3 training runs, t = 4.30, not 1.96). Where no duty is logged the estimator's start (its gain chosen by
simulating the fitted runs) depends on which runs are fitted, so each refit starts there, without the left-out run,
not from the full fit, whose basin a warm start never leaves. Where no duty is logged, a
scale profile (refits from starts with gains and torques halved, and doubled, again and again) widens an interval to hold every refit
that fits as well as the full one (the STS3250's scale, fixed only by PWM saturation, is flat that way).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.stats import t as student_t

from bench.calibrate.servo.data import ServoRun
from bench.calibrate.servo.fit import Z95, DutyData, Fit, duty_data, fit
from bench.calibrate.servo.sim import RUN_GAP, Windows

JACKKNIFE_NFEV = 10  # evaluations of each leave-one-run-out refit (warm-started from the full fit)
COLD_NFEV = 40  # evaluations of a refit from the estimator's own start (as many as the final fit's)
SCALE_STEPS = (0.5, 2.0)  # the scale profile's steps down and up (no duty logged)
SCALE_WALK = 6  # steps at most each way (a factor 64)
TORQUE_UNITS = ("N·m", "N·m·s/rad", "kg·m²")  # scale with the declared kt/R (inertia: torque over acceleration)


@dataclass(frozen=True)
class Jackknife:
    """The full fit and its leave-one-run-out refits (`replicates[i]`: run `left_out[i]` not fitted)."""

    full: Fit
    replicates: np.ndarray  # (n, k) parameter vectors
    left_out: list[str]
    torque_sd: float  # relative sd of the declared torque scale kt/R
    alternates: np.ndarray | None = None  # (m, k) refits from rescaled starts that fit as well (`scale_profile`)

    def sd_parts(self, f: Callable[[np.ndarray], float], *, torque: bool) -> dict[str, float]:
        """The sd of a scalar function of the parameter vector, in its three parts (Jacobian, jackknife, kt/R)."""
        x = self.full.x
        v = float(f(x))
        out = {"jacobian": 0.0, "jackknife": 0.0, "torque_scale": abs(v) * self.torque_sd if torque else 0.0}
        if self.full.cov is not None:
            g = np.zeros_like(x)
            for i in range(x.size):  # central differences of f in each parameter's own size
                h = 1e-6 * max(abs(x[i]), 1e-9)
                xp, xm = x.copy(), x.copy()
                xp[i] += h
                xm[i] -= h
                g[i] = (f(xp) - f(xm)) / (2 * h)
            used = g != 0  # an unbounded parameter (infinite variance) counts only where f depends on it
            c = self.full.cov[np.ix_(used, used)]
            out["jacobian"] = float(np.sqrt(max(float(g[used] @ c @ g[used]), 0.0)))
        n = len(self.replicates)
        if n >= 2:
            vals = np.array([f(r) for r in self.replicates])
            out["jackknife"] = float(np.sqrt((n - 1) / n * np.sum((vals - vals.mean()) ** 2)))
        return out

    def interval(
        self, f: Callable[[np.ndarray], float], *, torque: bool, within: tuple[float, float] | None = None
    ) -> dict[str, Any]:
        """Value, 95% interval (the three variances summed, Student's t at their Welch-Satterthwaite degrees of
        freedom; cut to the parameter's range `within`, e.g. a gravity torque is not negative) and the sd of each
        part; None where the data do not bound it."""
        v = float(f(self.full.x))
        parts = self.sd_parts(f, torque=torque)
        sd = float(np.sqrt(sum(s * s for s in parts.values())))
        if not np.isfinite(sd):  # the data do not bound it
            return {"value": v, "interval": None, "sd": None}
        half = self.quantile(parts) * sd
        if len(self.replicates) >= 2:  # adding a known variance never narrows the jackknife's own interval
            half = max(half, float(student_t.ppf(0.975, len(self.replicates) - 1)) * parts["jackknife"])
        lo, hi = v - half, v + half
        if self.alternates is not None and len(self.alternates):  # other scales that fit as well: the span holds them
            alt = [float(f(a)) for a in self.alternates]
            lo, hi = min(lo, *alt), max(hi, *alt)
        if within is not None:
            lo, hi = max(lo, within[0]), min(hi, within[1])
        return {"value": v, "interval": [lo, hi], "sd": parts}

    def quantile(self, parts: dict[str, float]) -> float:
        """The 95% two-sided quantile for the summed variances: the jackknife's variance rests on n - 1 degrees of
        freedom (n runs left out in turn; 2 for the STS3250's 3 training runs, where 1.96 would pretend it is
        known), the Jacobian's and the declared kt/R's are taken as known (Welch-Satterthwaite: df =
        (sum s_i^2)^2 / sum s_i^4 / df_i)."""
        n = len(self.replicates)
        jk = parts.get("jackknife", 0.0)
        total = sum(s * s for s in parts.values())
        if n < 2 or jk <= 0 or total <= 0:
            return Z95
        df = total**2 / (jk**4 / (n - 1))
        return float(student_t.ppf(0.975, df))

    def parameter(self, name: str) -> dict[str, Any]:
        """The interval of one fitted parameter (torque-scaled when its unit is a torque, damping or inertia)."""
        i = self.full.prob.names.index(name)
        units = {p.field: p.unit for p in self.full.prob.params}
        lo, hi = self.full.prob.bounds()
        return self.interval(
            lambda x: float(x[i]), torque=units.get(name, "") in TORQUE_UNITS, within=(float(lo[i]), float(hi[i]))
        )


def jackknife(
    full: Fit,
    runs: list[ServoRun],
    w: Windows,
    sd_q: float,
    sd_d: float,
    torque_sd: float,
    *,
    duty_stride: int = 2,
    max_nfev: int = JACKKNIFE_NFEV,
    cold_start: Callable[[int], np.ndarray] | None = None,
    cold_nfev: int = COLD_NFEV,
) -> Jackknife:
    """Refit `full`'s problem leaving out each run of `runs` in turn (its windows and its duty samples); `w` are
    the windows `full` was fitted on, over `runs` in that order. A run whose gain setting no other run shares is
    kept (leaving it out would leave that gain unfitted, not resampled).

    Each refit starts from the full fit (`max_nfev` evaluations) or, with `cold_start`, from `cold_start(i)`: the
    start the estimator itself would take without run i (`cold_nfev` evaluations). A warm start stays in the full
    fit's basin; where the start depends on which runs are fitted (no duty logged: the gain from a grid of
    simulations) only the cold one shows what the estimate is without a run."""
    labels = full.prob.labels
    reps, names = [], []
    for i, r in enumerate(runs):
        if sum(o.label == r.label for o in runs) < 2:
            continue
        keep = w.run != i
        dd: DutyData | None = duty_data(
            [o if j != i else _no_duty(o) for j, o in enumerate(runs)], labels, RUN_GAP, stride=duty_stride
        )
        x0, nfev = (full.x, max_nfev) if cold_start is None else (cold_start(i), cold_nfev)
        f = fit(full.prob, x0, w.subset(keep), dd, sd_q, sd_d, max_nfev=nfev, covariance=False)
        reps.append(f.x)
        names.append(r.name)
    return Jackknife(full, np.array(reps).reshape(len(reps), full.x.size), names, torque_sd)


def scale_profile(
    full: Fit, w: Windows, sd_q: float, steps: tuple[float, ...] = SCALE_STEPS, *, max_nfev: int = 30
) -> np.ndarray:
    """Refits of `full` (no duty logged) along the servo's scale: from the last refit, the gains and every
    torque-scaled parameter multiplied by each step in turn, as long as the refit's cost stays within `full.delta95`
    of the full fit's (inside the 95% region), at most `SCALE_WALK` times per step; those refits are returned.

    Without a logged duty the scale of gains and torques is fixed only by stretches where the PWM saturates; with
    few of them the cost is flat along that scale and a local interval (Jacobian, jackknife) misses it."""
    if full.delta95 is None:
        return np.zeros((0, full.x.size))
    units = {p.field: p.unit for p in full.prob.params}
    scaled = np.array([units.get(n, "") in TORQUE_UNITS or n.startswith("kp[") for n in full.prob.names])
    keep = []
    for step in steps:
        x = full.x
        for _ in range(SCALE_WALK):
            f = fit(full.prob, np.where(scaled, x * step, x), w, None, sd_q, 1.0, max_nfev=max_nfev, covariance=False)
            if f.cost - full.cost > full.delta95:
                break
            keep.append(f.x)
            x = f.x
    return np.array(keep).reshape(len(keep), full.x.size)


def _no_duty(r: ServoRun) -> ServoRun:
    """The run without its duty samples (left out of the duty block too)."""
    return replace(r, duty=None)
