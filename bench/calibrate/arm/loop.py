"""Calibrate a real arm from its own logs: inverse-dynamics identification, effects traced, forward check.

    bench calibrate spec=bench/calibrate/models/panda_gaz.yaml logs=DIR out=DIR   # `method: idim`

1. **Data** (`bench.calibrate.arm.data`): a uniform clock (resampled when the log's is not), the
   same zero-phase low-pass on every signal, derived velocities where none are logged, derived
   accelerations, a held-out time split.
2. **Declared fit**: the torque signal against the declared model's rigid-body torque plus, per
   joint, Coulomb and viscous friction, an offset and a rotor inertia, and corrections to the ten
   inertial parameters of every link (`bench.calibrate.arm.idim`): weighted, bounded least squares.
   What the data cannot identify stays at its declared value and is reported as such.
3. **Trace**: candidate effects (a payload at the flange or tool frame with its centre of mass, a
   gain error per drive for logs of commands or currents, Stribeck and asymmetric friction, a joint
   spring) are each refitted with everything else; one is added only if the held-out error drops by
   the margin, BIC agrees and its interval excludes zero; repeat.
4. **Honesty**: parameters that end at a bound, links whose fitted inertia is not a physical body,
   and any held-out error (per joint, torque or forward k-step) that rises are said in the report
   and in the command's last line.
5. **Forward check**: the declared and the calibrated model are both driven by the logged torque
   from logged states over short horizons (`horizon` seconds), and the per-joint position errors
   compared; this is the simulator a suite would run.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from bench.calibrate.arm.data import ArmLog, load_arm_log
from bench.calibrate.arm.entries import effect_terms, link_entries, param_entries, uncarried_effects, warnings_of
from bench.calibrate.arm.forward import forward_errors
from bench.calibrate.arm.idim import (
    FRICTION_V,
    Block,
    Dynamics,
    Fit,
    bootstrap,
    fit,
    identifiability,
    predict,
    prior_scale,
    windows_of,
)
from bench.calibrate.arm.inertial import STD_NAMES
from bench.calibrate.arm.model import ArmModel, build, check_positions, check_torques, group_std, realise
from bench.calibrate.arm.spec import ArmSpec
from bench.calibrate.fit import information

STRIBECK_VS = (0.01, 0.03, 0.1, 0.3)  # rad/s: Stribeck velocities tried (the best on training data is kept)
WINDOW_S = 0.5  # bootstrap window length (seconds of training data resampled together)
PULL_TRIES = 3  # times a link's pull toward its declared inertia is strengthened before it is left declared


@dataclass
class Candidate:
    """One effect on one target, as regressor blocks."""

    name: str
    target: str
    blocks: list[Block]
    amplitude: list[str]  # labels whose interval must exclude zero
    payload: bool = False
    note: dict[str, Any] = field(default_factory=dict)


@dataclass
class ArmCalibration:
    """Everything a real-arm calibration found, for the report and for runs."""

    spec: ArmSpec
    am: ArmModel
    log: ArmLog
    declared: Fit
    final: Fit
    added: list[dict]
    rejected: list[dict]
    params: list[dict]
    links: list[dict]
    errors: dict[str, Any]
    warnings: list[str]
    values: dict[str, Any]  # what `realise` writes: joints, links, payload
    not_carried: list[str]
    draws: list[dict[str, Any]]  # bootstrap replicates of `values`
    searched: list[str]
    wall: dict[str, float]
    fitted_model: mujoco.MjModel | None = None
    torques: dict[str, np.ndarray] = field(default_factory=dict)  # (N, n) modelled signal: nominal, final


def _joint_cols(n_rows: int, n: int, j: int, col: np.ndarray) -> np.ndarray:
    out = np.zeros((n_rows, n, 1))
    out[:, j, 0] = col
    return out


def _declared_blocks(spec: ArmSpec, am: ArmModel, log: ArmLog, dyn: Dynamics, base: np.ndarray) -> list[Block]:
    n_rows, n = log.q.shape
    m = am.model
    blocks: list[Block] = []
    wanted = None if spec.inertia is None else set(spec.inertia)
    for name, b in zip(am.links, am.link_ids):
        if wanted is not None and name not in wanted and not any(name.endswith(w) for w in wanted):
            continue
        cols = dyn.body_columns(int(b), log.q, log.dq, log.ddq, base)
        blocks.append(
            Block(
                f"link:{name}",
                [f"{name}.{s}" for s in STD_NAMES],
                cols,
                np.full(10, -np.inf),
                np.full(10, np.inf),
                p0 := group_std(m, am.groups[am.links.index(name)]),  # the link and what is fixed to it
                prior_scale(p0),
                pseudo=True,
            )
        )
    for j in range(n):
        jn, d = am.joints[j], int(am.dadr[j])
        dq, ddq = log.dq[:, j], log.ddq[:, j]
        terms = []
        if "coulomb" in spec.friction:
            terms.append(("coulomb", np.tanh(dq / FRICTION_V), 0.0, float(m.dof_frictionloss[d])))
        if "viscous" in spec.friction:
            terms.append(("viscous", dq, 0.0, float(m.dof_damping[d])))
        if "offset" in spec.friction:
            terms.append(("offset", np.ones(n_rows), -np.inf, 0.0))
        if spec.armature:
            terms.append(("armature", ddq, 0.0, float(m.dof_armature[d])))
        if not terms:
            continue
        cols = np.concatenate([_joint_cols(n_rows, n, j, c) for _, c, _, _ in terms], axis=-1)
        blocks.append(
            Block(
                f"joint:{jn}",
                [f"{jn}.{t}" for t, *_ in terms],
                cols,
                np.array([lo for _, _, lo, _ in terms]),
                np.full(len(terms), np.inf),
                np.array([p for *_, p in terms]),
                np.full(len(terms), np.inf),
            )
        )
    return blocks


def _payload_block(am: ArmModel, log: ArmLog, dyn: Dynamics, base: np.ndarray) -> tuple[Block, np.ndarray]:
    p = dyn.body_columns(am.payload_body, log.q, log.dq, log.ddq, base)
    col_m = p[..., 0] + p[..., 1:4] @ am.payload_pos
    col_h = p[..., 1:4] @ am.payload_rot
    cols = np.concatenate([col_m[..., None], col_h], axis=-1)
    name = am.payload_name
    lo = np.array([0.0, -np.inf, -np.inf, -np.inf])
    blk = Block(
        "payload",
        [f"payload@{name}.mass", f"payload@{name}.mx", f"payload@{name}.my", f"payload@{name}.mz"],
        cols,
        lo,
        np.full(4, np.inf),
        np.zeros(4),
        np.full(4, np.inf),
        kind="effect",
    )
    return blk, p[..., 4:]


def _candidates(
    spec: ArmSpec, am: ArmModel, log: ArmLog, dyn: Dynamics, base: np.ndarray, signal: np.ndarray, train: np.ndarray
) -> tuple[list[Candidate], list[str], np.ndarray | None]:
    n_rows, n = log.q.shape
    out: list[Candidate] = []
    searched: list[str] = []
    payload_inertia = None
    if "payload" in spec.effects:
        blk, payload_inertia = _payload_block(am, log, dyn, base)
        out.append(Candidate("payload", am.payload_name, [blk], [blk.labels[0]], payload=True))
        searched.append(f"payload at {am.payload_name} (mass and centre of mass)")
    for j, jn in enumerate(am.joints):
        dq, sgn = log.dq[:, j], np.tanh(log.dq[:, j] / FRICTION_V)
        if "actuator_gain" in spec.effects and spec.torque != "measured":
            blk = Block(
                f"gain:{jn}",
                [f"{jn}.gain_error"],
                _joint_cols(n_rows, n, j, -signal[:, j]),
                np.array([-0.9]),
                np.array([5.0]),
                np.zeros(1),
                np.full(1, np.inf),
                kind="effect",
            )
            out.append(Candidate("actuator_gain", jn, [blk], blk.labels))
        if "stribeck_friction" in spec.effects:
            best = None
            for vs in STRIBECK_VS:
                col = _joint_cols(n_rows, n, j, sgn * np.exp(-((dq / vs) ** 2)))
                c = col[train, j, 0]
                r = signal[train, j] - base[train, j]
                score = float(abs(c @ r) / max(np.linalg.norm(c), 1e-12))
                if best is None or score > best[0]:
                    best = (score, vs, col)
            assert best is not None
            blk = Block(
                f"stribeck:{jn}",
                [f"{jn}.stribeck_excess"],
                best[2],
                np.zeros(1),
                np.full(1, np.inf),
                np.zeros(1),
                np.full(1, np.inf),
                kind="effect",
            )
            out.append(Candidate("stribeck_friction", jn, [blk], blk.labels, note={"stribeck_velocity": best[1]}))
        if "asymmetric_friction" in spec.effects:
            blk = Block(
                f"asym:{jn}",
                [f"{jn}.asymmetry"],
                _joint_cols(n_rows, n, j, np.abs(sgn)),
                np.full(1, -np.inf),
                np.full(1, np.inf),
                np.zeros(1),
                np.full(1, np.inf),
                kind="effect",
            )
            out.append(Candidate("asymmetric_friction", jn, [blk], blk.labels))
        if "joint_spring" in spec.effects:
            q0 = float(am.model.qpos_spring[am.qadr[j]])
            blk = Block(
                f"spring:{jn}",
                [f"{jn}.stiffness"],
                _joint_cols(n_rows, n, j, -(log.q[:, j] - q0)),
                np.zeros(1),
                np.full(1, np.inf),
                np.zeros(1),
                np.full(1, np.inf),
                kind="effect",
            )
            out.append(Candidate("joint_spring", jn, [blk], blk.labels))
    if "actuator_gain" in spec.effects:
        searched.append(
            "actuator gain per drive"
            if spec.torque != "measured"
            else "actuator gain: not searched (the log measures the applied torque, not a command)"
        )
    for fam in ("stribeck_friction", "asymmetric_friction", "joint_spring"):
        if fam in spec.effects:
            searched.append(f"{fam.replace('_', ' ')} per joint")
    return out, searched, payload_inertia


class _Fitter:
    """Fits with a fixed signal, base torque, split and weights; knows the payload's inertia fixed point."""

    def __init__(
        self,
        am: ArmModel,
        signal: np.ndarray,
        base: np.ndarray,
        train: np.ndarray,
        hold: np.ndarray,
        payload_inertia: np.ndarray | None,
        criterion: str,
    ) -> None:
        self.am, self.signal, self.base, self.train, self.hold = am, signal, base, train, hold
        self.payload_inertia, self.criterion = payload_inertia, criterion
        self.spread = np.maximum(signal[hold].std(axis=0), 1e-9)
        self.weights: np.ndarray | None = None

    def fixed(self, f: Fit | None, blocks: list[Block]) -> np.ndarray:
        """The base torque plus, with a payload, its point-mass inertia at the current estimate."""
        if f is None or self.payload_inertia is None or not any(b.name == "payload" for b in blocks):
            return self.base
        m, hx, hy, hz = f.values("payload")
        if m <= 1e-9:
            return self.base
        c_body = self.am.payload_pos + self.am.payload_rot @ (np.array([hx, hy, hz]) / m)
        io = m * (c_body @ c_body * np.eye(3) - np.outer(c_body, c_body))
        vec = np.array([io[0, 0], io[0, 1], io[0, 2], io[1, 1], io[1, 2], io[2, 2]])
        return self.base + self.payload_inertia @ vec

    def __call__(
        self, blocks: list[Block], x0: np.ndarray | None = None, hold_links: bool = False
    ) -> tuple[Fit, np.ndarray]:
        f = fit(blocks, self.signal, self.base, self.train, weights=self.weights, x0=x0, hold_links=hold_links)
        fixed = self.base
        if any(b.name == "payload" for b in blocks):
            for _ in range(4):  # the payload's own inertia: a fixed point in its mass and centre
                fixed = self.fixed(f, blocks)
                f = fit(blocks, self.signal, fixed, self.train, weights=self.weights, x0=f.x, hold_links=hold_links)
        return f, fixed

    def error(self, f: Fit, fixed: np.ndarray) -> tuple[float, np.ndarray]:
        """Held-out normalised error (mean over joints of RMSE / spread) and per-joint RMSE."""
        pred = predict(f.blocks, f.x, fixed)[self.hold]
        rmse = np.sqrt(np.mean((self.signal[self.hold] - pred) ** 2, axis=0))
        return float(np.mean(rmse / self.spread)), rmse

    def ic(self, f: Fit, n_eff: float) -> float:
        return information(f.ssr * n_eff / max(f.n, 1), len(f.x), n_eff, self.criterion)


def _excludes_zero(f: Fit, labels: list[str]) -> bool:
    sd = f.sd()
    idx = [f.labels.index(lab) for lab in labels]
    return all(sd[i] > 0 and abs(f.x[i]) > 1.96 * sd[i] for i in idx)


def _values(am: ArmModel, f: Fit) -> dict[str, Any]:
    """What `realise` writes, from a fit's parameter vector."""
    out: dict[str, Any] = {"joints": {}, "links": {}}
    off = 0
    for b in f.blocks:
        x = f.x[off : off + b.size]
        off += b.size
        if b.name.startswith("link:"):
            out["links"][b.name.split(":", 1)[1]] = np.asarray(x, dtype=np.float64).copy()  # absolute values
        elif b.name.startswith("joint:"):
            jn = b.name.split(":", 1)[1]
            for lab, v in zip(b.labels, x):
                out["joints"].setdefault(jn, {})[lab.rsplit(".", 1)[1]] = float(v)
        elif b.name == "payload" and x[0] > 1e-9:
            out["payload"] = {"mass": float(x[0]), "com": (x[1:4] / x[0]).tolist()}
        elif b.name.startswith("gain:"):
            out["joints"].setdefault(b.name.split(":", 1)[1], {})["gain"] = float(1.0 + x[0])
        elif b.name.startswith("spring:"):
            out["joints"].setdefault(b.name.split(":", 1)[1], {})["stiffness"] = float(x[0])
    return out


def calibrate_arm(
    spec: ArmSpec,
    episodes: list[dict[str, np.ndarray]],
    fps: float,
    *,
    seed: int = 0,
    threads: int = 1,
    log: Callable[[str], None] = lambda msg: None,
) -> ArmCalibration:
    """The whole real-arm loop of the module docstring; bad data or a bad spec is one line, before any fit."""
    t0 = time.perf_counter()
    wall: dict[str, float] = {}
    am = build(spec)
    data = load_arm_log(spec, episodes, fps, seed)
    for r in data.resampled:
        log(
            f"episode {r['episode']}: irregular clock (periods {r['source_period_s']['min'] * 1e3:.2f}-"
            f"{r['source_period_s']['max'] * 1e3:.2f} ms) resampled to {r['fps']:g} Hz by linear interpolation"
        )
    check_positions(am, data.q, spec.signals["qpos"].column)
    signal = data.tau.copy() * (np.asarray(spec.gains) if spec.gains else 1.0)  # currents in torque units
    n_rows, n = signal.shape
    dyn = Dynamics(am.model, am.qadr, am.dadr, am.qpos0)
    base = dyn.torques(data.q, data.dq, data.ddq)
    check_torques(am, signal, base, spec.signals["torque"].column)
    hold = ~data.train
    log(
        f"{len(am.joints)} joints, {n_rows} samples at {data.rate:g} Hz ({int(data.train.sum())} to fit, "
        f"{int(hold.sum())} held out); torque signal: {spec.torque}"
    )
    wall["data"] = time.perf_counter() - t0
    declared = _declared_blocks(spec, am, data, dyn, base)
    cands, searched, payload_inertia = _candidates(spec, am, data, dyn, base, signal, data.train)
    wall["regressor"] = time.perf_counter() - t0 - wall["data"]
    log(
        f"regressor: {sum(b.size for b in declared)} declared parameters, {len(cands)} candidate effects "
        f"({dyn.evaluations:,} inverse-dynamics evaluations, {wall['regressor']:.1f} s)"
    )
    # link blocks hold absolute parameters: the declared links' own torque leaves the fixed part
    links0 = [b for b in declared if b.pseudo]
    base_free = base - sum((np.einsum("njk,k->nj", b.cols, b.prior) for b in links0), np.zeros_like(base))
    fitter = _Fitter(am, signal, base_free, data.train, hold, payload_inertia, spec.trace.criterion)
    blocks, warnings = declared, []
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
        for c in cands:
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
        entry = {"name": c.name, "target": c.target, "round": rnd, "heldout_drop": round(drop, 4), **c.note}
        added.append(entry)
        log(f"round {rnd}: added {c.name} at {c.target} (held-out error -{100 * drop:.1f}%)")
        cur, cur_blocks, cur_err, cur_fixed = fc, cur_blocks + c.blocks, err, fx
    rejected = [v for k, v in tried.items() if not any(f"{a['name']}@{a['target']}" == k for a in added)]
    wall["trace"] = time.perf_counter() - t0 - wall["data"] - wall["regressor"]
    final, fixed = cur, cur_fixed
    ident = identifiability(final.blocks, data.train, final.weights)
    windows = windows_of(data.t + 1e4 * data.episode, data.train, WINDOW_S)
    draws_x = bootstrap(final.blocks, signal, fixed, windows, final.weights, spec.bootstrap, seed, final.x)
    wall["bootstrap"] = time.perf_counter() - t0 - sum(wall.values())
    values = _values(am, final)
    draws = [
        _values(am, Fit(final.blocks, x, final.weights, final.cov, final.tau, final.ssr, final.n)) for x in draws_x
    ]
    params = param_entries(final, f_decl, ident, draws_x, spec)
    for entry in added:  # the physical quantities of what was added, with intervals
        entry.update(effect_terms(entry, final, draws_x))
    links = link_entries(am, values, ident)
    err_final, rmse_final = fitter.error(final, fixed)
    nominal = _nominal_torque(am, data, base)
    rmse_nom = np.sqrt(np.mean((signal[hold] - nominal[hold]) ** 2, axis=0))
    torques = {"nominal": nominal, "final": predict(final.blocks, final.x, fixed)}
    offsets = {jn: v.get("offset", 0.0) for jn, v in values["joints"].items()}
    errors: dict[str, Any] = {
        "torque": {
            "unit": "N·m (N for slide joints)",
            "joints": am.joints,
            "spread": fitter.spread.tolist(),
            "nominal": {"rmse": rmse_nom.tolist(), "nrmse": float(np.mean(rmse_nom / fitter.spread))},
            "declared": {"rmse": rmse_decl.tolist(), "nrmse": err_decl},
            "final": {"rmse": rmse_final.tolist(), "nrmse": err_final},
        }
    }
    fitted = realise(am, values)
    errors["forward"] = forward_errors(am, spec, data, fitted, values, offsets, threads)
    wall["forward"] = time.perf_counter() - t0 - sum(wall.values())
    warnings += warnings_of(final, params, errors, am)
    not_carried = uncarried_effects(values, added, spec)
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
        values,
        not_carried,
        draws,
        searched,
        wall,
        fitted,
        torques,
    )


def _nominal_torque(am: ArmModel, data: ArmLog, base: np.ndarray) -> np.ndarray:
    """The declared model's torque as given: rigid body plus its own rotor inertia, damping and friction loss."""
    m, d = am.model, am.dadr
    return (
        base
        + m.dof_armature[d] * data.ddq
        + m.dof_damping[d] * data.dq
        + m.dof_frictionloss[d] * np.tanh(data.dq / FRICTION_V)
    )


def summary_line(cal: ArmCalibration) -> str:
    """The command's last line: what improved, what did not, and what to look at."""
    tq = cal.errors["torque"]
    parts = [f"held-out torque NRMSE {tq['nominal']['nrmse']:.3g} (declared model) -> {tq['final']['nrmse']:.3g}"]
    fw = cal.errors.get("forward", {})
    if "k_step" in fw:
        parts.append(
            f"forward {fw['horizon_s'] * 1e3:.0f} ms k-step NRMSE {fw['k_step']['nominal']['nrmse']:.3g} -> "
            f"{fw['k_step']['final']['nrmse']:.3g}"
        )
    added = ", ".join(f"{a['name']}@{a['target']}" for a in cal.added) or "none"
    parts.append(f"effects added: {added}")
    at = [p["name"] for p in cal.params if p.get("at_bound")]
    if at:
        parts.append(f"AT A BOUND: {', '.join(at)}")
    rose = [w for w in cal.warnings if "rose" in w]
    if rose:
        parts.append("ROSE: " + "; ".join(rose))
    parts.append(f"{cal.wall['total']:.1f} s")
    return "; ".join(parts)
