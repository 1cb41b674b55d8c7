"""The servo's Real2Sim loop: fit the declared servo, find which effects the logs need, refit, and report the error on
whole runs the fit never saw, before (the declared servo) and after (with the effects added).

Held out are whole runs (by trajectory, the spec's `holdout`): new to the fit in their goal profile, and for
`lift_and_drop` in their physics (stretches with the torque off: free fall under gravity and friction alone). Each
run's gain setting is fitted on the other runs with that setting (the setting is a label, its value never used).
Effects are chosen on validation windows of the training runs (every fourth window), never on the held-out runs.
Intervals combine the Jacobian's with a jackknife over whole training runs and the declared kt/R's spread
(`bench.calibrate.servo.intervals`); the physics recovered says how many known values lie inside them.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from bench.calibrate.servo.data import ServoRun
from bench.calibrate.servo.effects import KP_UNIT, SERVO_EFFECTS, scale_of
from bench.calibrate.servo.fit import Fit, Problem, duty_data, fit, linear_start, position_cost, window_score
from bench.calibrate.servo.intervals import Jackknife, jackknife, scale_profile
from bench.calibrate.servo.law import GRAVITY, ServoParams
from bench.calibrate.servo.sim import RUN_GAP, Windows, make_windows, simulate
from bench.calibrate.servo.spec import ServoSpec
from bench.calibrate.servo.verdict import verdict_lines, verdicts
from bench.core.errors import DataError
from bench.core.threads import one_blas_thread

KP_GRID = np.geomspace(0.5, 5000.0, 28)  # gains tried by the linear start where no duty is logged
SEARCH_NFEV = 12  # evaluations of a candidate's fit
FINAL_NFEV = 40
GOAL_SLOWNESS_START = 1.0 / 5.2  # s/rad: the Feetech STS firmware's default limit, 3400 steps/s (BAM)
SEARCH_HALVE = 100  # fit windows from which the search screens on every second one


@dataclass
class ServoCalibration:
    """What `calibrate_servo` found: fits before and after, held-out errors per run, the physics recovered."""

    spec: ServoSpec
    train: list[str]
    heldout: list[str]
    labels: list[str]
    declared: Fit
    final: Fit
    added: list[dict[str, Any]]
    rounds: list[dict[str, Any]]
    errors: dict[str, Any]
    physics: dict[str, Any]
    wall: dict[str, float]
    jackknives: dict[str, Jackknife]  # "declared", "final": each fit's leave-one-run-out refits
    sources: list[str] = field(default_factory=list)  # the runs' files
    warnings: list[str] = field(default_factory=list)

    def parameters(self, f: Fit) -> dict[str, Any]:
        """Every fitted parameter with its unit and 95% interval: the Jacobian's, the jackknife over training runs
        and, for torques, the declared kt/R's spread combined (`bench.calibrate.servo.intervals`); the sd of each
        part beside it."""
        units = {p.field: p.unit for p in f.prob.params}
        jk = next((j for j in self.jackknives.values() if j.full is f), None)
        out: dict[str, Any] = {}
        for n in f.prob.names:
            if jk is None:
                out[n] = {"value": f.value(n), "unit": units.get(n, KP_UNIT), "interval": f.interval(n), "sd": None}
            else:
                iv = jk.parameter(n)
                out[n] = {"value": iv["value"], "unit": units.get(n, KP_UNIT), "interval": iv["interval"]}
                out[n]["sd"] = iv["sd"]
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "schema": "bench.calibration.servo/1",
            "spec": self.spec.to_json(),
            "train": self.train,
            "heldout": {
                "runs": self.heldout,
                "why_new": "whole runs never fitted: their goal profile, and with the torque off (lift_and_drop) "
                "free motion under gravity and friction alone",
            },
            "labels": self.labels,
            "effects_added": self.added,
            "rounds": self.rounds,
            "parameters": {"declared": self.parameters(self.declared), "final": self.parameters(self.final)},
            "intervals": {
                "method": "95%: Jacobian (noise) + jackknife over whole training runs (model error; each refit from "
                "the estimator's own start without that run where no duty is logged) + the declared kt/R's relative "
                "sd for torques, variances summed; Student's t at the Welch-Satterthwaite degrees of freedom (the "
                "jackknife's n - 1); cut to the parameter's range",
                "jackknife_left_out": self.jackknives["final"].left_out,
            },
            "errors": self.errors,
            "verdict": verdicts(self.errors, self.heldout),
            "physics": self.physics,
            "wall": self.wall,
            "warnings": self.warnings,
        }


def _split(spec: ServoSpec, runs: list[ServoRun]) -> tuple[list[ServoRun], list[ServoRun]]:
    key, val = next(iter(spec.holdout.items()))
    if key == "trajectory":
        held = [r for r in runs if r.trajectory == val]
    else:
        names = [str(v) for v in (val if isinstance(val, list) else [val])]
        held = [r for r in runs if r.name in names]
    train = [r for r in runs if r not in held]
    if not held or not train:
        raise DataError(
            f"holdout {spec.holdout!r} leaves {len(train)} run(s) to fit and {len(held)} to hold out; both need one "
            f"(trajectories: {', '.join(sorted({r.trajectory for r in runs}))})"
        )
    missing = sorted({r.label for r in held} - {r.label for r in train})
    if missing:
        raise DataError(f"held-out runs with gain setting {missing[0]} have no run with that setting to fit it on")
    return train, held


def _label_key(label: str) -> tuple[float, str]:
    try:
        return float(label.split("=")[-1]), label
    except ValueError:
        return float("inf"), label


def _extend(prob: Problem, x: np.ndarray, name: str) -> tuple[Problem, np.ndarray]:
    """The problem with effect `name` added, and `x` with its parameters at their start (amplitude zero)."""
    new = Problem(prob.base, prob.labels, (*prob.effects, name), prob.scale)
    k = len(prob.params)
    starts = [p.start(prob.scale) for p in SERVO_EFFECTS[name].params]
    if name == "backlash":  # a play of exactly zero is a different (one-body) model: start inside the family
        starts[0] = 0.1 * SERVO_EFFECTS[name].params[0].bounds(prob.scale)[1]
    if name == "goal_velocity_limit":  # a limit far above every goal velocity has no gradient: start where it binds
        starts[0] = GOAL_SLOWNESS_START
    return new, np.concatenate([x[:k], starts, x[k:]])


def _gated(f: Fit, name: str) -> bool:
    """The effect's amplitude parameters have intervals that exclude zero."""
    for fld in SERVO_EFFECTS[name].gated:
        iv = f.interval(fld)
        if iv is None or iv[0] <= 0:
            return False
    return True


def heldout_errors(
    p: ServoParams, kp: np.ndarray, runs: list[ServoRun], labels: list[str], horizon: int
) -> dict[str, Any]:
    """Per run: free-run (from the first logged state to the end, driven by the logged goal) and k-step position
    errors (also split: windows with the torque on throughout, windows with it off part of the time), and the
    free-run error over the frames with the torque off (free fall)."""
    full = make_windows(runs, labels, 0)
    sim = simulate(p.with_(kp=kp[full.label]), full)
    kw = make_windows(runs, labels, horizon)
    ks = simulate(p.with_(kp=kp[kw.label]), kw)
    out: dict[str, Any] = {}
    for i, r in enumerate(runs):
        n = r.frames - 1
        err = sim[i, :n] - r.q[1:]
        sd = float(np.std(r.q))
        off = r.enable[1:] < 0.5
        mine = kw.run == i
        kerr = (ks[mine] - kw.target[mine])[kw.mask[mine]]
        on = mine & (kw.enable.min(axis=1) > 0.5)  # windows with the torque on throughout (the rest: off a while)
        parts = {}
        for tag, sel in (("on", on), ("off", mine & ~on)):
            e = (ks[sel] - kw.target[sel])[kw.mask[sel]]
            parts[f"k_step_rmse_torque_{tag}"] = float(np.sqrt(np.mean(e**2))) if e.size else None
        out[r.name] = {
            "trajectory": r.trajectory,
            "label": r.label,
            "free_run_rmse": float(np.sqrt(np.mean(err**2))),
            "free_run_nrmse": float(np.sqrt(np.mean(err**2)) / sd),
            "k_step_rmse": float(np.sqrt(np.mean(kerr**2))),
            **parts,
            "free_fall_rmse": float(np.sqrt(np.mean(err[off] ** 2))) if off.any() else None,
            "free_fall_frames": int(off.sum()),
        }
    return out


def _physics(jk: Jackknife, train: list[ServoRun], labels: list[str]) -> dict[str, Any]:
    """The load and the gains recovered, beside the bench's known values (read from the logs, never fitted), each
    with its honest interval (`bench.calibrate.servo.intervals`) and whether the known value lies inside it."""
    cal_fit = jk.full
    names = cal_fit.prob.names
    truth = train[0].truth
    out: dict[str, Any] = {}
    ig = names.index("gravity")
    positive = (0.0, np.inf)  # a gravity torque and a gain are not negative
    g_data = jk.interval(_component(ig), torque=False, within=positive)  # the data's part alone
    g = jk.interval(_component(ig), torque=True, within=positive)
    mgl = truth["mass"] * GRAVITY * truth["length"] if "mass" in truth and "length" in truth else None
    out["gravity_torque"] = {
        "fitted": g["value"],
        "interval_data": g_data["interval"],
        "interval_with_torque_scale": g["interval"],
        "sd": g["sd"],
        "known_mgl": mgl,
        "relative_error": (g["value"] - mgl) / mgl if mgl else None,
        "inside": _inside(mgl, g["interval"]),
    }
    known = {r.label: float(r.truth["kp"]) for r in train if "kp" in r.truth}
    base = labels[0]
    i0 = names.index(f"kp[{base}]")
    kps = {}
    for lab in labels:
        i = names.index(f"kp[{lab}]")
        kp = jk.interval(_component(i), torque=False, within=positive)
        ratio = jk.interval(_ratio(i, i0), torque=False, within=positive)
        true_ratio = known[lab] / known[base] if lab in known and base in known else None
        kps[lab] = {
            "fitted": kp["value"],
            "interval": kp["interval"],
            "sd": kp["sd"],
            "known": known.get(lab),
            "inside": _inside(known.get(lab), kp["interval"]),
            "ratio_to_" + base: ratio["value"],
            "ratio_interval": ratio["interval"] if lab != base else None,
            "known_ratio": true_ratio,
            "ratio_error": (ratio["value"] - true_ratio) / true_ratio if true_ratio else None,
            "ratio_inside": _inside(true_ratio, ratio["interval"]) if lab != base else None,
        }
    out["gains"] = kps
    if mgl and "length" in truth:
        j = cal_fit.value("inertia")
        ml2 = truth["mass"] * truth["length"] ** 2
        out["inertia"] = {"fitted": j, "point_mass_ml2": ml2, "implied_armature": j - ml2}
    checks = [out["gravity_torque"]["inside"]] + [k["inside"] for k in kps.values()]
    checks += [k["ratio_inside"] for k in kps.values()]
    known_checks = [c for c in checks if c is not None]
    out["truths_inside"] = {"inside": sum(known_checks), "checked": len(known_checks)}
    return out


def _component(i: int) -> Callable[[np.ndarray], float]:
    return lambda x: float(x[i])


def _ratio(i: int, base: int) -> Callable[[np.ndarray], float]:
    return lambda x: float(x[i] / x[base])


def _inside(v: float | None, iv: list[float] | None) -> bool | None:
    """Whether known value `v` lies in `iv` (None: no known value; an unbounded interval holds every value)."""
    return None if v is None else (iv is None or bool(iv[0] <= v <= iv[1]))


def calibrate_servo(
    spec: ServoSpec, runs: list[ServoRun], log: Callable[[str], None] = lambda m: None
) -> ServoCalibration:
    """Fit, search the effects, refit, and score on the held-out runs (see the module's docstring)."""
    t_start, c_start = time.perf_counter(), time.process_time()
    train, held = _split(spec, runs)
    labels = sorted({r.label for r in train}, key=_label_key)
    base = ServoParams(error_gain=spec.error_gain, max_duty=spec.max_duty, kt_over_r=spec.kt_over_r, kt=spec.kt)
    with one_blas_thread():
        horizon = max(2, int(round(spec.horizon * spec.rate)))
        w = make_windows(train, labels, horizon)
        val = np.arange(len(w.q0)) % 4 == 3
        w_fit, w_val = w.subset(~val), w.subset(val)
        sd_q = float(np.std(np.concatenate([r.q for r in train])))

        start, kp0 = linear_start(train, labels, base, KP_GRID, window_score(w_fit, sd_q))
        dd = duty_data(train, labels, RUN_GAP, stride=2)
        sd_d = float(np.std(dd.duty)) if dd is not None else 1.0
        torque = spec.kt_over_r * float(np.mean(np.concatenate([r.vin for r in train]))) * spec.max_duty
        scale = scale_of(torque, np.concatenate([r.dq for r in train]), start.inertia, 1.0 / spec.rate)
        prob = Problem(base, labels, (), scale)
        cur = fit(prob, prob.vector(start, kp0), w_fit, dd, sd_q, sd_d, max_nfev=FINAL_NFEV)
        cur_val = position_cost(prob, cur.x, w_val, sd_q)
        log(f"declared servo: validation k-step MSE {cur_val:.4g} (sd units)")
        added: list[dict[str, Any]] = []
        rounds: list[dict[str, Any]] = []
        # the search screens on half the fit windows (all of them when they are few: a half would overfit)
        w_search = w_fit.subset(np.arange(len(w_fit.q0)) % 2 == 0) if len(w_fit.q0) >= SEARCH_HALVE else w_fit
        while True:
            scores = []
            for name in spec.effects:
                if name in cur.prob.effects:
                    continue
                pr, x0 = _extend(cur.prob, cur.x, name)
                f = fit(pr, x0, w_search, dd, sd_q, sd_d, max_nfev=SEARCH_NFEV)
                scores.append((position_cost(pr, f.x, w_val, sd_q), name, f))
            if not scores:
                break
            scores.sort(key=lambda s: s[0])
            rounds.append({"before": cur_val, "candidates": {n: v for v, n, _ in scores}})
            passing = [s for s in scores if 1.0 - s[0] / cur_val >= spec.margin and _gated(s[2], s[1])]
            for v, n, f in scores[:3]:
                tag = (
                    "added"
                    if passing and n == passing[0][1]
                    else (
                        "not added: interval includes 0"
                        if (v, n, f) not in passing and 1.0 - v / cur_val >= spec.margin
                        else ""
                    )
                )
                log(f"  {n}: validation {cur_val:.4g} -> {v:.4g} ({1.0 - v / cur_val:+.1%}) {tag}".rstrip())
            if not passing:
                break
            best_val, name, best = passing[0]
            added.append({"name": name, "validation_drop": 1.0 - best_val / cur_val})
            cur, cur_val = best, best_val
        t_search = time.perf_counter()
        declared = fit(prob, prob.vector(start, kp0), w, dd, sd_q, sd_d, max_nfev=FINAL_NFEV)
        final = fit(cur.prob, cur.x, w, dd, sd_q, sd_d, max_nfev=FINAL_NFEV) if added else declared
        t_fit = time.perf_counter()
        # no duty logged: the start's gain comes from simulations of the fitted runs, so each leave-one-run-out
        # refit takes the start the estimator would take without that run (a warm start stays in this basin)
        cold = None if dd is not None else _cold_start(train, labels, base, w_fit, sd_q)
        jks = {"declared": jackknife(declared, train, w, sd_q, sd_d, spec.kt_over_r_sd, cold_start=_on(cold, prob))}
        jks["final"] = (
            jackknife(final, train, w, sd_q, sd_d, spec.kt_over_r_sd, cold_start=_on(cold, final.prob))
            if added
            else jks["declared"]
        )
        if dd is None:  # the scale is fixed by PWM saturation alone: widen to the scales that fit as well
            for tag in dict.fromkeys(jks):
                jk = jks[tag]
                jks[tag] = replace(jk, alternates=scale_profile(jk.full, w, sd_q))
            if not added:
                jks["final"] = jks["declared"]
        errors = {}
        for tag, f in (("declared", declared), ("final", final)):
            p, kp = f.servo()
            errors[tag] = heldout_errors(p, kp, held, labels, horizon)
    t_end = time.perf_counter()
    wall = {
        "total": t_end - t_start,
        "search": t_search - t_start,
        "intervals": t_end - t_fit,
        "cpu": time.process_time() - c_start,
    }
    return ServoCalibration(
        spec=spec,
        train=[r.name for r in train],
        heldout=[r.name for r in held],
        labels=labels,
        declared=declared,
        final=final,
        added=added,
        rounds=rounds,
        errors=errors,
        physics=_physics(jks["final"], train, labels),
        wall=wall,
        jackknives=jks,
        sources=[r.source for r in runs],
    )


def _cold_start(
    train: list[ServoRun], labels: list[str], base: ServoParams, w_fit: Windows, sd_q: float
) -> Callable[[int], tuple[ServoParams, np.ndarray]]:
    """The linear start (`linear_start`, its gain chosen by simulating `w_fit`) without training run i."""

    def start(i: int) -> tuple[ServoParams, np.ndarray]:
        score = window_score(w_fit.subset(w_fit.run != i), sd_q)
        return linear_start([r for j, r in enumerate(train) if j != i], labels, base, KP_GRID, score)

    return start


def _on(
    start: Callable[[int], tuple[ServoParams, np.ndarray]] | None, prob: Problem
) -> Callable[[int], np.ndarray] | None:
    """Start vectors of `prob` from servo starts: the declared parameters, then each effect's own start."""
    if start is None:
        return None

    def vector(i: int) -> np.ndarray:
        p, kp = start(i)
        cur = Problem(prob.base, prob.labels, (), prob.scale)
        x = cur.vector(p, kp)
        for name in prob.effects:
            cur, x = _extend(cur, x, name)
        return x

    return vector


def _run_labels(cal: ServoCalibration) -> dict[str, str]:
    """Each held-out run's trajectory and gain setting, for the verdict's lines."""
    return {n: f"{e['trajectory']}, {e['label']}" for n, e in cal.errors["declared"].items()}


def summary(cal: ServoCalibration) -> list[str]:
    """Lines for the console: effects added, held-out errors before -> after, the verdict per held-out run (which
    metric did not improve), the physics recovered."""
    added = ", ".join(a["name"] for a in cal.added) or "none"
    lines = [f"effects added: {added}"]
    for name in cal.heldout:
        b, a = cal.errors["declared"][name], cal.errors["final"][name]
        ff = ""
        if b["free_fall_rmse"] is not None:
            ff = f"; torque off: {b['free_fall_rmse']:.4f} -> {a['free_fall_rmse']:.4f} rad"
        lines.append(
            f"held-out {name} ({b['trajectory']}, {b['label']}): free-run RMSE {b['free_run_rmse']:.4f} -> "
            f"{a['free_run_rmse']:.4f} rad; k-step {b['k_step_rmse']:.4f} -> {a['k_step_rmse']:.4f} rad{ff}"
        )
    lines += verdict_lines(cal.errors, cal.heldout, _run_labels(cal))
    g = cal.physics["gravity_torque"]
    if g["known_mgl"]:
        lines.append(
            f"gravity torque m·g·l: fitted {g['fitted']:.4f} N·m, known {g['known_mgl']:.4f} ({g['relative_error']:+.1%})"
        )
    ins = cal.physics["truths_inside"]
    if ins["checked"]:
        lines.append(
            f"known values (m·g·l, gains, gain ratios) inside their 95% intervals: {ins['inside']} of {ins['checked']}"
        )
    return lines
