"""Signatures: how the simulated output moves when a candidate effect is switched on from zero.

Each candidate (effect x target) is perturbed from zero by a finite step; the change of the
simulated held-out horizons is its signature. It is fitted to the held-out residual together with
the sensitivities of the parameters already in the model (a linearised refit, as in a score test),
so a candidate scores only for what re-tuning the current parameters cannot explain. All variants
of a round run in one batched rollout.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import lsq_linear

from bench.calibrate.effects import SIGNATURE_LEVELS, signature_steps
from bench.calibrate.fit import Objective, information
from bench.calibrate.model import Candidate, Layout

CUR_STEP = 1e-2  # step for the current parameters' sensitivities (normalised units)
SHAPE_GRID = (0.05, 0.15, 0.4)  # shares of a shape parameter's range tried before a refit
SCAN_STARTS = 3  # best scanned amplitudes (`Effect.scan`) checked on held-out data before a refit


class Linearisation:
    """The residual of the current model on a set of segments and its sensitivities to the current
    parameters: what a change of the simulated output leaves after re-tuning them (linearised)."""

    def __init__(
        self,
        obj: Objective,
        base: np.ndarray,
        cur_steps: np.ndarray,
        moved: np.ndarray,
        dlo: np.ndarray,
        dhi: np.ndarray,
    ) -> None:
        self.obj, self.base, self.dlo, self.dhi = obj, base, dlo, dhi
        self.r = ((base - obj.target) * obj.weight)[obj.mask]  # sim - log
        cols = [self.change(m) / h for m, h in zip(moved, cur_steps)]
        self.jcur = np.stack(cols, axis=1) if cols else np.zeros((len(self.r), 0))

    def change(self, pred: np.ndarray) -> np.ndarray:
        """Weighted change of the simulated channels (n, length, C) from the current model's."""
        return ((pred - self.base) * self.obj.weight)[self.obj.mask]

    def best(
        self, cols: np.ndarray, lo: np.ndarray, hi: np.ndarray, res: np.ndarray | None = None
    ) -> tuple[float, np.ndarray]:
        """Least SSR of res + cols @ u over the bounded u, and u."""
        res = self.r if res is None else res
        if cols.shape[1] == 0 or not np.any(cols):
            return float(res @ res), np.zeros(cols.shape[1])
        sol = lsq_linear(cols, -res, bounds=(np.minimum(lo, 0.0), np.maximum(hi, 0.0)), method="bvls").x
        return float(np.sum((res + cols @ sol) ** 2)), sol

    def retune(self, change: np.ndarray) -> tuple[float, np.ndarray]:
        """SSR left after a change of the output, with the current parameters re-tuned; their change."""
        return self.best(self.jcur, self.dlo, self.dhi, self.r + change)


@dataclass
class Score:
    """How much of the held-out residual one candidate's signature explains."""

    cand: Candidate
    replaces: Candidate | None
    score: float  # share of the residual's sum of squares explained
    predicted: float  # information-criterion change this predicts (negative = better)
    step: np.ndarray  # best change of the candidate's amplitude parameters along its signature
    delta: np.ndarray  # the accompanying change of the current parameters
    # threshold effects: the simulated signature points (amplitude change, current parameters re-tuned
    # to the exact change they make), where a secant says little
    points: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    lin: Linearisation | None = None  # the round's linearisation (to re-tune the current parameters)

    def to_json(self) -> dict:
        return {
            "name": self.cand.effect.name,
            "target": self.cand.target.label,
            "score": round(self.score, 6),
            "predicted_delta_ic": round(self.predicted, 3),
            **({"replaces": self.replaces.key} if self.replaces else {}),
        }


def relation(cand: Candidate, active: list[Candidate]) -> tuple[str, Candidate | None]:
    """'new', 'replace' (generalises an active effect on the same target) or 'skip'.

    A family that generalises another (Stribeck or asymmetric over Coulomb friction) is only offered
    as a replacement of it: the simpler family has to earn its place first; unless it is `standalone`
    (a spring with its own rest position generalises a bias, and is also a family of its own).
    """
    for a in active:
        if a.target != cand.target:
            continue
        if a.effect.name == cand.effect.name or cand.effect.name in a.effect.extends:
            return "skip", a
        if a.effect.name in cand.effect.extends:
            return "replace", a
        if set(a.effect.fields) & set(cand.effect.fields) or (a.effect.group and a.effect.group == cand.effect.group):
            return "skip", a
    if cand.effect.extends and not cand.effect.standalone:
        return "skip", None
    return "new", None


def with_candidate(
    layout: Layout, x: np.ndarray, cand: Candidate, replaces: Candidate | None, params: np.ndarray
) -> tuple[Layout, np.ndarray, int]:
    """Layout and vector with `cand` added (or swapped in for `replaces`); offset of its parameters."""
    if replaces is None:
        new = Layout(layout.plant, layout.active + [cand])
        return new, np.concatenate([x, params]), len(x)
    off = layout.offset(replaces)
    k = len(replaces.effect.params)
    new = Layout(layout.plant, [cand if a is replaces else a for a in layout.active])
    return new, np.concatenate([x[:off], params, x[off + k :]]), off


def start_vector(cand: Candidate, replaces: Candidate | None, layout: Layout, x: np.ndarray) -> np.ndarray:
    if replaces is None:
        return cand.start()
    off = layout.offset(replaces)
    old = x[off : off + len(replaces.effect.params)]
    return np.asarray(cand.effect.extends[replaces.effect.name](old, cand.bounds), dtype=float)


def score_candidates(
    obj: Objective, layout: Layout, x: np.ndarray, cands: list[Candidate], criterion: str, n_eff: float
) -> list[Score]:
    """Score every candidate's signature against the residual of `obj` (sorted, best first)."""
    lo_cur, hi_cur = layout.bounds
    span_cur = hi_cur - lo_cur
    z = (x - lo_cur) / np.where(span_cur > 0, span_cur, 1.0)
    cur_steps = np.where(z + CUR_STEP <= 1.0, CUR_STEP, -CUR_STEP) * span_cur
    variants = [layout.realise(x)]
    for i, h in enumerate(cur_steps):
        xi = x.copy()
        xi[i] += h
        variants.append(layout.realise(xi))
    plan = []
    for cand in cands:
        rel, other = relation(cand, layout.active)
        if rel == "skip":
            continue
        replaces = other if rel == "replace" else None
        x0 = start_vector(cand, replaces, layout, x)
        new, xfull, off = with_candidate(layout, x, cand, replaces, x0)
        levels = []
        for level in SIGNATURE_LEVELS if cand.effect.threshold else SIGNATURE_LEVELS[:1]:
            steps = signature_steps(cand.effect, cand.bounds, level)
            for i, h in enumerate(steps):
                if x0[i] + h > cand.bounds[i][1]:
                    steps[i] = h = -h
                xi = xfull.copy()
                xi[off + i] += h
                variants.append(new.realise(xi))
            levels.append(steps)
        plan.append((cand, replaces, x0, levels))
    grid = obj.sim.run(variants, obj.segs)[..., obj.channels]
    lin = Linearisation(obj, grid[0], cur_steps, grid[1 : 1 + len(x)], lo_cur - x, hi_cur - x)
    r, jcur, dlo, dhi, best = lin.r, lin.jcur, lin.dlo, lin.dhi, lin.best

    def column(j: int, h: float) -> np.ndarray:
        return lin.change(grid[j]) / h

    ssr0, _ = best(jcur, dlo, dhi)
    out, j = [], 1 + len(x)
    for cand, replaces, x0, levels in plan:
        kn = cand.effect.n_nested
        lo = np.array([b[0] for b in cand.bounds[:kn]]) - x0[:kn]
        hi = np.array([b[1] for b in cand.bounds[:kn]]) - x0[:kn]
        ssr, step, delta = ssr0, np.zeros(kn), np.zeros(len(x))
        points = []
        for steps in levels:  # the amplitude whose secant explains most
            s = np.stack([column(j + i, h) for i, h in enumerate(steps)], axis=1)
            j += len(steps)
            ssr_l, sol = best(np.concatenate([s, jcur], axis=1), np.concatenate([lo, dlo]), np.concatenate([hi, dhi]))
            if ssr_l < ssr:
                ssr, step, delta = ssr_l, sol[:kn], sol[kn:]
            if cand.effect.threshold:
                points.append((steps.copy(), best(jcur, dlo, dhi, r + s @ steps)[1]))
        k_new = len(cand.effect.params) - (len(replaces.effect.params) if replaces else 0)
        predicted = information(ssr, k_new, n_eff, criterion) - information(ssr0, 0, n_eff, criterion)
        out.append(Score(cand, replaces, 1.0 - ssr / max(ssr0, 1e-300), predicted, step, delta, points, lin))
    out.sort(key=lambda sc: (sc.predicted, -sc.score))
    return out


def scan(obj: Objective, layout: Layout, x: np.ndarray, scores: list[Score]) -> None:
    """Starting points for effects whose landscape has several basins (`Effect.scan`): their amplitude
    grid simulated exactly (one batched call), the current parameters re-tuned to each; the best
    `SCAN_STARTS` become the candidate's points."""
    todo = [sc for sc in scores if sc.cand.effect.scan and sc.lin is not None]
    variants, amps = [], []
    for sc in todo:
        eff, kn = sc.cand.effect, sc.cand.effect.n_nested
        x0 = start_vector(sc.cand, sc.replaces, layout, x)
        new, xfull, off = with_candidate(layout, x, sc.cand, sc.replaces, x0)
        lo = np.array([b[0] for b in sc.cand.bounds[:kn]])
        hi = np.array([b[1] for b in sc.cand.bounds[:kn]])
        for share in eff.scan:
            amp = np.clip(x0[:kn] + share * np.maximum(np.abs(lo), np.abs(hi)), lo, hi) - x0[:kn]
            xi = xfull.copy()
            xi[off : off + kn] += amp
            variants.append(new.realise(xi))
            amps.append(amp)
    if not variants:
        return
    grid = obj.sim.run(variants, obj.segs)[..., obj.channels]
    i = 0
    for sc in todo:
        assert sc.lin is not None
        found = []
        for _ in sc.cand.effect.scan:
            ssr, delta = sc.lin.retune(sc.lin.change(grid[i]))
            found.append((ssr, amps[i], delta))
            i += 1
        sc.points = [(a, d) for _, a, d in sorted(found, key=lambda p: p[0])[:SCAN_STARTS]]


STEP_FRACTIONS = (1.0, 0.5, 0.25)  # of the signature step, checked on held-out data before a refit


def _trial_start(sc: Score, layout: Layout, x: np.ndarray, fraction: float) -> tuple[Layout, np.ndarray, int]:
    kn = sc.cand.effect.n_nested
    lo_cur, hi_cur = layout.bounds
    xd = np.clip(x + fraction * sc.delta, lo_cur, hi_cur)
    x0 = start_vector(sc.cand, sc.replaces, layout, xd)
    lo = np.array([b[0] for b in sc.cand.bounds[:kn]])
    hi = np.array([b[1] for b in sc.cand.bounds[:kn]])
    x0[:kn] = np.clip(x0[:kn] + fraction * sc.step, lo + 1e-3 * (hi - lo), hi)
    return with_candidate(layout, xd, sc.cand, sc.replaces, x0)


def trial_starts(sc: Score, layout: Layout, x: np.ndarray) -> list[tuple[Layout, np.ndarray, int]]:
    """Starting points for refitting a candidate: fractions of its signature step (the linearisation
    overshoots for strongly nonlinear effects) and, for shape parameters, a few values of them."""
    out = []
    eff = sc.cand.effect
    for step, delta in sc.points:  # threshold effects: the simulated signature points themselves
        out.append(_trial_start(Score(sc.cand, sc.replaces, sc.score, sc.predicted, step, delta), layout, x, 1.0))
    for fraction in STEP_FRACTIONS:
        new, xs, off = _trial_start(sc, layout, x, fraction)
        if not eff.shape:
            out.append((new, xs, off))
            continue
        for share in SHAPE_GRID:
            xi = xs.copy()
            for j in range(eff.n_nested, len(eff.params)):
                lo, hi = sc.cand.bounds[j]
                xi[off + j] = lo + share * (hi - lo)
            out.append((new, xi, off))
    return out
