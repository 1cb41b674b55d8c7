"""Bounded least squares on multi-step simulation error, with Jacobian intervals and conditioning checks.

Parameters are optimised in bound-normalised form z = (x - lo) / (hi - lo) in [0, 1], so one
finite-difference step suits a 95 kg mass and a 10 ms delay alike. The Jacobian is computed by
forward differences with all perturbed variants in one batched rollout.

Intervals are the usual (J^T J)^-1 sigma^2, inflated by the residual's integrated autocorrelation
time tau: within a truncated horizon the error of one initial state persists for many frames, so
the residual holds about n / tau independent values, not n. The same n_eff = n / tau enters the
information criteria, which would otherwise accept any improvement at all.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from bench.calibrate.model import Layout
from bench.replay.data import Recording
from bench.replay.simulate import Segments, Simulator, logged

Z_STEP = 1e-3  # finite-difference step in normalised units
# where the output moves in jumps (an effect with its own `fd_step`), finer tolerances only buy
# evaluations that wander between the jumps: the finest tolerance and the most evaluations asked for
ROUGH_TOL, ROUGH_NFEV = 1e-3, 8
VIF_WARN = 100.0  # variance inflation above which a parameter is reported ill-conditioned


class Objective:
    """Normalised residuals sim - log of a layout on a set of segments (positions, and logged velocities)."""

    def __init__(
        self, sim: Simulator, layout: Layout, segs: Segments, rec: Recording, scale: np.ndarray, channels: np.ndarray
    ) -> None:
        self.sim, self.layout, self.segs = sim, layout, segs
        self.channels = channels
        self.target = logged(rec, segs)[..., channels]
        self.weight = 1.0 / scale[channels]
        mask = segs.mask if segs.mask is not None else np.ones((len(segs), segs.length), bool)
        self.mask = np.broadcast_to(mask[..., None], self.target.shape)

    @property
    def size(self) -> int:
        return int(self.mask.sum())

    def simulate(self, xs: np.ndarray) -> np.ndarray:
        """Simulated channels for each parameter vector: (V, n, length, C)."""
        variants = [self.layout.realise(x) for x in np.atleast_2d(xs)]
        return self.sim.run(variants, self.segs)[..., self.channels]

    def residual_grid(self, xs: np.ndarray) -> np.ndarray:
        """Weighted residuals (V, n, length, C); zero where the mask is off."""
        r = (self.simulate(xs) - self.target[None]) * self.weight
        return np.where(self.mask[None], r, 0.0)

    def residuals(self, xs: np.ndarray) -> np.ndarray:
        """Flattened weighted residuals of the existing frames: (V, size)."""
        grid = self.residual_grid(xs)
        return grid[:, self.mask]


def autocorrelation_time(grid: np.ndarray) -> float:
    """Integrated autocorrelation time of residuals along each segment (initial positive sequence)."""
    r = grid.reshape(grid.shape[0], grid.shape[1], -1) if grid.ndim == 3 else grid
    r = np.moveaxis(r, 1, -1)  # (n, C, length)
    den = float(np.sum(r * r))
    length = r.shape[-1]
    if den <= 0 or length < 2:
        return 1.0
    tau = 1.0
    for k in range(1, length):
        rho = float(np.sum(r[..., k:] * r[..., :-k])) / den
        if rho <= 0.0:
            break
        tau += 2.0 * rho
    return float(min(max(tau, 1.0), length))


def information(ssr: float, k: int, n_eff: float, criterion: str) -> float:
    """AIC or BIC (up to a constant) of a least-squares fit with n_eff independent residuals."""
    penalty = math.log(max(n_eff, 2.0)) if criterion == "bic" else 2.0
    return n_eff * math.log(max(ssr, 1e-300) / max(n_eff, 1.0)) + k * penalty


@dataclass
class FitResult:
    """A fitted parameter vector with its uncertainty."""

    x: np.ndarray
    labels: list[str]
    ssr: float
    n: int
    tau: float
    sd: np.ndarray  # standard deviations (inf where not identifiable)
    cov: np.ndarray
    nfev: int
    success: bool
    warnings: list[str] = field(default_factory=list)

    @property
    def n_eff(self) -> float:
        return self.n / self.tau

    def interval(self, i: int, z: float = 1.96) -> tuple[float, float]:
        return float(self.x[i] - z * self.sd[i]), float(self.x[i] + z * self.sd[i])

    def excludes_zero(self, i: int) -> bool:
        lo, hi = self.interval(i)
        return bool(np.isfinite(self.sd[i]) and (lo > 0 or hi < 0))

    def contrast_excludes_zero(self, off: int, weights: np.ndarray) -> bool:
        """Whether the 95% interval of weights . x[off:off+len(weights)] excludes zero."""
        sl = slice(off, off + len(weights))
        if not np.all(np.isfinite(self.sd[sl])):
            return False
        value = float(weights @ self.x[sl])
        sd = float(np.sqrt(max(weights @ self.cov[sl, sl] @ weights, 0.0)))
        return abs(value) > 1.96 * sd


def fd_jacobian(obj: Objective, x: np.ndarray, f0: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    span = hi - lo
    z = (x - lo) / span
    h = obj.layout.fd_steps(Z_STEP)
    steps = np.where(z + h <= 1.0, h, -h)
    xs = np.repeat(x[None], len(x), axis=0)
    xs[np.arange(len(x)), np.arange(len(x))] += steps * span
    fs = obj.residuals(xs)
    return ((fs - f0[None]) / steps[:, None]).T  # (size, p) in normalised units


def covariance(
    jz: np.ndarray, r: np.ndarray, tau: float, span: np.ndarray, labels: list[str]
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Parameter covariance (physical units), standard deviations and conditioning warnings."""
    n, p = jz.shape
    warnings: list[str] = []
    if p == 0:
        return np.zeros((0, 0)), np.zeros(0), warnings
    a = jz.T @ jz
    diag = np.diag(a).copy()
    dead = diag <= 1e-12 * max(float(diag.max()), 1e-300)
    c = np.linalg.pinv(a, rcond=1e-12)
    sigma2 = float(r @ r) / max(n - p, 1)
    cov_z = tau * sigma2 * c
    cov = cov_z * span[:, None] * span[None, :]
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    sd[dead] = np.inf
    vif = np.diag(c) * diag
    dinv = 1.0 / np.sqrt(np.maximum(np.diag(c), 1e-300))
    corr = c * dinv[:, None] * dinv[None, :]
    for i in range(p):
        if dead[i]:
            warnings.append(f"{labels[i]}: no effect on the simulated output; not identifiable from these logs")
        elif vif[i] > VIF_WARN:
            row = np.abs(corr[i]).copy()
            row[i] = 0.0
            j = int(np.argmax(row)) if p > 1 else i
            partner = f"; most correlated with {labels[j]} (r={corr[i, j]:+.2f})" if p > 1 else ""
            warnings.append(f"{labels[i]}: ill-conditioned (variance inflation {vif[i]:.0f}){partner}")
    return cov, sd, warnings


def fit(obj: Objective, x0: np.ndarray, *, max_nfev: int = 40, tol: float = 1e-6, broyden: bool = False) -> FitResult:
    """Bounded least squares of the objective from x0; intervals and warnings at the optimum.

    `tol` is the relative cost and step tolerance; a coarse one is enough to judge a candidate, and
    where the output moves in jumps (contact events) no finer one than ROUGH_TOL is asked for, in at
    most ROUGH_NFEV evaluations.
    With `broyden`, the Jacobian is a finite-difference one at the start and rank-one (Broyden)
    updates after each step (one simulation per step instead of one per parameter), where the output
    is smooth and near-linear in the parameters (`Layout.smooth`); the one at the optimum, for the
    intervals, is a finite-difference one either way.
    """
    lo, hi = obj.layout.bounds
    span = hi - lo
    labels = obj.layout.labels
    x0 = np.clip(np.asarray(x0, float), lo, hi)
    z0 = (x0 - lo) / span
    broyden = broyden and obj.layout.smooth
    if any(c.effect.fd_step is not None for c in obj.layout.active):
        tol, max_nfev = max(tol, ROUGH_TOL), min(max_nfev, ROUGH_NFEV)
    grids: dict[bytes, np.ndarray] = {}  # the last residual grid and Jacobian, by normalised vector:
    jacs: dict[bytes, np.ndarray] = {}  # the optimum's are reused for the intervals
    last: list = []  # Broyden: the previous (z, f, J)

    def grid_at(z: np.ndarray) -> np.ndarray:
        key = z.tobytes()
        if key not in grids:
            grids.clear()
            grids[key] = obj.residual_grid((lo + z * span)[None])[0]
        return grids[key]

    def fun(z: np.ndarray) -> np.ndarray:
        return grid_at(z)[obj.mask]

    def broyden_jac(z: np.ndarray) -> np.ndarray:
        f = fun(z)
        if last:
            zp, fp, jp = last
            dz = z - zp
            j = jp + np.outer(f - fp - jp @ dz, dz) / max(float(dz @ dz), 1e-300)
        else:
            j = fd_jacobian(obj, lo + z * span, f, lo, hi)
        last[:] = [z.copy(), f, j]
        return j

    def exact_jac(z: np.ndarray) -> np.ndarray:
        key = z.tobytes()
        if key not in jacs:
            jacs.clear()
            jacs[key] = fd_jacobian(obj, lo + z * span, fun(z), lo, hi)
        return jacs[key]

    if len(x0):
        res = least_squares(
            fun,
            z0,
            jac=broyden_jac if broyden else exact_jac,
            bounds=(0.0, 1.0),
            method="trf",
            x_scale=1.0,
            ftol=tol,
            xtol=tol,
            gtol=1e-8,
            max_nfev=max_nfev,
        )
        z, nfev, success = res.x, res.nfev, bool(res.success)
    else:
        z, nfev, success = np.zeros(0), 0, True
    return optimum(obj, lo + z * span, grid_at(z), lambda r: exact_jac(z), span, labels, nfev, success)


def optimum(
    obj: Objective,
    x: np.ndarray,
    grid: np.ndarray,
    jacobian: Callable[[np.ndarray], np.ndarray],
    span: np.ndarray,
    labels: list[str],
    nfev: int,
    success: bool,
) -> FitResult:
    """The fit's result at `x` (residual `grid` there): intervals from `jacobian(residuals)` in normalised
    units, inflated by the residual's autocorrelation time, and their warnings. Every fitter reports this way."""
    r = grid[obj.mask]
    tau = autocorrelation_time(grid)
    jz = jacobian(r) if len(x) else np.zeros((len(r), 0))
    cov, sd, warnings = covariance(jz, r, tau, span, labels)
    return FitResult(
        x=x,
        labels=labels,
        ssr=float(r @ r),
        n=len(r),
        tau=tau,
        sd=sd,
        cov=cov,
        nfev=nfev,
        success=success,
        warnings=warnings,
    )
