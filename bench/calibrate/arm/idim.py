"""Inverse-dynamics identification (IDIM-LS) of an arm in a MuJoCo model: the fit and its intervals.

The joint torque of a rigid arm is linear in each link's ten standard inertial parameters (mass,
first moment m·c, inertia about the link frame's origin) and in the usual joint terms (Coulomb and
viscous friction, a constant offset, rotor inertia): tau = Y(q, dq, ddq) theta, Y from MuJoCo
(`bench.calibrate.arm.dynamics`), in blocks of columns (`Block`: a link, a joint's friction, an effect).

The fit is weighted least squares (each joint's equations divided by that joint's residual spread),
with bounds where physics sets them (a mass, a friction, a rotor inertia are not negative) and a
faint pull of the inertial corrections toward the declared model: directions the data do not excite
stay at the declared values instead of wandering (`identifiability` says which parameters those
are). Intervals come from a window bootstrap of the training data (the residuals of one trajectory
are correlated in time, so whole windows are resampled), which also gives the draws that
`perturb.AXIS=from(CALIBRATION)` samples from.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bench.calibrate.arm.inertial import LOG_DIAG, factor_of, physical, std_of_factor
from bench.core.errors import DataError

FRICTION_V = 0.02  # rad/s: the Coulomb sign is smoothed as tanh(dq / FRICTION_V)


def prior_scale(p: np.ndarray) -> np.ndarray:
    """How far a link's declared parameters may be off, per parameter: all of their own size (a declared
    inertia may be a placeholder), at least 0.5 kg, m x 0.1 m and 0.01 kg m^2."""
    mass = max(float(p[0]), 0.5)
    first = max(float(np.max(np.abs(p[1:4]))), 0.1 * mass)
    inertia = max(float(np.max(np.abs(p[4:]))), 0.01)
    return np.array([mass, first, first, first, *([inertia] * 6)])


NULL_TOL = 1e-6  # singular values below this share of the largest span the unexcited directions
LAMBDA = 10.0  # the pull toward the declared values weighs as much as this many weighted residuals
MIN_MASS = 0.05  # kg: a link lighter than this is not a link
COM_RADIUS = 0.3  # m: a link's centre of mass lies within this distance of its frame (an arm's links are < 0.5 m)
COM_TOL, FENCE_WEIGHT = 0.01, 100.0  # the fence's residual: FENCE_WEIGHT per COM_TOL beyond it


@dataclass
class Block:
    """Columns of the regressor that belong to one parameter group (a link, a joint's friction, an effect)."""

    name: str  # e.g. "link:robot0_link3", "coulomb:robot0_joint2", "payload"
    labels: list[str]  # one per parameter
    cols: np.ndarray  # (N, n, k)
    lo: np.ndarray  # (k,) bounds of the parameter values
    hi: np.ndarray
    prior: np.ndarray  # (k,) declared values (what the parameters are pulled toward where unexcited)
    scale: np.ndarray  # (k,) prior spread; np.inf = no pull
    kind: str = "declared"  # declared | effect
    pseudo: bool = False  # a link's standard parameters, kept physical (log-Cholesky of its pseudo-inertia)
    region: tuple[np.ndarray, float] | None = None  # [mass, m c (3)] block: its centre of mass within (centre, radius)

    @property
    def size(self) -> int:
        return len(self.labels)


@dataclass
class Fit:
    """A weighted, bounded least-squares fit of the signal on some blocks."""

    blocks: list[Block]
    x: np.ndarray  # parameter values, block after block
    weights: np.ndarray  # (n,) 1 / residual spread per joint (training data)
    cov: np.ndarray  # covariance of x (inflated by the residuals' autocorrelation time)
    tau: float  # integrated autocorrelation time of the weighted training residuals
    ssr: float  # weighted training sum of squares
    n: int  # training residuals
    at_bound: list[str] = field(default_factory=list)

    def values(self, name: str) -> np.ndarray:
        off = 0
        for b in self.blocks:
            if b.name == name:
                return self.x[off : off + b.size]
            off += b.size
        raise KeyError(name)

    def offset(self, name: str) -> int:
        off = 0
        for b in self.blocks:
            if b.name == name:
                return off
            off += b.size
        raise KeyError(name)

    @property
    def labels(self) -> list[str]:
        return [lab for b in self.blocks for lab in b.labels]

    def sd(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))


def design(blocks: list[Block], rows: np.ndarray) -> np.ndarray:
    """(len(rows), n, K) regressor of the chosen sample rows."""
    return np.concatenate([b.cols[rows] for b in blocks], axis=-1)


def predict(blocks: list[Block], x: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """(N, n) modelled signal: the fixed part plus every block times its parameters."""
    return fixed + np.einsum("njk,k->nj", np.concatenate([b.cols for b in blocks], axis=-1), x)


def bounds_of(blocks: list[Block]) -> tuple[np.ndarray, np.ndarray]:
    return np.concatenate([b.lo for b in blocks]), np.concatenate([b.hi for b in blocks])


@dataclass
class Problem:
    """A fit compressed to its normal equations: ||b - R x||^2 is the weighted SSR up to a constant."""

    r: np.ndarray  # (K, K)
    b: np.ndarray  # (K,)
    const: float  # the part of the SSR no parameter reaches
    n: int  # weighted residuals behind it


def compress(blocks: list[Block], signal: np.ndarray, fixed: np.ndarray, rows: np.ndarray, w: np.ndarray) -> Problem:
    a = (design(blocks, rows) * w[None, :, None]).reshape(-1, sum(b.size for b in blocks))
    y = ((signal - fixed)[rows] * w[None, :]).reshape(-1)
    return from_gram(a.T @ a, a.T @ y, float(y @ y), y.size)


def from_gram(g: np.ndarray, ay: np.ndarray, yy: float, n: int) -> Problem:
    lam, vec = np.linalg.eigh(g)
    lam = np.maximum(lam, 0.0)
    root = (vec * np.sqrt(lam)) @ vec.T
    b = np.linalg.lstsq(root, ay, rcond=1e-13)[0]
    return Problem(root, b, yy - float(b @ b), n)


def _trf(fun, jac, z0: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_it: int) -> np.ndarray:
    """scipy's trust-region reflective least squares within the box (the problems are small: a compressed
    regressor), at most `max_it` evaluations."""
    from scipy.optimize import least_squares  # scipy: loaded only when a fit is computed

    z0 = np.clip(z0, np.where(np.isfinite(lo), lo + 1e-12, lo), np.where(np.isfinite(hi), hi - 1e-12, hi))
    res = least_squares(
        fun,
        z0,
        jac=jac,
        bounds=(lo, hi),
        method="trf",
        x_scale="jac",
        xtol=1e-9,
        ftol=1e-10,
        gtol=1e-9,
        max_nfev=max_it,
    )
    return res.x


def _solve(
    pb: Problem,
    blocks: list[Block],
    lam: float,
    x0: np.ndarray | None = None,
    max_it: int = 300,
    hold_links: bool = False,
    one_step: bool = False,
    fences: bool = True,
) -> np.ndarray:
    """Bounded least squares of the compressed problem; link blocks through their log-Cholesky factor
    (always a physical body), every parameter with a prior scale pulled faintly toward its prior."""
    sizes = [b.size for b in blocks]
    offs = np.concatenate([[0], np.cumsum(sizes)])
    prior = np.concatenate([b.prior for b in blocks])
    scale = np.concatenate([b.scale for b in blocks])
    lo, hi = bounds_of(blocks)
    pulled = np.flatnonzero(np.isfinite(scale))
    links = [i for i, b in enumerate(blocks) if b.pseudo]
    if hold_links and x0 is not None and links:  # links as they are: the rest is a convex problem
        from scipy.optimize import lsq_linear  # scipy: loaded only when a fit is computed

        held = np.zeros(len(prior), bool)
        for i in links:
            held[offs[i] : offs[i + 1]] = True
        x = np.asarray(x0, dtype=np.float64).copy()
        rest = ~held
        a = pb.r[:, rest]
        y = pb.b - pb.r[:, held] @ x[held]
        pr = [k for k in pulled if rest[k]]
        if pr:
            pen = np.zeros((len(pr), len(prior)))
            pen[np.arange(len(pr)), pr] = np.sqrt(lam) / scale[pr]
            a, y = np.vstack([a, pen[:, rest]]), np.concatenate([y, pen[:, rest] @ prior[rest]])
        norm = np.maximum(np.linalg.norm(a, axis=0), 1e-300)
        x[rest] = lsq_linear(a / norm, y, bounds=(lo[rest] * norm, hi[rest] * norm), method="bvls").x / norm
        return x
    if x0 is None:  # the convex problem without the links' physics, then each link nudged inside it
        from scipy.optimize import lsq_linear  # scipy: loaded only when a fit is computed

        pen = np.zeros((len(pulled), len(prior)))
        pen[np.arange(len(pulled)), pulled] = np.sqrt(lam) / scale[pulled]
        a = np.vstack([pb.r, pen])
        y = np.concatenate([pb.b, pen @ prior])
        norm = np.maximum(np.linalg.norm(a, axis=0), 1e-300)
        x0 = lsq_linear(a / norm, y, bounds=(lo * norm, hi * norm), method="bvls").x / norm
    start = np.clip(x0, lo, hi)
    z0, zlo, zhi = start.copy(), lo.copy(), hi.copy()
    for i in links:
        sl = slice(offs[i], offs[i + 1])
        z0[sl], zlo[sl], zhi[sl] = factor_of(start[sl]), -np.inf, np.inf
        zlo[offs[i] + LOG_DIAG], zhi[offs[i] + LOG_DIAG] = -25.0, 8.0  # exp(-25)..exp(8): a factor's scale, never inf
    z0 = np.clip(z0, zlo, zhi)
    sq = np.sqrt(lam)

    link_idx = np.array([np.arange(offs[i], offs[i + 1]) for i in links], dtype=np.int64).reshape(len(links), 10)
    regions = [(int(offs[i]), b.region) for i, b in enumerate(blocks) if b.region is not None]

    def params(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x, dx = z.copy(), np.eye(len(z))
        if links:
            std, jac = std_of_factor(z[link_idx])
            x[link_idx] = std
            for li, idx in enumerate(link_idx):
                dx[np.ix_(idx, idx)] = jac[li]
        return x, dx

    def fence(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Plausibility of each link, as residuals that are zero inside: mass >= MIN_MASS, and the
        centre of mass within COM_RADIUS of the link frame; and their gradients in x."""
        rows, grads = [], []
        for idx in link_idx:
            m, h = x[idx[0]], x[idx[1:4]]
            g_m = np.zeros(len(x))
            g_m[idx[0]] = -FENCE_WEIGHT / MIN_MASS
            rows.append(FENCE_WEIGHT * max(0.0, MIN_MASS - m) / MIN_MASS)
            grads.append(g_m if m < MIN_MASS else np.zeros(len(x)))
            mm = max(m, MIN_MASS)
            dist = float(np.linalg.norm(h)) / mm
            g_c = np.zeros(len(x))
            if dist > COM_RADIUS:
                g_c[idx[1:4]] = FENCE_WEIGHT / COM_TOL * h / (np.linalg.norm(h) * mm)
                if m > MIN_MASS:
                    g_c[idx[0]] = -FENCE_WEIGHT / COM_TOL * dist / mm
            rows.append(FENCE_WEIGHT * max(0.0, dist - COM_RADIUS) / COM_TOL)
            grads.append(g_c)
        for lo_i, (centre, radius) in regions if fences else []:
            m, h = x[lo_i], x[lo_i + 1 : lo_i + 4]
            u = h - m * centre  # |u| <= radius m: the centre of mass h / m within the region (a convex cone)
            dist = float(np.linalg.norm(u))
            scale = FENCE_WEIGHT / (COM_TOL * max(m, MIN_MASS))
            rows.append(scale * max(0.0, dist - radius * m))
            g = np.zeros(len(x))
            if dist > radius * m and dist > 0:
                g[lo_i + 1 : lo_i + 4] = scale * u / dist
                g[lo_i] = scale * (-(u @ centre) / dist - radius)
            grads.append(g)
        if not rows:
            return np.zeros(0), np.zeros((0, len(x)))
        return np.array(rows), np.array(grads)

    def fun(z: np.ndarray) -> np.ndarray:
        x, _ = params(z)
        return np.concatenate([pb.b - pb.r @ x, sq * (x[pulled] - prior[pulled]) / scale[pulled], fence(x)[0]])

    def jac(z: np.ndarray) -> np.ndarray:
        x, dx = params(z)
        return np.vstack([-pb.r @ dx, (sq / scale[pulled])[:, None] * dx[pulled], fence(x)[1] @ dx])

    if one_step:  # one Gauss-Newton step from x0 (a bootstrap replicate near the fit), box kept
        from scipy.optimize import lsq_linear  # scipy: loaded only when a fit is computed

        r0, j0 = fun(z0), jac(z0)
        d = np.maximum(np.linalg.norm(j0, axis=0), 1e-300)
        step = lsq_linear(j0 / d, -r0, bounds=((zlo - z0) * d, (zhi - z0) * d), method="bvls").x / d
        return params(np.clip(z0 + step, zlo, zhi))[0]
    return params(_trf(fun, jac, z0, zlo, zhi, max_it))[0]


def fit(
    blocks: list[Block],
    signal: np.ndarray,
    fixed: np.ndarray,
    train: np.ndarray,
    *,
    weights: np.ndarray | None = None,
    lam: float = LAMBDA,
    x0: np.ndarray | None = None,
    hold_links: bool = False,
    fences: bool = True,
) -> Fit:
    """Weighted bounded least squares of `signal - fixed` on `blocks` over the `train` rows.

    Without `weights`, an unweighted fit gives each joint's residual spread, and the fit is repeated
    with 1 / spread per joint (the usual two-step weighted IDIM). `lam` weighs the pull toward the
    declared values (each parameter with a finite prior scale), in weighted residuals (LAMBDA).
    """
    rows = np.flatnonzero(train)
    n_j = signal.shape[1]
    if weights is None:
        x1 = _solve(compress(blocks, signal, fixed, rows, np.ones(n_j)), blocks, lam)
        r1 = (signal - fixed)[rows] - np.einsum("njk,k->nj", design(blocks, rows), x1)
        weights = 1.0 / np.maximum(r1.std(axis=0), 1e-9)
    pb = compress(blocks, signal, fixed, rows, weights)
    x = _solve(pb, blocks, lam, x0, hold_links=hold_links, fences=fences)
    return fit_at(blocks, x, signal, fixed, train, weights, gram=pb.r.T @ pb.r)


def fit_at(
    blocks: list[Block],
    x: np.ndarray,
    signal: np.ndarray,
    fixed: np.ndarray,
    train: np.ndarray,
    weights: np.ndarray,
    gram: np.ndarray | None = None,
) -> Fit:
    """The `Fit` of parameters `x` on these rows: residual sum of squares, autocorrelation time, covariance.

    What `fit` returns for its solution, and how an estimate found on other samples (the forward
    refinement's simulated ones) is stated on the logged training rows.
    """
    from bench.calibrate.fit import autocorrelation_time  # scipy via fit: loaded only when a fit is computed

    rows = np.flatnonzero(train)
    a3 = design(blocks, rows)
    if gram is None:
        a = (a3 * weights[None, :, None]).reshape(-1, len(x))
        gram = a.T @ a
    r = ((signal - fixed)[rows] - np.einsum("njk,k->nj", a3, x)) * weights[None, :]
    tau = autocorrelation_time(r[None, :, :])
    ssr = float(np.sum(r**2))
    dof = max(r.size - len(x), 1)
    lo, hi = bounds_of(blocks)
    free = ~(np.isclose(x, lo, rtol=0, atol=1e-12) | np.isclose(x, hi, rtol=0, atol=1e-12))
    cov = np.zeros((len(x), len(x)))
    if free.any():
        cov[np.ix_(free, free)] = tau * ssr / dof * np.linalg.pinv(gram[np.ix_(free, free)], rcond=1e-12)
    labels = [lab for b in blocks for lab in b.labels]
    prior = np.concatenate([b.prior for b in blocks])
    at_bound = [
        labels[i]
        for i in np.flatnonzero(~free)
        if (np.isfinite(lo[i]) or np.isfinite(hi[i])) and not np.isclose(x[i], prior[i])
    ]
    return Fit(blocks, x, weights, cov, tau, ssr, int(r.size), at_bound)


def identifiability(blocks: list[Block], train: np.ndarray, weights: np.ndarray) -> dict[str, dict]:
    """Per parameter: identified alone, only in combination with others (named), or not at all.

    From the SVD of the weighted, column-normalised training regressor: the share of a parameter's
    unit vector in the unexcited subspace (singular values below NULL_TOL of the largest) is 0 for a
    parameter the data pin down alone, 1 for one they say nothing about, in between for one they
    only fix in combination.
    """
    rows = np.flatnonzero(train)
    a = (design(blocks, rows) * weights[None, :, None]).reshape(-1, sum(b.size for b in blocks))
    norm = np.linalg.norm(a, axis=0)
    labels = [lab for b in blocks for lab in b.labels]
    out: dict[str, dict] = {}
    zero = norm <= 1e-12 * max(float(norm.max()), 1e-300)
    an = a / np.where(zero, 1.0, norm)
    _, s, vt = np.linalg.svd(an, full_matrices=False)
    null = vt[s < NULL_TOL * s[0]]
    for i, lab in enumerate(labels):
        if zero[i]:
            out[lab] = {"status": "not identifiable", "why": "the data do not move the torque with it"}
            continue
        share = float(np.sum(null[:, i] ** 2)) if len(null) else 0.0
        if share < 0.01:
            out[lab] = {"status": "identified"}
        elif share > 0.99:
            out[lab] = {"status": "not identifiable", "why": "no excitation: left at its declared value"}
        else:
            w = np.abs(null.T @ null[:, i])
            w[i] = 0.0
            partners = [labels[j] for j in np.argsort(-w)[:3] if w[j] > 0.05 * share]
            out[lab] = {"status": "in combination", "with": partners, "unexcited_share": round(share, 3)}
    return out


def windows_of(t: np.ndarray, train: np.ndarray, length_s: float) -> np.ndarray:
    """Window index of every training row (contiguous stretches of `length_s` seconds); -1 elsewhere."""
    out = np.full(len(t), -1, dtype=np.int64)
    rows = np.flatnonzero(train)
    if rows.size == 0:
        raise DataError("no training samples left for the fit (a shorter holdout or a longer log)")
    out[rows] = np.floor((t[rows] - t[rows[0]]) / length_s).astype(np.int64)
    return out


def _linear(pb: Problem, blocks: list[Block], lam: float) -> np.ndarray:
    """The convex problem: every parameter linear (links unconstrained), bounds kept, the faint pull."""
    from scipy.optimize import lsq_linear  # scipy: loaded only when a fit is computed

    prior = np.concatenate([b.prior for b in blocks])
    scale = np.concatenate([b.scale for b in blocks])
    lo, hi = bounds_of(blocks)
    pulled = np.flatnonzero(np.isfinite(scale))
    pen = np.zeros((len(pulled), len(prior)))
    pen[np.arange(len(pulled)), pulled] = np.sqrt(lam) / scale[pulled]
    a = np.vstack([pb.r, pen])
    y = np.concatenate([pb.b, pen @ prior])
    norm = np.maximum(np.linalg.norm(a, axis=0), 1e-300)
    return lsq_linear(a / norm, y, bounds=(lo * norm, hi * norm), method="bvls").x / norm


def bootstrap(
    blocks: list[Block],
    signal: np.ndarray,
    fixed: np.ndarray,
    windows: np.ndarray,
    weights: np.ndarray,
    draws: int,
    seed: int,
    x0: np.ndarray,
    lam: float = LAMBDA,
) -> np.ndarray:
    """(draws, K) parameter vectors for training windows drawn with replacement (seeded).

    Each replicate moves the fit `x0` by what resampling moves the convex (all-linear) solution,
    x0 + (x_b - x_all); bounds are kept and a link that leaves the physical set is put back on its
    nearest physical point. Cheap (one small linear solve per replicate) and centred on the fit.
    """
    k = sum(b.size for b in blocks)
    if draws <= 0:
        return np.zeros((0, k))
    ids = np.unique(windows[windows >= 0])
    grams, ays, yys, ns = [], [], [], []
    for w in ids:
        rows = np.flatnonzero(windows == w)
        a = (design(blocks, rows) * weights[None, :, None]).reshape(-1, k)
        y = ((signal - fixed)[rows] * weights[None, :]).reshape(-1)
        grams.append(a.T @ a)
        ays.append(a.T @ y)
        yys.append(float(y @ y))
        ns.append(y.size)
    g_all, ay_all, yy_all, n_all = np.stack(grams), np.stack(ays), np.array(yys), np.array(ns)
    base = _linear(from_gram(g_all.sum(0), ay_all.sum(0), float(yy_all.sum()), int(n_all.sum())), blocks, lam)
    lo, hi = bounds_of(blocks)
    offs = np.concatenate([[0], np.cumsum([b.size for b in blocks])])
    rng = np.random.default_rng(seed)
    out = np.empty((draws, k))
    for i in range(draws):
        pick = rng.integers(0, len(ids), len(ids))
        pb = from_gram(g_all[pick].sum(0), ay_all[pick].sum(0), float(yy_all[pick].sum()), int(n_all[pick].sum()))
        x = np.clip(x0 + (_linear(pb, blocks, lam) - base), lo, hi)
        for bi, b in enumerate(blocks):
            if b.pseudo:
                x[offs[bi] : offs[bi + 1]] = physical(x[offs[bi] : offs[bi + 1]])
        out[i] = x
    return out
