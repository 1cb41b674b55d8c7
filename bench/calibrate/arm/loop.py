"""Calibrate a real arm from its own logs: inverse-dynamics identification, effects traced, forward checks.

    bench calibrate spec=bench/calibrate/models/panda_gaz.yaml logs=DIR out=DIR   # `method: idim`

1. **Data** (`bench.calibrate.arm.data`): a uniform clock, the same zero-phase low-pass on every signal,
   derived accelerations, and held-out data that are *new*: by default the stretch (or episodes) that
   repeat the fitted data least, with its repeat share measured (`bench.calibrate.novelty`).
2. **Declared fit** (`bench.calibrate.arm.blocks`, `.idim`): the torque signal against the declared
   model's rigid-body torque plus, per joint, Coulomb and viscous friction, an offset and a rotor
   inertia, and the ten inertial parameters of every link: weighted, bounded, physically consistent
   least squares.
3. **Trace**: candidate effects (a payload at the flange or tool frame, its centre of mass held inside
   the spec's `payload_region`; a gain error per drive for logs of commands or currents; Stribeck and
   asymmetric friction; a joint spring) are each refitted with everything else; one is added only if
   the held-out error drops by the margin, BIC agrees and its interval excludes zero; repeat.
4. **What the data identify** (`bench.calibrate.arm.identifiability`): parameters alone, combinations,
   and unbounded intervals along what they leave open.
5. **Repeat baseline**: memory (the torque of the nearest fitted state, or of one period earlier) scored
   on the same held-out samples; a model is better only if it beats it.
6. **Forward** (`bench.calibrate.arm.forward`, `.didim`): the declared model and each calibrated estimate,
   built from the model edits a run writes, simulated on the held-out data (closed loop: the criterion;
   open loop beside its baselines); the IDIM estimate refined by DIDIM; `estimate: auto` carries the one
   the held-out simulation supports.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from bench.calibrate import novelty
from bench.calibrate.apply import CalibrationEdit, edited_model, edits
from bench.calibrate.arm import forward
from bench.calibrate.arm.blocks import Fitter, Regression, nominal_torque, regression, torque_error, values_of
from bench.calibrate.arm.data import ArmLog, load_arm_log
from bench.calibrate.arm.didim import Iteration, refine
from bench.calibrate.arm.dynamics import Dynamics
from bench.calibrate.arm.entries import effect_terms, link_entries, param_entries, uncarried_effects, warnings_of
from bench.calibrate.arm.identifiability import Identifiability, analyse, payload_sentence
from bench.calibrate.arm.idim import Fit, bootstrap, fit_at, predict, windows_of
from bench.calibrate.arm.model import ArmModel, Values, build, check_positions, check_torques, realise
from bench.calibrate.arm.spec import ArmSpec
from bench.core.threads import one_blas_thread

WINDOW_S = 0.5  # bootstrap window length (seconds of training data resampled together)


@dataclass
class Estimate:
    """One calibrated estimate (IDIM, or its DIDIM refinement) as a run would carry it."""

    name: str
    fit: Fit
    fixed: np.ndarray  # (N, n) fixed torque on the logged rows
    values: Values  # what `realise` writes
    edits: list[CalibrationEdit]  # the model edits a run writes (`bench.calibrate.apply`)
    model: mujoco.MjModel  # the declared model with those edits, as a run has it
    torque_rmse: np.ndarray  # (n,) held-out torque RMSE on the logged states
    torque_nrmse: float


@dataclass
class ArmCalibration:
    """Everything a real-arm calibration found, for the report and for runs."""

    spec: ArmSpec
    am: ArmModel
    log: ArmLog
    declared: Fit
    final: Fit  # the carried estimate's fit
    added: list[dict]
    rejected: list[dict]
    params: list[dict]
    links: list[dict]
    errors: dict[str, Any]
    warnings: list[str]
    values: Values  # what `realise` writes for the carried estimate: joints, links, payload
    not_carried: list[str]
    draws: list[Values]  # bootstrap replicates of `values`
    searched: list[str]
    wall: dict[str, float]
    fitted_model: mujoco.MjModel | None = None
    torques: dict[str, np.ndarray] = field(default_factory=dict)  # (N, n) modelled signal: nominal, final
    estimates: dict[str, Estimate] = field(default_factory=dict)
    chosen: str = "idim"
    identifiability: Identifiability | None = None
    trust: dict[str, object] = field(default_factory=dict)
    didim_history: list[Iteration] = field(default_factory=list)


def _excludes_zero(f: Fit, labels: list[str]) -> bool:
    sd = f.sd()
    idx = [f.labels.index(lab) for lab in labels]
    return all(sd[i] > 0 and abs(f.x[i]) > 1.96 * sd[i] for i in idx)


def _repeat_baseline(data: ArmLog, signal: np.ndarray, spread: np.ndarray) -> dict[str, Any]:
    """Memory on the held-out rows: the signal of the nearest fitted state (q, dq, ddq), and of one period earlier."""
    feats = np.hstack([data.q, data.dq, data.ddq])
    hold = data.hold
    pred, _ = novelty.nearest_signal(feats[data.train], signal[data.train], feats[hold], novelty.spread(feats))
    out: dict[str, Any] = {}

    def score(p: np.ndarray) -> dict[str, Any]:
        nrmse, rmse = torque_error(signal[hold], p, spread)
        return {"rmse": rmse.tolist(), "nrmse": nrmse}

    out["nearest"] = {**score(pred), "what": "the measured torque of the nearest fitted state (q, dq, ddq)"}
    period = data.heldout.period_s
    if period:
        rows = np.flatnonzero(hold)
        p = np.full((len(rows), signal.shape[1]), np.nan)
        for e in np.unique(data.episode[rows]):
            ep = np.flatnonzero(data.episode == e)
            sel = data.episode[rows] == e
            local = np.searchsorted(ep, rows[sel])
            p[sel] = novelty.period_signal(signal[ep], data.t[ep], period, data.train[ep], local)
        ok = np.all(np.isfinite(p), axis=1)
        if ok.mean() >= 0.5:
            nrmse, rmse = torque_error(signal[rows[ok]], p[ok], spread)
            out["period"] = {
                "rmse": rmse.tolist(),
                "nrmse": nrmse,
                "covered_share": float(ok.mean()),
                "what": f"the measured torque one period ({period:.4g} s) earlier, where that instant was fitted",
            }
    best = min(("nearest", "period"), key=lambda k: out[k]["nrmse"] if k in out else np.inf)
    out["best"] = best
    return out


def _estimate(name: str, am: ArmModel, f: Fit, fixed: np.ndarray, fitter: Fitter) -> Estimate:
    values = values_of(am, f)
    model_edits = edits(am.model, realise(am, values))
    nrmse, rmse = fitter.error(f, fixed)
    return Estimate(name, f, fixed, values, model_edits, edited_model(am.model, model_edits), rmse, nrmse)


def _drive(am: ArmModel, values: Values, model: mujoco.MjModel) -> forward.Drive:
    joints = values.get("joints", {})
    offset = np.array([joints.get(jn, {}).get("offset", 0.0) for jn in am.joints])
    gain = np.array([joints.get(jn, {}).get("gain", 1.0) for jn in am.joints])
    return forward.Drive(model, offset, gain)


def _trace(
    spec: ArmSpec, fitter: Fitter, reg: Regression, log: Callable[[str], None]
) -> tuple[Fit, np.ndarray, list[dict], list[dict], Fit, float, np.ndarray]:
    """The declared fit, then effects added round by round (module docstring, step 3)."""
    blocks = list(reg.declared)
    f_decl, fixed = fitter(blocks)
    fitter.weights = f_decl.weights
    err_decl, rmse_decl = fitter.error(f_decl, fixed)
    log(f"declared fit: held-out torque NRMSE {err_decl:.4g}")
    cur, cur_blocks, cur_err, cur_fixed = f_decl, list(blocks), err_decl, fixed
    added: list[dict] = []
    tried: dict[str, dict] = {}
    n_eff = f_decl.n / f_decl.tau
    for rnd in range(1, spec.trace.max_effects + 1):
        # screen every candidate with the links held where they are (a convex refit), then refit the
        # most promising `max_tries` with everything free; only those full refits can be accepted
        screened = []
        for c in reg.candidates:
            if any(a["name"] == c.name and a["target"] == c.target for a in added):
                continue
            fc, fx = fitter(cur_blocks + c.blocks, np.concatenate([cur.x, *(b.prior for b in c.blocks)]), True)
            err, _ = fitter.error(fc, fx)
            screened.append((1.0 - err / cur_err, c))
            tried[f"{c.name}@{c.target}"] = {
                "name": c.name,
                "target": c.target,
                "round": rnd,
                "screen_drop": round(1.0 - err / cur_err, 4),
            }
        results = []
        for screen, c in sorted(screened, key=lambda r: -r[0])[: spec.trace.max_tries]:
            if screen < spec.trace.min_score * spec.trace.margin:
                continue
            fc, fx = fitter(cur_blocks + c.blocks, np.concatenate([cur.x, *(b.prior for b in c.blocks)]))
            err, _ = fitter.error(fc, fx)
            drop = 1.0 - err / cur_err
            better_ic = fitter.ic(fc, n_eff) < fitter.ic(cur, n_eff)
            excl = _excludes_zero(fc, c.amplitude)
            tried[f"{c.name}@{c.target}"].update(
                heldout_drop=round(drop, 4), criterion_improves=bool(better_ic), interval_excludes_zero=bool(excl)
            )
            if drop >= spec.trace.margin and better_ic and excl:
                results.append((drop, c, fc, fx, err))
        if not results:
            break
        drop, c, fc, fx, err = max(results, key=lambda r: r[0])
        added.append({"name": c.name, "target": c.target, "round": rnd, "heldout_drop": round(drop, 4), **c.note})
        log(f"round {rnd}: added {c.name} at {c.target} (held-out error -{100 * drop:.1f}%)")
        cur, cur_blocks, cur_err, cur_fixed = fc, cur_blocks + c.blocks, err, fx
    rejected = [v for k, v in tried.items() if not any(f"{a['name']}@{a['target']}" == k for a in added)]
    return cur, cur_fixed, added, rejected, f_decl, err_decl, rmse_decl


@one_blas_thread()
def calibrate_arm(
    spec: ArmSpec,
    episodes: list[dict[str, np.ndarray]],
    fps: float,
    *,
    seed: int = 0,
    threads: int = 1,
    log: Callable[[str], None] = lambda msg: None,
) -> ArmCalibration:
    """The whole real-arm loop of the module docstring; bad data or a bad spec is one line, before any fit.

    One thread: numpy's and scipy's BLAS are held to one (`bench.core.threads`), MuJoCo rollouts use `threads`.
    """
    t0 = time.perf_counter()
    wall: dict[str, float] = {}

    def lap(name: str) -> None:
        wall[name] = time.perf_counter() - t0 - sum(wall.values())

    am = build(spec)
    data = load_arm_log(spec, episodes, fps, seed)
    for r in data.resampled:
        log(
            f"episode {r['episode']}: irregular clock (periods {r['source_period_s']['min'] * 1e3:.2f}-"
            f"{r['source_period_s']['max'] * 1e3:.2f} ms) resampled to {r['fps']:g} Hz by linear interpolation"
        )
    check_positions(am, data.q, spec.signals["qpos"].column)
    signal = data.tau.copy() * (np.asarray(spec.gains) if spec.gains else 1.0)  # currents in torque units
    n_rows = len(signal)
    log(
        f"{len(am.joints)} joints, {n_rows} samples at {data.rate:g} Hz ({int(data.train.sum())} to fit, "
        f"{int(data.hold.sum())} held out); torque signal: {spec.torque}"
    )
    log(data.heldout.sentence())
    lap("data")
    dyn = Dynamics(am.model, am.qadr, am.dadr, am.qpos0)
    reg = regression(spec, am, data, dyn, signal, data.train)
    check_torques(am, signal, reg.base, spec.signals["torque"].column)
    lap("regressor")
    log(
        f"regressor: {sum(b.size for b in reg.declared)} declared parameters, {len(reg.candidates)} candidate "
        f"effects ({dyn.evaluations:,} samples through MuJoCo's kinematics, {wall['regressor']:.1f} s)"
    )
    fitter = Fitter(am, signal, reg.base_free, data.train, data.hold, reg.payload_inertia, spec.trace.criterion)
    idim_fit, fixed, added, rejected, f_decl, err_decl, rmse_decl = _trace(spec, fitter, reg, log)
    lap("trace")
    warnings: list[str] = []
    fenced = False  # the payload held at its region's edge: the region, not the data, sets it
    if any(a["name"] == "payload" for a in added):
        region = _payload_region_check(spec, am, fitter, idim_fit)
        warnings += region
        fenced = bool(region)
    estimates = {"idim": _estimate("idim", am, idim_fit, fixed, fitter)}
    # forward: the declared model and each estimate simulated on the held-out data
    bench = forward.bench_of(am, spec, data, threads)
    loop = forward.loop_for(am, spec, data) if not isinstance(bench, str) else None
    history: list[Iteration] = []
    if not isinstance(bench, str) and loop is not None and spec.didim > 0:

        def drive_of(f: Fit) -> forward.Drive:
            v = values_of(am, f)
            return _drive(am, v, edited_model(am.model, edits(am.model, realise(am, v))))

        f_didim, _, history = refine(spec, am, dyn, bench, loop, idim_fit, added, drive_of, log)
        if f_didim is not None:  # the same blocks on the logged rows: the DIDIM parameters stated there
            probe = Fit(idim_fit.blocks, f_didim.x, idim_fit.weights, idim_fit.cov, 1.0, 0.0, 0)
            fixed_log = fitter.fixed(probe, idim_fit.blocks)
            f_log = fit_at(idim_fit.blocks, f_didim.x, signal, fixed_log, data.train, idim_fit.weights)
            estimates["didim"] = _estimate("didim", am, f_log, fixed_log, fitter)
    lap("didim")
    fw: forward.Forward
    if isinstance(bench, str):
        fw = {"skipped": bench}
    else:
        assert loop is not None
        drives = {"nominal": forward.Drive(am.model, np.zeros(len(am.joints)), np.ones(len(am.joints)))}
        drives.update({k: _drive(am, e.values, e.model) for k, e in estimates.items()})
        fw = forward.forward_errors(bench, drives, loop)
    lap("forward")
    chosen, why = _choose(spec, fw, estimates)
    est = estimates[chosen]
    log(f"estimate carried: {chosen} ({why})")
    final = est.fit
    rows = np.flatnonzero(data.train)
    dof = max(final.n - len(final.x), 1)
    ident = analyse(final.blocks, final.x, rows, final.weights, final.tau * final.ssr / dof, fitter.spread)
    windows = windows_of(data.t + 1e4 * data.episode, data.train, WINDOW_S)
    draws_x = bootstrap(final.blocks, signal, est.fixed, windows, final.weights, spec.bootstrap, seed, final.x)
    lap("bootstrap")
    draws = [
        values_of(am, Fit(final.blocks, x, final.weights, final.cov, final.tau, final.ssr, final.n)) for x in draws_x
    ]
    params = param_entries(final, f_decl, ident, draws_x, spec)
    for entry in added:  # the physical quantities of what was added, with intervals
        entry.update(effect_terms(entry, final, draws_x, ident))
    if fenced:
        held_at_edge(added, params)
    links = link_entries(am, est.values, ident.status)
    nominal = nominal_torque(am, data, reg.base)
    hold = data.hold
    nrmse_nom, rmse_nom = torque_error(signal[hold], nominal[hold], fitter.spread)
    repeat = _repeat_baseline(data, signal, fitter.spread)
    best_repeat = repeat[repeat["best"]]["nrmse"]
    torque: dict[str, Any] = {
        "unit": "N·m (N for slide joints)",
        "joints": am.joints,
        "spread": fitter.spread.tolist(),
        "nominal": {"rmse": rmse_nom.tolist(), "nrmse": nrmse_nom},
        "declared": {"rmse": rmse_decl.tolist(), "nrmse": err_decl},
        **{k: {"rmse": e.torque_rmse.tolist(), "nrmse": e.torque_nrmse} for k, e in estimates.items()},
        "final": {"rmse": est.torque_rmse.tolist(), "nrmse": est.torque_nrmse},
        "repeat": repeat,
        "beats_repeat": bool(est.torque_nrmse < best_repeat),
    }
    errors: dict[str, Any] = {"torque": torque, "forward": fw}
    verdict: forward.Verdict = (
        forward.verdict(fw, chosen) if "skipped" not in fw else {"simulates_better": None, "why": fw["skipped"]}
    )
    trust = {
        "heldout": data.heldout.to_json(),
        "estimate": chosen,
        "estimate_why": why,
        "torque_beats_repeat": torque["beats_repeat"],
        "repeat_baseline_nrmse": best_repeat,
        "forward": verdict,
        "simulates_better": verdict.get("simulates_better"),
    }
    warnings += _trust_warnings(data, torque, verdict, repeat)
    warnings += warnings_of(final, params, errors, am)
    sentence = (
        payload_sentence(ident, f"payload@{am.payload_name}") if any(a["name"] == "payload" for a in added) else None
    )
    if sentence:
        warnings.append(sentence)
    not_carried = uncarried_effects(est.values, added, spec)
    wall["total"] = time.perf_counter() - t0
    return ArmCalibration(
        spec,
        am,
        data,
        f_decl,
        final,
        added,
        rejected,
        params,
        links,
        errors,
        warnings,
        est.values,
        not_carried,
        draws,
        reg.searched,
        wall,
        est.model,
        {"nominal": nominal, "final": predict(final.blocks, final.x, est.fixed)},
        estimates,
        chosen,
        ident,
        trust,
        history,
    )


def _choose(spec: ArmSpec, fw: forward.Forward, estimates: dict[str, Estimate]) -> tuple[str, str]:
    """Which estimate runs carry, and why: the spec's choice, else the one the held-out closed-loop free run supports."""
    if spec.estimate != "auto":
        if spec.estimate not in estimates:
            return "idim", f"the spec asks for {spec.estimate}, which did not improve on IDIM: IDIM"
        return spec.estimate, "the spec's choice (estimate: " + spec.estimate + ")"
    if "didim" not in estimates:
        return "idim", "the only estimate (no forward refinement ran)"
    if "skipped" in fw:
        return "idim", "no forward check to compare the two"
    free = fw["closed_loop"]["free_run"]
    a, b = free["idim"]["nrmse"], free["didim"]["nrmse"]
    if b is not None and (a is None or b < a * 0.98):
        return "didim", f"it simulates the held-out data better in closed loop (free-run NRMSE {b:.4g} against {a:.4g})"
    return "idim", (
        f"DIDIM does not simulate the held-out data clearly better (free-run NRMSE {b if b is None else f'{b:.4g}'} "
        f"against {a if a is None else f'{a:.4g}'}): the torque fit's estimate is kept"
    )


HELD = "none: held at the edge of the declared payload_region, so the region, not the data, sets it"


def held_at_edge(added: list[dict[str, Any]], params: list[dict[str, Any]]) -> None:
    """No interval for a payload whose centre of mass the fit held at its region's edge (its mass and centre of
    mass are then the region's consequence: an interval around them would exclude the truth with confidence)."""
    for a in added:
        if a["name"] == "payload":
            a.update(mass_interval=None, com_interval=None, interval_note=HELD)
    for q in params:
        if q["name"].startswith("payload@"):
            q.update(interval=None, interval_method=HELD)


def _payload_region_check(spec: ArmSpec, am: ArmModel, fitter: Fitter, f: Fit) -> list[str]:
    """A warning when the fit, unfenced, wants the payload's centre of mass outside the declared region."""
    free, _ = fitter(f.blocks, x0=f.x, fences=False)
    m, *h = free.values("payload")
    if m <= 1e-9:
        return []
    centre, radius = np.asarray(spec.payload_region[0]), spec.payload_region[1]
    com = np.asarray(h) / m
    dist = float(np.linalg.norm(com - centre))
    if dist <= radius * 1.001:
        return []
    return [
        f"the fit wants the payload's centre of mass at {np.round(com, 3).tolist()} m in {am.payload_name!r} "
        f"({dist:.3g} m from the region's centre), outside the declared region (radius {radius:g} m, spec field "
        f"'payload_region'); it is held at the region's edge (unfenced mass {m:.4g} kg)"
    ]


def _trust_warnings(
    data: ArmLog, torque: dict[str, Any], verdict: forward.Verdict, repeat: dict[str, Any]
) -> list[str]:
    out = []
    if data.heldout.nothing_new:
        out.append(data.heldout.sentence())
    best = repeat["best"]
    if not torque["beats_repeat"]:
        out.append(
            f"the calibrated model does not beat the repeat baseline on the held-out data (torque NRMSE "
            f"{torque['final']['nrmse']:.4g} against {repeat[best]['nrmse']:.4g} for {repeat[best]['what']}): "
            "its held-out error says nothing a memory of the log would not"
        )
    if verdict.get("simulates_better") is False:
        out.append(
            "the calibrated model simulates the held-out data worse than the declared one in closed loop ("
            + "; ".join(verdict.get("rose", []))
            + "): bench run ... calibration= warns, strict=true refuses it"
        )
    return out


def summary_line(cal: ArmCalibration) -> str:
    """The command's last line: what improved against what, what did not, and what to look at."""
    tq = cal.errors["torque"]
    rep = tq["repeat"][tq["repeat"]["best"]]["nrmse"]
    parts = [
        f"held-out torque NRMSE {tq['nominal']['nrmse']:.3g} (declared model) -> {tq['final']['nrmse']:.3g} "
        f"(repeat baseline {rep:.3g}; {100 * cal.log.heldout.repeat_share:.0f}% of the held-out data repeat fitted states)"
    ]
    fw = cal.errors.get("forward", {})
    if "closed_loop" in fw and fw["closed_loop"]["free_run"]:
        free = fw["closed_loop"]["free_run"]
        parts.append(
            f"closed-loop free-run NRMSE {free['nominal']['nrmse']:.3g} -> {free[cal.chosen]['nrmse']:.3g} ({cal.chosen})"
        )
    added = ", ".join(f"{a['name']}@{a['target']}" for a in cal.added) or "none"
    parts.append(f"effects added: {added}")
    at = [p["name"] for p in cal.params if p.get("at_bound")]
    if at:
        parts.append(f"AT A BOUND: {', '.join(at)}")
    flags = [w for w in cal.warnings if "rose" in w or "worse" in w or "NOTHING NEW" in w or "repeat baseline" in w]
    if flags:
        parts.append("CHECK: " + "; ".join(flags))
    parts.append(f"{cal.wall['total']:.1f} s")
    return "; ".join(parts)


def score_reference(cal: ArmCalibration, table: Mapping[str, object]) -> dict[str, object]:
    """Another model's predicted torque on this calibration's held-out rows (a table with `t` and `tau`, e.g.
    results/references/gaz_panda.json), scored by the same code as ours: {nrmse, rmse}, or {why} when the table
    was made for other rows (another processing or split): then it must be made anew."""
    rows = np.flatnonzero(cal.log.hold)
    t, tau = np.asarray(table.get("t", []), dtype=float), np.asarray(table.get("tau", []), dtype=float)
    if (
        len(t) != len(rows)
        or not np.allclose(t, cal.log.t[rows], atol=1e-5)
        or tau.shape != (len(rows), len(cal.am.joints))
    ):
        return {
            "why": f"the table holds {len(t)} rows; this calibration holds out {len(rows)} other ones: make it anew"
        }
    signal = cal.log.tau * (np.asarray(cal.spec.gains) if cal.spec.gains else 1.0)
    nrmse, rmse = torque_error(signal[rows], tau, np.asarray(cal.errors["torque"]["spread"]))
    return {"nrmse": nrmse, "rmse": rmse.tolist()}
