"""The forward check of an arm calibration: its models simulated from logged states under the logged torque.

Inverse dynamics fits torques; a suite steps the simulator forward. This check replays what the
robot did in the declared model and in every calibrated estimate, each built from the model edits
that `bench run ... calibration=` writes (`bench.calibrate.apply.edits`, applied by the runner's own
`write_fields`), so the model checked is the model a run would simulate. Contacts and the simulator's
air drag are off (the real arm's workspace is not the suite's scene; MuJoCo's fluid model drags each
body's equivalent inertia box, not the arm's shape). A `measured` torque is the link-side torque of a
joint torque sensor: the rotor inertia (armature) is on the sensor's other side and the calibration
does not change it, so both models step their links without it.

Two ways, at the horizons of `spec.horizons` (k-step: re-initialised from the log every horizon):

- **closed loop**, the criterion: the log was recorded under feedback (a robot tracking an
  excitation), and the simulation closes the same loop around the log: the applied torque is the
  logged one plus kp (q_log - q) + kd (dq_log - dq) (`bench.calibrate.feedback`). The loop is the
  log's own where the spec declares it (`controller:`), else a *virtual* tracking loop with the same
  gains for every model: a joint's stiffness is `loop_gain` times its logged torque spread over its
  position spread (a torque error the size of the joint's torque moves it by 1 / loop_gain of its range),
  its damping ratio 0.7 on the declared model's mean link inertia. With the loop the arm is stable, so
  the whole held-out window is also simulated in one free run. Integration is MuJoCo's `implicitfast` (the loop's
  damping on link inertias of a few grams-square-metre is beyond explicit Euler at the model's step).
- **open loop** (the logged torque alone), beside two baselines on the same horizons: constant
  velocity (no dynamics at all) and the repeat baseline (`bench.calibrate.novelty.nearest_motion`:
  the motion of the nearest fitted state). On an arm whose distal link inertia about its joint axis
  is small, any torque error is amplified into acceleration error (M^-1), so open-loop errors can
  exceed constant velocity for every model; the check then says open loop is not informative.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import TypedDict

import mujoco
import numpy as np

from bench.calibrate.arm.data import ArmLog
from bench.calibrate.arm.model import ArmModel, require_motors
from bench.calibrate.arm.spec import ArmSpec
from bench.calibrate.novelty import horizon_starts, nearest_motion, spread
from bench.replay.data import Recording, Window
from bench.replay.metrics import segment_errors
from bench.replay.simulate import Coordinates, Segments, Simulator, Variant, free_runs, horizons

MIN_FRAMES = 2  # a horizon shorter than this is no forward check
DAMPING_RATIO = 0.7  # of the virtual tracking loop


class Score(TypedDict):
    """One simulation of the held-out horizons scored: position RMSE per joint and mean NRMSE (None: diverged)."""

    rmse: list[float] | None
    nrmse: float | None
    finite: bool


class ClosedLoop(TypedDict):
    k_step: dict[str, dict[str, Score]]  # horizon (s) -> drive -> score
    free_run: dict[str, Score]  # drive -> score


class OpenLoop(TypedDict, total=False):
    k_step: dict[str, dict[str, Score]]  # horizon (s) -> drive or baseline -> score
    informative: bool
    why: str


class Forward(TypedDict, total=False):
    """The forward check (calibration.json's `errors.forward`); only `skipped` when there is none."""

    input: str
    integrator: str
    fps: float
    loop: dict[str, object]
    horizons_s: list[float]
    closed_loop: ClosedLoop
    open_loop: OpenLoop
    skipped: str


class Verdict(TypedDict, total=False):
    """Whether a model simulates the held-out data at least as well as the reference (`verdict`); `why` when unchecked."""

    criterion: str
    declared: float | None
    calibrated: float | None
    simulates_better: bool | None
    rose: list[str]
    why: str


@dataclass(frozen=True)
class Loop:
    """The feedback the simulation closes around the log: kp, kd per joint (torque per rad, per rad/s)."""

    kp: np.ndarray
    kd: np.ndarray
    source: str  # log (the spec's `controller`) | virtual (`loop_gain`)
    gain: float | None = None  # the virtual loop's stiffness in torque spreads per position spread

    def to_json(self) -> dict[str, object]:
        return {
            "source": self.source,
            "kp": self.kp.tolist(),
            "kd": self.kd.tolist(),
            "loop_gain": self.gain,
            "why": "the log's own loop (spec field 'controller')"
            if self.source == "log"
            else f"a virtual tracking loop, identical for every model: stiffness {self.gain:g} x each joint's torque "
            f"spread over its position spread, damping ratio {DAMPING_RATIO} on the declared model's mean link "
            "inertia (the log's own loop is not declared)",
        }


@dataclass
class Drive:
    """One model and how the logged torque signal drives it: ctrl = (signal - offset / gain) / (gear x gain0)."""

    model: mujoco.MjModel
    offset: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (n,) the signal's fitted constant
    gain: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (n,) the drive's fitted gain (1: none)


def _prepare(model: mujoco.MjModel, fps: float, link_side: bool, motors: np.ndarray, dadr: np.ndarray):
    m = copy.copy(model)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    m.opt.density, m.opt.viscosity = 0.0, 0.0
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    substeps = max(1, int(round(1.0 / (fps * m.opt.timestep))))
    m.opt.timestep = 1.0 / (fps * substeps)
    if link_side:  # a link-side torque drives the link: the rotor is on the sensor's other side
        m.dof_armature[dadr] = 0.0
    return m, substeps


def link_inertia(am: ArmModel, q: np.ndarray, link_side: bool) -> np.ndarray:
    """(n,) mean diagonal of the declared model's joint-space inertia over some logged poses."""
    m = copy.copy(am.model)
    if link_side:
        m.dof_armature[am.dadr] = 0.0
    d = mujoco.MjData(m)
    full = np.zeros((m.nv, m.nv))
    out = np.zeros(len(am.dadr))
    rows = np.linspace(0, len(q) - 1, min(len(q), 50)).astype(int)
    for i in rows:
        d.qpos[:] = am.qpos0
        d.qpos[am.qadr] = q[i]
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, full, d.qM)
        out += np.diag(full)[am.dadr]
    return out / len(rows)


def loop_for(am: ArmModel, spec: ArmSpec, data: ArmLog) -> Loop:
    """The log's loop when declared, else the virtual tracking loop of `spec.loop_gain`."""
    if spec.controller is not None:
        return Loop(np.asarray(spec.controller[0], float), np.asarray(spec.controller[1], float), "log")
    inertia = link_inertia(am, data.q, spec.torque == "measured")
    tau = data.tau * (np.asarray(spec.gains) if spec.gains else 1.0)
    kp = spec.loop_gain * np.maximum(tau.std(axis=0), 1e-6) / np.maximum(data.q.std(axis=0), 1e-6)
    return Loop(kp, 2 * DAMPING_RATIO * np.sqrt(kp * inertia), "virtual", spec.loop_gain)


@dataclass
class Bench:
    """The dense log at the check's rate, its windows, and a way to run drives over segments."""

    am: ArmModel
    spec: ArmSpec
    rec: Recording
    tau: np.ndarray  # (N, n) torque signal in torque units
    fps: float
    train: list[Window]
    hold: list[Window]
    threads: int = 1

    def horizon_frames(self, seconds: float) -> int:
        return max(MIN_FRAMES, int(round(seconds * self.fps)))

    def simulate(self, drive: Drive, loop: Loop | None, segs: Segments) -> np.ndarray:
        """(n_segs, length, 2n) simulated [q, dq] of the arm's joints."""
        am, n = self.am, len(self.am.joints)
        m, substeps = _prepare(drive.model, self.fps, self.spec.torque == "measured", am.motors, am.dadr)
        gains = drive.gain if drive.gain.size else np.ones(n)
        off = drive.offset if drive.offset.size else np.zeros(n)
        ctrl = np.zeros((len(self.tau), m.nu))
        gear = m.actuator_gear[am.motors, 0]
        ctrl[:, am.motors] = (self.tau - off / gains) / gear / am.model.actuator_gainprm[am.motors, 0]
        if loop is not None:
            gain = m.actuator_gainprm[am.motors, 0]
            m.actuator_biastype[am.motors] = mujoco.mjtBias.mjBIAS_AFFINE
            m.actuator_biasprm[am.motors, 0] = 0.0
            m.actuator_biasprm[am.motors, 1] = -loop.kp / gear**2
            m.actuator_biasprm[am.motors, 2] = -loop.kd / gear**2
            m.actuator_ctrllimited[am.motors] = 0
            ctrl[:, am.motors] += (loop.kp * self.rec.qpos + loop.kd * self.rec.qvel) / (gear * gain)
        nv = m.nv

        def init(frames: np.ndarray, lq: np.ndarray, lv: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            fq = np.repeat(am.qpos0[None, :], len(frames), axis=0)
            fv = np.zeros((len(frames), nv))
            fq[:, am.qadr], fv[:, am.dadr] = lq, lv
            return fq, fv

        sim = Simulator(m, self.rec, substeps, self.threads)
        try:
            variant = Variant(
                m, np.repeat(ctrl, substeps, axis=0), np.zeros(nv), coords=Coordinates(am.qadr, am.dadr, init)
            )
            return sim.run([variant], segs)[0]
        finally:
            sim.close()

    def score(self, pred: np.ndarray, segs: Segments) -> Score:
        n = len(self.am.joints)
        spread_ = np.maximum(self.rec.qpos[self.rec.frames(self.hold)].std(axis=0), 1e-12)
        err = segment_errors(pred[..., :n], self.rec, segs, spread_)
        finite = bool(np.all(np.isfinite(pred)))
        return {
            "rmse": err.rmse.tolist() if finite else None,
            "nrmse": float(np.mean(err.nrmse)) if finite else None,
            "finite": finite,
        }


def bench_of(am: ArmModel, spec: ArmSpec, data: ArmLog, threads: int = 1) -> Bench | str:
    """The dense log at the model's step (at most the log's rate), or why there is no forward check."""
    why = require_motors(am)
    if why:
        return f"no forward check: {why}"
    src = data.source_fps
    step = max(1, int(round(src * am.model.opt.timestep)))  # log frames per model timestep (at least one)
    fps = src / step
    q, dq, tau = (data.dense[k][::step] for k in ("q", "dq", "tau"))
    if spec.gains:  # a current signal in torque units
        tau = tau * np.asarray(spec.gains)
    lengths = [len(range(0, int(b - a), step)) for a, b in zip(data.dense_offsets[:-1], data.dense_offsets[1:])]
    offs = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)

    def windows(ws: list[tuple[int, int, int]]) -> list[Window]:
        out = []
        for e, a, b in ws:
            w = Window(e, -(-a // step), min(int(offs[e + 1] - offs[e]), b // step))
            if len(w) > MIN_FRAMES:
                out.append(w)
        return out

    rec = Recording(
        fps=fps,
        qpos=q,
        qvel=dq,
        ctrl=np.zeros((len(q), 0)),
        inputs=None,
        offsets=offs,
        train=[],
        holdout=[],
        qvel_logged=True,
    )
    return Bench(am, spec, rec, tau, fps, windows(data.dense_train), windows(data.dense_hold), threads)


def _baselines(bench: Bench, segs: Segments) -> dict[str, Score]:
    """Constant velocity and the repeat baseline (the nearest fitted state's motion) on the same horizons."""
    rec, n = bench.rec, len(bench.am.joints)
    steps = np.arange(1, segs.length + 1) / bench.fps
    cv = rec.qpos[segs.start][:, None, :] + rec.qvel[segs.start][:, None, :] * steps[None, :, None]
    out = {"constant_velocity": bench.score(np.concatenate([cv, np.zeros_like(cv)], axis=-1), segs)}
    k = segs.length
    fit_starts = horizon_starts(rec.offsets, bench.train, k)
    if fit_starts.size:
        feats = np.hstack([rec.qpos, rec.qvel])
        q_next = nearest_motion(rec.qpos, feats, segs.start, fit_starts, k + 1, spread(feats))[:, 1:, :n]
        out["repeat"] = bench.score(np.concatenate([q_next, np.zeros_like(q_next)], axis=-1), segs)
    return out


def forward_errors(bench: Bench, drives: dict[str, Drive], loop: Loop) -> Forward:
    """Closed-loop k-step and free-run errors, and open-loop k-step errors beside their baselines, per drive."""
    spec = bench.spec
    out: Forward = {
        "input": "the logged torque"
        + (" (link side: every model steps its links without rotor inertia)" if spec.torque == "measured" else ""),
        "integrator": "implicitfast",
        "fps": bench.fps,
        "loop": loop.to_json(),
        "horizons_s": [],
        "closed_loop": {"k_step": {}, "free_run": {}},
        "open_loop": {"k_step": {}},
    }
    if not bench.hold:
        out["skipped"] = "no held-out window is long enough for a forward check"
        return out
    for h in spec.horizons:
        k = bench.horizon_frames(h)
        key = f"{k / bench.fps:.4g}"
        out["horizons_s"].append(k / bench.fps)
        segs = horizons(bench.rec, bench.hold, k)
        out["closed_loop"]["k_step"][key] = {
            lab: bench.score(bench.simulate(d, loop, segs), segs) for lab, d in drives.items()
        }
        open_k = {lab: bench.score(bench.simulate(d, None, segs), segs) for lab, d in drives.items()}
        out["open_loop"]["k_step"][key] = {**open_k, **_baselines(bench, segs)}
    segs = free_runs(bench.rec, bench.hold)
    out["closed_loop"]["free_run"] = {
        lab: bench.score(bench.simulate(d, loop, segs), segs) for lab, d in drives.items()
    }
    out["open_loop"].update(_open_loop_verdict(out["open_loop"]["k_step"], list(drives)))
    return out


def _open_loop_verdict(by_h: dict[str, dict[str, Score]], labels: list[str]) -> OpenLoop:
    """Open loop is informative when some model beats constant velocity at the shortest horizon."""
    first = by_h[min(by_h, key=float)]
    baseline = first.get("constant_velocity")
    cv = baseline["nrmse"] if baseline is not None else None
    best = min((v for v in (first[lab]["nrmse"] for lab in labels) if v is not None), default=None)
    if cv is None or best is None:
        return {"informative": False, "why": "no finite open-loop simulation"}
    if best < cv:
        return {"informative": True, "why": "a model beats constant velocity at the shortest horizon"}
    return {
        "informative": False,
        "why": (
            f"no model beats constant velocity (NRMSE {cv:.3g}) even at the shortest horizon: the remaining torque "
            "error, divided by small link inertias, is more acceleration error than the logged motion has; "
            "open-loop replay of this log tests the amplification, not the model (the closed loop is the criterion)"
        ),
    }


def verdict(fw: Forward, label: str, reference: str = "nominal") -> Verdict:
    """Does `label` simulate the held-out data at least as well as `reference` in closed loop (every horizon
    and the free run)? The criterion `bench run ... calibration=` checks."""
    if "skipped" in fw:
        return {"simulates_better": None, "why": fw["skipped"]}
    rows = [(f"k-step {h} s", v) for h, v in fw["closed_loop"]["k_step"].items()]
    rows.append(("free run", fw["closed_loop"]["free_run"]))
    rose = []
    for name, v in rows:
        a, b = v[reference]["nrmse"], v[label]["nrmse"]
        if b is None or (a is not None and b > a * 1.001):
            rose.append(f"{name}: {a if a is None else round(a, 5)} -> {b if b is None else round(b, 5)}")
    free = fw["closed_loop"]["free_run"]
    return {
        "criterion": "closed-loop position NRMSE on the held-out data, every horizon and the free run",
        "declared": free[reference]["nrmse"],
        "calibrated": free[label]["nrmse"],
        "simulates_better": not rose,
        "rose": rose,
    }
