"""Fitting a servo to its logs: bounded least squares on windows simulated from logged states (positions), plus the
firmware's P law against the logged duty where the servo logs it, intervals from the Jacobian, and a linear start.

The torque scale is declared (kt/R, the stall torque per volt): from positions alone a servo and its load are known
only up to one common factor (inertia, gravity torque, gains and friction all scale together); the logged duty, or
stretches where the PWM saturates, tie the gains to volts, and kt/R turns volts into N·m.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from bench.calibrate.servo.data import ServoRun
from bench.calibrate.servo.effects import DECLARED, SERVO_EFFECTS, Param, Scale
from bench.calibrate.servo.law import ServoParams, duty
from bench.calibrate.servo.sim import Windows, simulate, target_axis

Z95 = 1.96
FD_STEP = 1e-4  # finite-difference step in normalised units (each parameter over its own size)


@dataclass(frozen=True)
class DutyData:
    """Logged duty of the enabled frames of the fitted runs, with what the P law needs to predict it."""

    times: np.ndarray  # on the windows' shared time axis
    run_start: np.ndarray
    q: np.ndarray
    duty: np.ndarray
    label: np.ndarray


def duty_data(runs: list[ServoRun], labels: list[str], run_gap: float, stride: int = 1) -> DutyData | None:
    """The duty samples of `runs`, every `stride`-th enabled frame (None when no run logs its duty); indexes of
    `runs` give their place on the axis."""
    parts = [(i, r) for i, r in enumerate(runs) if r.duty is not None]
    if not parts:
        return None
    keep = [(r.enable > 0.5) & (np.arange(r.frames) % stride == 0) for _, r in parts]
    cat = lambda f: np.concatenate([f(i, r)[k] for (i, r), k in zip(parts, keep)])  # noqa: E731
    return DutyData(
        times=cat(lambda i, r: r.t + i * run_gap),
        run_start=cat(lambda i, r: np.full(r.frames, i * run_gap)),
        q=cat(lambda i, r: r.q),
        duty=cat(lambda i, r: r.duty),
        label=cat(lambda i, r: np.full(r.frames, labels.index(r.label))),
    )


@dataclass
class Problem:
    """What is fitted: the declared parameters, one gain per setting, and the parameters of the effects added."""

    base: ServoParams  # declared constants and the values of everything not fitted
    labels: list[str]
    effects: tuple[str, ...]
    scale: Scale

    @property
    def params(self) -> list[Param]:
        out = list(DECLARED)
        for e in self.effects:
            out += list(SERVO_EFFECTS[e].params)
        return out

    @property
    def names(self) -> list[str]:
        return [p.field for p in self.params] + [f"kp[{lab}]" for lab in self.labels]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        b = [p.bounds(self.scale) for p in self.params] + [(1e-6, 1e5)] * len(self.labels)
        return np.array([lo for lo, _ in b]), np.array([hi for _, hi in b])

    def vector(self, p: ServoParams, kp: np.ndarray) -> np.ndarray:
        return np.concatenate([[float(getattr(p, q.field)) for q in self.params], kp])

    def batch(self, X: np.ndarray) -> tuple[ServoParams, np.ndarray]:
        """The parameters of vectors X (P, k): every fitted field (P, 1), and the gains (P, settings)."""
        k = len(self.params)
        return self.base.with_(**{q.field: X[:, i : i + 1] for i, q in enumerate(self.params)}), X[:, k:]

    def servo(self, x: np.ndarray) -> tuple[ServoParams, np.ndarray]:
        """The parameters of vector `x` and the gain of each setting."""
        k = len(self.params)
        return self.base.with_(**{q.field: float(v) for q, v in zip(self.params, x[:k])}), np.asarray(x[k:])


def duty_goal(w: Windows, dd: DutyData, delay: Any, slowness: Any) -> np.ndarray:
    """The firmware's target at the duty samples (P, n) for delays and slownesses of shape (P, 1) or scalars."""
    d = np.ravel(np.asarray(delay, dtype=float))
    sl = np.ravel(np.asarray(slowness, dtype=float))
    P = max(d.size, sl.size)
    d, sl = np.broadcast_to(d, (P,)), np.broadcast_to(sl, (P,))
    axes: dict[float, np.ndarray] = {}
    out = np.empty((P, dd.times.size))
    for i in range(P):
        if float(sl[i]) not in axes:
            axes[float(sl[i])] = target_axis(w, float(sl[i]))
        ax = axes[float(sl[i])]
        out[i] = np.interp(np.maximum(dd.times - d[i], dd.run_start), w.axis_t, ax)
    return out


def residuals(prob: Problem, X: np.ndarray, w: Windows, dd: DutyData | None, sd_q: float, sd_d: float) -> np.ndarray:
    """Position errors of every window (in sd of the logged position) and duty errors (in sd of the logged duty),
    each block weighted by one over the root of its size so each weighs the same whatever the log's length;
    for a batch of vectors X (P, k): (P, n), simulated in one pass."""
    p, kp = prob.batch(X)
    sim = simulate(p.with_(kp=kp[:, w.label]), w)
    r = ((sim - w.target) / sd_q)[:, w.mask] / np.sqrt(max(int(w.mask.sum()), 1))
    if dd is None:
        return r
    g = duty_goal(w, dd, p.delay, p.goal_slowness)
    model = duty(p.with_(kp=kp[:, dd.label]), g, dd.q)
    return np.concatenate([r, (model - dd.duty) / sd_d / np.sqrt(dd.duty.size)], axis=1)


@dataclass(frozen=True)
class Fit:
    """A fitted vector, its cost, covariance (normalised residual units) and what it cost to get."""

    prob: Problem
    x: np.ndarray
    cost: float  # mean squared position error (in sd units) plus the duty block's
    cov: np.ndarray | None
    evaluations: int
    delta95: float | None = None  # a cost this much above `cost` is still inside the 95% region (3.84 s² tau)

    def servo(self) -> tuple[ServoParams, np.ndarray]:
        return self.prob.servo(self.x)

    def value(self, name: str) -> float:
        return float(self.x[self.prob.names.index(name)])

    def interval(self, name: str) -> list[float] | None:
        if self.cov is None:
            return None
        i = self.prob.names.index(name)
        sd = float(np.sqrt(max(self.cov[i, i], 0.0)))
        if not np.isfinite(sd):
            return None
        return [float(self.x[i] - Z95 * sd), float(self.x[i] + Z95 * sd)]


def _autocorr_time(r: np.ndarray, mask: np.ndarray) -> float:
    """Integrated autocorrelation time of the residuals along each window (frames), at least 1."""
    z = np.where(mask, r, 0.0)
    z = z - z.sum(axis=1, keepdims=True) / np.maximum(mask.sum(axis=1, keepdims=True), 1)
    z = np.where(mask, z, 0.0)
    var = float(np.sum(z * z))
    if var <= 0:
        return 1.0
    tau = 1.0
    for k in range(1, z.shape[1]):
        rho = float(np.sum(z[:, k:] * z[:, :-k])) / var
        if rho < 0.05:
            break
        tau += 2.0 * rho
    return min(tau, float(z.shape[1]))


def fit(
    prob: Problem,
    x0: np.ndarray,
    w: Windows,
    dd: DutyData | None,
    sd_q: float,
    sd_d: float,
    *,
    max_nfev: int = 60,
    covariance: bool = True,
) -> Fit:
    """Bounded least squares from `x0` (trust region reflective, finite differences in normalised units); the
    Jacobian's covariance unless `covariance` is false (a jackknife replicate needs only the vector)."""
    lo, hi = prob.bounds()
    span = np.maximum(np.abs(x0), 0.1 * (hi - lo) if np.all(np.isfinite(hi)) else 1.0)
    span = np.where(np.isfinite(span) & (span > 0), span, 1.0)
    x0c = np.clip(x0, lo, hi)
    lo_n, hi_n = lo / span, hi / span

    def fun(z: np.ndarray) -> np.ndarray:
        return residuals(prob, (z * span)[None], w, dd, sd_q, sd_d)[0]

    def jac(z: np.ndarray) -> np.ndarray:
        # forward differences, every coordinate in one batched simulation; stepped inwards at an upper bound
        h = np.where(z + FD_STEP > hi_n, -FD_STEP, FD_STEP)
        Z = np.vstack([z, z + np.diag(h)])
        R = residuals(prob, Z * span, w, dd, sd_q, sd_d)
        return ((R[1:] - R[0]) / h[:, None]).T

    res = least_squares(fun, x0c / span, jac=jac, bounds=(lo_n, hi_n), max_nfev=max_nfev, xtol=1e-6)
    x = res.x * span
    jm = np.asarray(res.jac)
    n, k = res.fun.size, x.size
    cov, delta95 = None, None
    if covariance and n > k:
        s2 = float(res.fun @ res.fun) / (n - k)
        npos = int(w.mask.sum())
        sim_r = res.fun[:npos]
        full = np.zeros(w.mask.shape)
        full[w.mask] = sim_r
        tau = _autocorr_time(full, w.mask)
        cov_n = np.linalg.pinv(jm.T @ jm) * s2 * tau
        # a parameter the residuals do not move (e.g. a goal velocity limit that never binds) is unbounded by the
        # data: pinv would give it zero variance, an interval that excludes anything
        flat = np.linalg.norm(jm, axis=0) <= 1e-9 * max(float(np.max(np.linalg.norm(jm, axis=0))), 1e-300)
        cov_n[flat, :] = 0.0
        cov_n[:, flat] = 0.0
        cov_n[flat, flat] = np.inf
        cov = cov_n * np.outer(span, span)
        delta95 = Z95**2 * s2 * tau
    return Fit(prob, x, float(res.fun @ res.fun), cov, int(res.nfev), delta95)


def window_score(w: Windows, sd_q: float) -> Callable[[ServoParams, np.ndarray], float]:
    """The mean squared position error of windows `w` in sd units for a servo and its gain per setting (the
    linear start's score of a trial gain)."""

    def score(p: ServoParams, kp: np.ndarray) -> float:
        return float(np.mean(((simulate(p.with_(kp=kp[w.label]), w) - w.target) / sd_q)[w.mask] ** 2))

    return score


def position_cost(prob: Problem, x: np.ndarray, w: Windows, sd_q: float) -> float:
    """Mean squared position error of windows `w` in sd units (the selection's and the report's k-step score)."""
    return window_score(w, sd_q)(*prob.servo(x))


def linear_start(
    runs: list[ServoRun],
    labels: list[str],
    base: ServoParams,
    grid: np.ndarray,
    score: Callable[[ServoParams, np.ndarray], float] | None = None,
) -> tuple[ServoParams, np.ndarray]:
    """A start by linear regression on the logged accelerations (no simulation):

    J ddq + kt/R kt dq [enabled] + c dq [off] + a sin q + b cos q = kt/R vin duty,

    with the logged duty where there is one (the gain then from duty = error_gain kp (goal - q) on the
    unsaturated frames), else the P law's duty for each gain of `grid`, the one whose solution `score`s best
    (a simulation: the regression alone prefers gains too small to ever saturate). Inertia,
    gravity torque m·g·l = hypot(a, b), offset atan2(b, a) and kt follow.
    """
    kp = np.ones(len(labels))
    for j, lab in enumerate(labels):
        mine = [r for r in runs if r.label == lab and r.duty is not None]
        if mine:
            e = np.concatenate([base.error_gain * (r.goal - r.q)[r.enable > 0.5] for r in mine])
            d = np.concatenate([r.duty[r.enable > 0.5] for r in mine if r.duty is not None])
            ok = np.abs(d) < 0.9 * base.max_duty
            kp[j] = float(np.sum(d[ok] * e[ok]) / max(float(np.sum(e[ok] ** 2)), 1e-12))

    def solve(kp: np.ndarray) -> tuple[np.ndarray, float]:
        rows, rhs = [], []
        for r in runs:
            d = r.duty if r.duty is not None else duty(base.with_(kp=kp[labels.index(r.label)]), r.goal, r.q)
            en = r.enable
            rows.append(np.stack([r.ddq, base.kt_over_r * en * r.dq, (1 - en) * r.dq, np.sin(r.q), np.cos(r.q)], 1))
            rhs.append(base.kt_over_r * r.vin * d * en)
        A, y = np.concatenate(rows), np.concatenate(rhs)
        sol, *_ = np.linalg.lstsq(A, y, rcond=None)
        return sol, float(np.sum((A @ sol - y) ** 2))

    if score is not None and any(r.duty is None for r in runs):
        # no duty logged: one gain for the settings without it, the one whose regression simulates best
        free = [j for j, lab in enumerate(labels) if any(r.label == lab and r.duty is None for r in runs)]
        best = (np.inf, kp)
        for g in grid:
            trial = kp.copy()
            trial[free] = g
            sol, _ = solve(trial)
            if sol[0] > 0:
                c = score(_from(base, sol), trial)
                best = min(best, (c, trial), key=lambda b: b[0])
        kp = best[1]
    sol, _ = solve(kp)
    return _from(base, sol), kp


def _from(base: ServoParams, sol: np.ndarray) -> ServoParams:
    """The servo of a linear-start solution (inertia, kt/R kt, viscous when off, a, b)."""
    return base.with_(
        inertia=max(float(sol[0]), 1e-5),
        kt=float(np.clip(sol[1], 0.0, 20.0)),
        gravity=float(np.hypot(sol[3], sol[4])),
        offset=float(np.clip(np.arctan2(sol[4], sol[3]), -0.5, 0.5)),
    )
