"""The Real2Sim loop: fit the declared parameters, trace the residual to a missing effect, add it, repeat.

Each round scores every candidate (effect x target) by its signature (`bench.calibrate.signature`)
against the held-out residual, checks the best along their signature step, refits them with
everything else, and accepts one only when

1. the held-out k-step error drops by at least `trace.margin`,
2. the information criterion (BIC by default, on n_eff = n / tau training residuals) improves, and
3. every amplitude parameter of the effect has a 95% interval that excludes zero (for a family that
   generalises an accepted one, e.g. Stribeck over Coulomb friction: the generalisation does).

Of several that pass, the largest held-out drop wins. An effect accepted earlier whose interval
now includes zero is removed; pairs that together are one family are merged. The loop stops when
no candidate passes or `trace.max_effects` are in.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.calibrate.data import extract, heldout_of
from bench.calibrate.effects import EFFECTS, MERGES
from bench.calibrate.feedback import close_loop
from bench.calibrate.fit import FitResult, Objective, autocorrelation_time, fit, information
from bench.calibrate.metrics import against_memory, evaluate, heldout_errors, repeat_baseline, trust, trust_warnings
from bench.calibrate.model import Candidate, Layout, Plant
from bench.calibrate.novelty import Heldout
from bench.calibrate.residual import learn
from bench.calibrate.signature import Score, scan, score_candidates, trial_starts
from bench.calibrate.spec import CalibrationSpec, EffectRequest
from bench.replay.data import Recording
from bench.replay.simulate import Segments, Simulator, horizons
from bench.replay.spec import load_model

TRIAL_TOL = 1e-3  # least-squares tolerance when judging a candidate (the accepted one is then polished)
# candidates are judged on a seeded share (at least JUDGE_MIN) of the training horizons
JUDGE_SHARE, JUDGE_MIN = 0.5, 20
SCORE_MAX = 40  # held-out horizons the signatures are scored on (a seeded subset beyond; acceptance uses all)


@dataclass
class Calibration:
    """Everything the loop found: fits, accepted and rejected effects, errors, traces for plots."""

    spec: CalibrationSpec
    plant: Plant
    seed: int
    layout: Layout
    declared_fit: FitResult
    final_fit: FitResult
    x_nominal: np.ndarray
    errors: dict[str, dict]
    traces: dict[str, dict]
    added: list[dict] = field(default_factory=list)
    rejected: list[dict] = field(default_factory=list)
    rounds: list[list[dict]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    wall: dict[str, float] = field(default_factory=dict)
    k: int = 1
    residual: dict[str, np.ndarray] = field(default_factory=dict)
    learned: dict | None = None  # the learned residual (`bench.calibrate.residual`), apart from the physics
    heldout: Heldout | None = None  # where the held-out data sit and how much of them repeats the fitted
    trust: Mapping[str, object] = field(default_factory=dict)  # calibration.json's `trust` (`metrics.trust`)

    @property
    def rec(self) -> Recording:
        return self.plant.rec


def _merge(layout: Layout, x: np.ndarray) -> tuple[Layout, np.ndarray, list[tuple[Candidate, Candidate, Candidate]]]:
    """Replace pairs of active effects that together are exactly one family (e.g. Coulomb + bias)."""
    plant = layout.plant
    done = []
    for (a_name, b_name), (m_name, lift) in MERGES.items():
        for a in list(layout.active):
            b = next(
                (
                    c
                    for c in layout.active
                    if c.effect.name == b_name and c.target.dof == a.target.dof and c.target.kind == a.target.kind
                ),
                None,
            )
            if a.effect.name != a_name or b is None:
                continue
            eff = EFFECTS[m_name]
            merged = Candidate(eff, a.target, eff.bounds(plant.scales, a.target))
            xa = x[layout.offset(a) : layout.offset(a) + len(a.effect.params)]
            xb = x[layout.offset(b) : layout.offset(b) + len(b.effect.params)]
            xm = lift(xa, xb)
            if not all(lo <= v <= hi for v, (lo, hi) in zip(xm, merged.bounds)):
                continue
            rest = [c for c in layout.active if c is not a and c is not b]
            parts = [x[layout.offset(c) : layout.offset(c) + len(c.effect.params)] for c in rest]
            layout = Layout(plant, rest + [merged])
            x = np.concatenate([x[: len(plant.slots)], *parts, xm])
            done.append((a, b, merged))
    return layout, x, done


def _physical(cand: Candidate, f: FitResult, off: int, plant: Plant) -> tuple[dict, dict]:
    k = len(cand.effect.params)
    x = f.x[off : off + k]
    sd = f.sd[off : off + k]
    val = cand.effect.physical(x, plant.scales, cand.target)
    if not np.all(np.isfinite(sd)):
        return val, {p: None for p in val}
    if cand.effect.intervals is not None:
        return val, cand.effect.intervals(x, f.cov[off : off + k, off : off + k], plant.scales, cand.target)
    a = cand.effect.physical(x - 1.96 * sd, plant.scales, cand.target)
    b = cand.effect.physical(x + 1.96 * sd, plant.scales, cand.target)
    return val, {p: sorted([a[p], b[p]]) for p in val}


def _entry(cand: Candidate, **kw) -> dict:
    t = cand.target
    return {"name": cand.effect.name, "target": t.label, "joint": t.joint or None, "kind": t.kind, **kw}


def _subset(segs: Segments, rows: np.ndarray) -> Segments:
    """The segments `rows` of `segs`, their mask (horizons of episodes shorter than k) kept."""
    return Segments(segs.start[rows], segs.length, None if segs.mask is None else segs.mask[rows])


class _Loop:
    """State of one calibration: the simulator, the data split and the current model."""

    def __init__(
        self,
        plant: Plant,
        sim: Simulator,
        train: Segments,
        hold: Segments,
        scale: np.ndarray,
        channels: np.ndarray,
        log: Callable[[str], None],
        seed: int = 0,
        fitter: Callable[..., FitResult] = fit,
    ) -> None:
        self.plant, self.sim, self.train, self.hold = plant, sim, train, hold
        self.fitter = fitter  # `fit` (least squares) or `bench.calibrate.gradient.GradientFitter` (MJX)
        self.scale, self.channels, self.log = scale, channels, log
        self.tr = plant.spec.trace
        m = min(len(train), max(JUDGE_MIN, int(np.ceil(JUDGE_SHARE * len(train)))))
        pick = np.random.default_rng([seed, 1]).choice(len(train), size=m, replace=False)
        self.judged = _subset(train, np.sort(pick))  # where candidates are refitted
        pick = np.random.default_rng([seed, 2]).choice(len(hold), size=min(len(hold), SCORE_MAX), replace=False)
        self.scored = _subset(hold, np.sort(pick))  # where signatures are scored
        self._base: tuple[int, float, float] | None = None  # (id of the current fit, its SSR and n_eff there)

    def base(self, layout: Layout, cur: FitResult) -> tuple[float, float]:
        """SSR and n_eff of the current fit on the judging horizons (once per current fit)."""
        if self._base is None or self._base[0] != id(cur):
            obj = self.objective(layout, self.judged)
            grid = obj.residual_grid(cur.x[None])[0]
            r = grid[obj.mask]
            self._base = (id(cur), float(r @ r), len(r) / autocorrelation_time(grid))
        return self._base[1], self._base[2]

    def objective(self, layout: Layout, segs: Segments) -> Objective:
        return Objective(self.sim, layout, segs, self.plant.rec, self.scale, self.channels)

    def fit(self, layout: Layout, x0: np.ndarray, broyden: bool = False) -> FitResult:
        return self.fitter(self.objective(layout, self.train), x0, broyden=broyden)

    def heldout(self, pairs: list[tuple[Layout, np.ndarray]]) -> list[float]:
        return heldout_errors(self.sim, pairs, self.hold, self.plant.rec, self.scale, self.channels)

    def score(self, layout: Layout, x: np.ndarray, cands: list[Candidate]) -> list[Score]:
        obj = self.objective(layout, self.scored)
        n_eff = obj.size / autocorrelation_time(obj.residual_grid(x[None])[0])
        return score_candidates(obj, layout, x, cands, self.tr.criterion, n_eff)

    def judge(
        self,
        sc: Score,
        start: tuple[Layout, np.ndarray, int],
        layout: Layout,
        cur: FitResult,
        err0: float,
        rnd: int,
        step: float,
    ) -> tuple[dict, FitResult, Layout, list[str]]:
        """Refit with the candidate in (on the judging horizons); the entry for the report and the
        reasons it fails (none: passes)."""
        new, xinit, off = start
        ssr0, n_eff = self.base(layout, cur)
        f = self.fitter(self.objective(new, self.judged), xinit, tol=TRIAL_TOL, broyden=True)
        err = self.heldout([(new, f.x)])[0]
        drop = 1.0 - err / err0
        crit = self.tr.criterion
        d_ic = information(f.ssr, len(f.x), n_eff, crit) - information(ssr0, len(cur.x), n_eff, crit)
        if sc.replaces is not None:  # the generalisation itself must be non-zero
            excl = f.contrast_excludes_zero(off, np.array(sc.cand.effect.contrast))
        else:
            excl = all(f.excludes_zero(off + i) for i in sc.cand.effect.gated)
        reasons = []
        if drop < self.tr.margin:
            reasons.append(f"held-out error drop {100 * drop:.1f}% < {100 * self.tr.margin:.0f}%")
        if d_ic >= 0:
            reasons.append(f"{crit.upper()} does not improve ({d_ic:+.1f})")
        if not excl:
            reasons.append("parameter interval includes zero")
        params, interval = _physical(sc.cand, f, off, self.plant)
        entry = _entry(
            sc.cand,
            params=params,
            interval=interval,
            round=rnd,
            score=sc.score,
            heldout_drop=drop,
            delta_ic=d_ic,
            **({"replaces": sc.replaces.key} if sc.replaces else {}),
        )
        self.log(
            f"round {rnd}: {sc.cand.key} score {sc.score:.3f}, step {100 * step:.1f}% ({f.nfev} evaluations), "
            f"held-out {err0:.4g} -> {err:.4g} ({100 * drop:.1f}%), d{crit.upper()} {d_ic:+.1f} -> "
            f"{'passes' if not reasons else '; '.join(reasons)}"
        )
        return entry, f, new, reasons

    def round(
        self, rnd: int, layout: Layout, cur: FitResult, err0: float, scores: list[Score], tried: dict[str, dict]
    ) -> tuple[Score, dict, FitResult, Layout] | None:
        """Check, refit and judge the shortlisted candidates; the winner, if any passes."""
        shortlist = [s for s in scores if s.score >= self.tr.min_score and s.predicted < 0][: self.tr.max_tries]
        scan(self.objective(layout, self.scored), layout, cur.x, shortlist)
        options = [trial_starts(sc, layout, cur.x) for sc in shortlist]
        errs = self.heldout([(new, xi) for opts in options for new, xi, _ in opts])
        checked, i0 = [], 0
        for sc, opts in zip(shortlist, options):
            e = errs[i0 : i0 + len(opts)]
            i0 += len(opts)
            checked.append((1.0 - min(e) / err0, sc, opts[int(np.argmin(e))]))
        best = None
        for step, sc, start in sorted(checked, key=lambda c: -c[0]):
            if step <= 0:  # even the signature's own step raises the held-out error: not worth a refit
                tried[sc.cand.key] = _entry(
                    sc.cand, score=sc.score, reason=f"its signature step raises the held-out error ({-100 * step:.1f}%)"
                )
                continue
            if best is not None and step < 0.5 * best[4]:
                break  # not competitive with the one that already passed
            entry, f, new, reasons = self.judge(sc, start, layout, cur, err0, rnd, step)
            if reasons:
                tried[sc.cand.key] = {**entry, "reason": "; ".join(reasons)}
            elif best is None or entry["heldout_drop"] > best[1]["heldout_drop"]:
                if best is not None:
                    tried[best[0].cand.key] = {**best[1], "reason": f"passed; {sc.cand.key} cut the error more"}
                best = (sc, entry, f, new, step)
            else:
                tried[sc.cand.key] = {**entry, "reason": f"passed; {best[0].cand.key} cut the error more"}
        return None if best is None else best[:4]

    def prune(
        self, rnd: int, layout: Layout, cur: FitResult, keep: Candidate, added: list[dict], tried: dict[str, dict]
    ) -> tuple[Layout, FitResult]:
        """Drop effects accepted earlier that the new one made redundant (no amplitude excludes zero)."""
        while True:
            weak = [
                c
                for c in layout.active
                if c is not keep and not any(cur.excludes_zero(layout.offset(c) + i) for i in c.effect.gated)
            ]
            if not weak:
                return layout, cur
            c = weak[0]
            off, kc = layout.offset(c), len(c.effect.params)
            layout = Layout(self.plant, [a for a in layout.active if a is not c])
            cur = self.fit(layout, np.concatenate([cur.x[:off], cur.x[off + kc :]]), broyden=True)
            gone = next(a for a in added if f"{a['name']}@{a['target']}" == c.key)
            added.remove(gone)
            tried[c.key] = {**gone, "reason": f"removed after {keep.key} was added: interval includes zero"}
            self.log(f"round {rnd}: {c.key} removed (its interval includes zero once {keep.key} is in)")

    def merge(self, rnd: int, layout: Layout, cur: FitResult, added: list[dict]) -> tuple[Layout, FitResult]:
        """Report pairs that together are exactly one family (Coulomb + bias) as that family."""
        layout, x, merged = _merge(layout, cur.x)
        if not merged:
            return layout, cur
        cur = self.fit(layout, x, broyden=True)
        for a, b, m in merged:
            parts = [e for e in added if f"{e['name']}@{e['target']}" in (a.key, b.key)]
            for e in parts:
                added.remove(e)
            params, interval = _physical(m, cur, layout.offset(m), self.plant)
            added.append(
                {**parts[-1], **_entry(m), "params": params, "interval": interval, "merged_from": [a.key, b.key]}
            )
            self.log(f"round {rnd}: {a.key} + {b.key} are together {m.key}; merged")
        return layout, cur


def _rejected(scores: list[Score], tried: dict[str, dict], added: list[dict], min_score: float) -> list[dict]:
    """Every candidate not added: its last score and why it was not taken."""
    added_keys = {f"{a['name']}@{a['target']}" for a in added}
    out, seen = [], set()
    for sc in scores:
        key = sc.cand.key
        if key in added_keys:
            continue
        seen.add(key)
        why = (
            "not tried: ranked below the tried candidates"
            if sc.score >= min_score and sc.predicted < 0
            else "not tried: its signature explains too little of the residual"
        )
        base = tried.get(key) or _entry(sc.cand, reason=why)
        out.append({**base, "score": sc.score, "predicted_delta_ic": sc.predicted})
    out += [e for k, e in tried.items() if k not in seen and k not in added_keys]
    return sorted(out, key=lambda e: -e.get("score", 0.0))


def calibrate_episodes(
    spec: CalibrationSpec, episodes: list[dict[str, np.ndarray]], fps: float, *, seed: int = 0, **loop: Any
) -> Calibration:
    """Run the whole loop on logged episodes (arrays keyed by column) and return what it found.

    `loop` takes `calibrate`'s keywords: `effects` ("spec": the spec's list, None: all, (): none, or
    explicit requests), `threads`, `log`, and `residual` (a learned residual fitted after the loop and
    reported apart from the physics, `Calibration.learned`).
    """
    t0 = time.perf_counter()
    model = load_model(spec.model)
    rec = extract(spec, episodes, fps, nq=model.nq, nv=model.nv, nu=model.nu, seed=seed)
    if spec.controller is not None:  # the log's feedback loop, closed in every simulated horizon
        model, rec = close_loop(model, rec, *spec.controller)
    return calibrate(Plant(spec, model, rec), seed=seed, t0=t0, **loop)


def calibrate(
    plant: Plant,
    *,
    seed: int = 0,
    effects: tuple[EffectRequest, ...] | None | str = "spec",
    threads: int | None = None,
    log: Callable[[str], None] = lambda msg: None,
    residual: bool = False,
    t0: float | None = None,
    fitter: Callable[..., FitResult] = fit,
) -> Calibration:
    """The loop on a plant built by the caller (`calibrate_episodes` for a spec and logs, `bench.calibrate.suite_robot` for a
    suite's robot in its scene). `effects`: "spec" (the spec's list), None (all), () (none) or explicit
    requests; with `residual`, a learned residual is fitted after the loop and reported apart from the
    physics (`Calibration.learned`); `fitter` fits a layout's parameters (`fit`, or a gradient fitter)."""
    t0 = time.perf_counter() if t0 is None else t0
    spec = plant.spec
    sim = plant.simulator(threads or spec.threads)
    try:
        cal = _calibrate(spec, plant, sim, seed, effects, log, t0, fitter)
        if residual:
            t1 = time.perf_counter()
            cal.learned = learn(sim, cal.layout.realise(cal.final_fit.x), cal.k, seed)
            cal.wall["residual"] = time.perf_counter() - t1
            h = cal.learned["heldout"]
            log(
                "learned residual (apart from the physics): held-out NRMSE, physics -> physics + residual: "
                + ", ".join(
                    f"{lb.replace('_', '-')} {_fmt(h['physics'][f'{lb}_nrmse'])} -> "
                    f"{_fmt(h['physics_plus_residual'][f'{lb}_nrmse'])}"
                    for lb in ("k_step", "free_run")
                )
            )
    finally:
        sim.close()
    log(
        f"final: {len(cal.added)} effect(s) added; held-out free-run NRMSE {cal.errors['final']['free_run_nrmse']:.4g}, "
        f"{against_memory(cal.errors, cal.trust)} ({cal.wall['total']:.1f} s)"
    )
    return cal


def at_bounds(layout: Layout, x: np.ndarray, rel: float = 1e-6) -> list[str]:
    """Parameters the fit left on a bound of their range (the bound, not the data, decided them)."""
    lo, hi = layout.bounds
    span = np.maximum(hi - lo, 1e-300)
    out = []
    for lab, v, a, b, w in zip(layout.labels, x, lo, hi, span):
        if v <= a + rel * w:
            out.append(f"{lab} = {v:.4g} at its lower bound")
        elif v >= b - rel * w:
            out.append(f"{lab} = {v:.4g} at its upper bound")
    return out


def honesty(layout: Layout, x: np.ndarray, errors: dict[str, dict]) -> list[str]:
    """What a user must not miss: parameters on a bound, and a held-out error that rose while the fitted
    one (k-step) fell."""
    out = [f"parameter {b} (widen the bounds, or the data do not pin it)" for b in at_bounds(layout, x)]
    k0, k1 = errors["declared"].get("k_step_nrmse"), errors["final"].get("k_step_nrmse")
    n0 = errors["nominal"].get("k_step_nrmse")
    for other in ("free_run_nrmse", "one_step_nrmse"):
        for ref in ("nominal", "declared"):
            a, b = errors[ref].get(other), errors["final"].get(other)
            fitted_fell = (
                (k1 is not None)
                and (k0 if ref == "declared" else n0) is not None
                and k1 < (k0 if ref == "declared" else n0)
            )
            if a is not None and b is not None and fitted_fell and b > a * 1.001:
                label = other.replace("_nrmse", "").replace("_", "-")
                out.append(
                    f"held-out {label} NRMSE rose {ref} -> final ({a:.4g} -> {b:.4g}) while the fitted k-step "
                    f"error fell: the fit trades one horizon for another"
                )
                break
    return out


def _fmt(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.4g}"


def _calibrate(
    spec: CalibrationSpec,
    plant: Plant,
    sim: Simulator,
    seed: int,
    effects: tuple[EffectRequest, ...] | None | str,
    log: Callable[[str], None],
    t0: float,
    fitter: Callable[..., FitResult] = fit,
) -> Calibration:
    """Nominal errors, declared fit, the add / refit / accept rounds, final errors."""
    rec = plant.rec
    k = max(1, int(round(spec.horizon * rec.fps)))
    nq, nv = rec.qpos.shape[1], rec.qvel.shape[1]  # the logged coordinates
    channels = np.arange(nq + (nv if rec.qvel_logged else 0))  # velocities only when logged
    train_frames = rec.frames(rec.train)
    scale = np.maximum(np.concatenate([rec.qpos[train_frames], rec.qvel[train_frames]], axis=1).std(axis=0), 1e-9)
    train = horizons(rec, rec.train, k, limit=spec.trace.max_segments, seed=seed)
    hold = horizons(rec, rec.holdout, k)
    loop = _Loop(plant, sim, train, hold, scale, channels, log, seed, fitter)
    heldout = heldout_of(rec)
    log(heldout.sentence())
    names = [n or f"q{i}" for i, n in enumerate(plant.joint_names)]

    layout = Layout(plant, [])
    x_nom = plant.declared_nominal()
    errors, traces = {}, {}
    errors["nominal"], traces["nominal"] = evaluate(sim, layout, x_nom, rec, rec.holdout, k, names)
    log(f"nominal: held-out free-run NRMSE {errors['nominal']['free_run_nrmse']:.4g}")
    t1 = time.perf_counter()
    declared = loop.fit(layout, plant.declared_init())
    errors["declared"], traces["declared"] = evaluate(sim, layout, declared.x, rec, rec.holdout, k, names)
    log(
        f"declared fit ({declared.nfev} evaluations): held-out free-run NRMSE "
        f"{errors['declared']['free_run_nrmse']:.4g}"
    )
    t2 = time.perf_counter()

    cands, notes = plant.candidates(spec.effects if isinstance(effects, str) else effects)
    cal = Calibration(spec, plant, seed, layout, declared, declared, x_nom, errors, traces, notes=notes, k=k)
    cur, err0 = declared, loop.heldout([(layout, declared.x)])[0]
    tried: dict[str, dict] = {}
    scores: list[Score] = []
    for rnd in range(1, spec.trace.max_effects + 1):
        if not cands:
            break
        scores = loop.score(layout, cur.x, cands)
        cal.rounds.append([s.to_json() for s in scores])
        won = loop.round(rnd, layout, cur, err0, scores, tried)
        if won is None:
            break
        sc, entry, _, layout = won
        cur = loop.fit(layout, won[2].x, broyden=True)  # polish the winner's fit on all training horizons
        log(f"round {rnd}: accepted {sc.cand.key}")
        if sc.replaces is not None:
            cal.added = [a for a in cal.added if f"{a['name']}@{a['target']}" != sc.replaces.key]
        cal.added.append(entry)
        tried.pop(sc.cand.key, None)
        layout, cur = loop.prune(rnd, layout, cur, sc.cand, cal.added, tried)
        layout, cur = loop.merge(rnd, layout, cur, cal.added)
        err0 = loop.heldout([(layout, cur.x)])[0]
    for entry in cal.added:  # report the values of the final fit
        cand = next(c for c in layout.active if c.key == f"{entry['name']}@{entry['target']}")
        entry["params"], entry["interval"] = _physical(cand, cur, layout.offset(cand), plant)
    cal.rejected = _rejected(scores, tried, cal.added, spec.trace.min_score)
    cal.layout, cal.final_fit = layout, cur
    errors["final"], traces["final"] = evaluate(sim, layout, cur.x, rec, rec.holdout, k, names)
    cal.residual = {
        "declared": loop.objective(Layout(plant, []), hold).residual_grid(declared.x[None])[0],
        "final": loop.objective(layout, hold).residual_grid(cur.x[None])[0],
        "start": hold.start,
    }
    errors["repeat"] = repeat_baseline(rec, hold, heldout.period_s)
    verdict = trust(heldout, errors)
    cal.heldout, cal.trust = heldout, verdict
    cal.warnings = sorted(set(declared.warnings) | set(cur.warnings)) + honesty(layout, cur.x, errors)
    cal.warnings += trust_warnings(heldout, errors, verdict)
    t3 = time.perf_counter()
    cal.wall = {"total": t3 - t0, "declared_fit": t2 - t1, "trace": t3 - t2, "sim_steps": sim.steps}
    return cal
