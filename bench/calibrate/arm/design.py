"""What to record: a periodic excitation that makes an arm spec's parameters identifiable (`bench calibrate design`).

Each joint follows a finite Fourier series (Swevers et al. 1997; Gaz et al. 2019), w = 2 pi / period:
q_j(t) = q0_j + sum_l a_jl / (w l) sin(w l t) - b_jl / (w l) cos(w l t), with analytic dq and ddq;
sum_l a_jl = 0 and sum_l l b_jl = 0 make it start and end each period at rest. It stays within each
joint's range less `margin` of its width at either end, its velocity limit and its torque limit (the
declared rigid-body torque and friction, and the rotor inertia where the spec's signal holds it) on a
grid of GRID_PER_HARMONIC points per cycle of the highest harmonic, and again on the 1 kHz trajectory.

The objective is the condition number of the regressor the calibration fits (the declared blocks and
the payload of `bench.calibrate.arm.blocks`), each joint's rows divided by NOISE_SHARE of its torque
limit, each column scaled to its parameter's plausible size (`identifiability.plausible_sizes`, fixed
once), over the directions a motion identifies at all: a rigid chain has combinations no motion
separates, so the structural rank r is found once on random rich trajectories and the condition is
s_1 / s_r. The search draws STARTS random trajectories (each joint at the largest amplitude its range
and velocity allow, all shrunk together until the torque fits), then runs a (1+1) evolution strategy
from the best for `evaluations` tries; every draw comes from `numpy.random.default_rng(seed)`. What
each excitation identifies is `identifiability.analyse` with that noise, over the log's length.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TypedDict

import mujoco
import numpy as np

from bench import __version__
from bench.calibrate.arm.blocks import declared_blocks, payload_block
from bench.calibrate.arm.data import load_arm_log
from bench.calibrate.arm.dynamics import Dynamics
from bench.calibrate.arm.identifiability import Identifiability, analyse, plausible_sizes
from bench.calibrate.arm.idim import FRICTION_V, Block, design
from bench.calibrate.arm.model import ArmModel, check_positions
from bench.calibrate.arm.spec import ArmSpec, is_arm_spec, parse_arm_spec
from bench.core.errors import ConfigError, SpecError
from bench.core.io import finite_or_none, write_atomic
from bench.core.provenance import git_sha, package_versions, portable
from bench.core.threads import one_blas_thread
from bench.replay.spec import read_spec_file

GRID_MIN, GRID_PER_HARMONIC = 100, 20  # optimisation grid: points per period, per cycle of the highest harmonic
STARTS = 16  # random starting trajectories
EVALUATIONS = 300  # trajectories the evolution strategy tries
SAFETY = 0.97  # share of each limit the optimisation grid may use (the 1 kHz check gets the rest)
RANK_TOL = 1e-8  # singular values below this share of the largest: combinations no motion identifies
NOISE_SHARE = 0.01  # assumed torque noise per sample, as a share of each joint's torque limit
CSV_RATE = 1000.0  # Hz of trajectory.csv
REST_POSES = 64  # poses tried for the at-rest torque check
SCHEMA = "bench.excitation/1"
RANK = {"not identifiable": 0, "in combination": 1, "identified": 2}


@dataclass
class Samples:
    """Joint positions, velocities and accelerations, (N, n) each."""

    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray


@dataclass(frozen=True)
class Fourier:
    """A finite Fourier series per joint: q0 (n,) and a, b (n, L) in rad/s."""

    period: float
    q0: np.ndarray
    a: np.ndarray
    b: np.ndarray

    def at(self, t: np.ndarray) -> Samples:
        wl = 2 * np.pi / self.period * np.arange(1, self.a.shape[1] + 1)
        s, c = np.sin(np.outer(t, wl)), np.cos(np.outer(t, wl))
        q = self.q0 + s @ (self.a / wl).T - c @ (self.b / wl).T
        return Samples(q, c @ self.a.T + s @ self.b.T, -s @ (self.a * wl).T + c @ (self.b * wl).T)

    def shrunk(self, k: float) -> Fourier:
        return Fourier(self.period, self.q0, self.a * k, self.b * k)


@dataclass(frozen=True)
class Limits:
    """Position range (the model's, and less the margin), velocity and torque limits, and their sources."""

    range: np.ndarray  # (n, 2)
    lo: np.ndarray
    hi: np.ndarray
    velocity: np.ndarray
    torque: np.ndarray
    margin: float
    source: dict[str, str]


def _model_torque(m: mujoco.MjModel, jid: int) -> float:
    """The largest torque the model lets a joint's actuators apply (inf when nothing bounds it)."""
    out = float(np.min(np.abs(m.jnt_actfrcrange[jid]))) if m.jnt_actfrclimited[jid] else np.inf
    total, seen = 0.0, False
    for a in np.flatnonzero((m.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT) & (m.actuator_trnid[:, 0] == jid)):
        force = float(np.min(np.abs(m.actuator_forcerange[a]))) if m.actuator_forcelimited[a] else np.inf
        if m.actuator_ctrllimited[a] and m.actuator_biastype[a] == 0:
            force = min(force, float(np.max(np.abs(m.actuator_ctrlrange[a])) * abs(m.actuator_gainprm[a, 0])))
        total, seen = total + force * abs(float(m.actuator_gear[a, 0])), True
    return min(out, total) if seen else out


def limits_of(am: ArmModel, margin: float, velocity: list[float] | None, torque: list[float] | None) -> Limits:
    """The limits a design meets: the model's where it has them, else the keys' (one line naming the key)."""
    m, n = am.model, len(am.joints)
    if not all(m.jnt_limited[am.jids] | (m.jnt_type[am.jids] == mujoco.mjtJoint.mjJNT_HINGE)):
        raise SpecError("spec field 'joints': a slide without a range in the model cannot be designed for")
    rng = np.where(m.jnt_limited[am.jids, None] > 0, m.jnt_range[am.jids], np.array([-np.pi, np.pi]))
    width = rng[:, 1] - rng[:, 0]
    lo, hi = rng[:, 0] + margin * width, rng[:, 1] - margin * width
    if np.any(hi - lo <= 1e-3):
        i = int(np.argmin(hi - lo))
        raise ConfigError(
            f"key 'margin': {margin:g} of the width at either end leaves joint {am.joints[i]}'s range "
            f"[{rng[i, 0]:.4g}, {rng[i, 1]:.4g}] empty; give a smaller margin"
        )
    given: dict[str, np.ndarray] = {}
    for key, value in (("velocity", velocity), ("torque", torque)):
        if value is not None and len(value) not in (1, n):
            raise ConfigError(
                f"key {key!r} lists {len(value)} limits; the spec names {n} joints ({', '.join(am.joints)}): "
                "give one per joint, in the spec's order, or one for all"
            )
        if value is not None:
            given[key] = np.broadcast_to(np.asarray(value, dtype=np.float64), (n,)).copy()
    if "velocity" not in given:
        raise ConfigError(
            "key 'velocity' is required: the model declares no joint velocity limits; give the manufacturer's "
            f"in rad/s, one per joint ({n}) or one for all, e.g. velocity=[2.0]"
        )
    source = {"velocity": "key velocity", "torque": "key torque"}
    tq = given.get("torque", np.array([_model_torque(m, int(j)) for j in am.jids]))
    if "torque" not in given:
        source["torque"] = "the model's actuators (forcerange, or ctrlrange x gain x gear)"
        if not np.all(np.isfinite(tq)):
            missing = [am.joints[i] for i in np.flatnonzero(~np.isfinite(tq))]
            raise ConfigError(
                f"key 'torque' is required: the model bounds no actuator of {', '.join(missing)} (no forcerange "
                f"or ctrlrange); give the limits in N·m, one per joint ({n}) or one for all"
            )
    return Limits(rng, lo, hi, given["velocity"], tq, margin, source)


class DesignProblem:
    """A spec's regressor and limits on a time grid: evaluates trajectories."""

    def __init__(self, spec: ArmSpec, am: ArmModel, lim: Limits, period: float, harmonics: int) -> None:
        self.spec, self.am, self.lim, self.period, self.harmonics = spec, am, lim, period, harmonics
        self.dyn = Dynamics(am.model, am.qadr, am.dadr, am.qpos0)
        self.bodies = sorted({*am.link_ids.tolist(), am.payload_body})
        points = max(GRID_MIN, GRID_PER_HARMONIC * harmonics)
        self.grid = np.arange(points) * period / points
        self.weights = 1.0 / (NOISE_SHARE * lim.torque)
        self.size = np.empty(0)  # plausible sizes, fixed by `reference`
        self.rank = self.evaluations = 0

    def torque(self, s: Samples) -> np.ndarray:
        """What the drives deliver: rigid body and friction (and the rotor where the signal holds it)."""
        m, d = self.am.model, self.am.dadr
        tau = self.dyn.torques(s.q, s.dq, s.ddq) + m.dof_damping[d] * s.dq
        tau += m.dof_frictionloss[d] * np.tanh(s.dq / FRICTION_V)
        return tau + (m.dof_armature[d] * s.ddq if self.spec.armature else 0.0)

    def blocks(self, s: Samples) -> list[Block]:
        """The blocks the calibration fits: declared ones and the payload (scales: the plausible sizes)."""
        cols = self.dyn.body_columns(self.bodies, s.q, s.dq, s.ddq)
        out = declared_blocks(self.spec, self.am, s, cols)
        if "payload" in self.spec.effects:
            out.append(payload_block(self.am, cols, self.spec.payload_region)[0])
        if self.size.size:
            off = np.cumsum([0] + [b.size for b in out])
            out = [dataclasses.replace(b, scale=self.size[o : o + b.size]) for b, o in zip(out, off)]
        return out

    def matrix(self, blocks: list[Block]) -> np.ndarray:
        a = design(blocks, np.arange(len(blocks[0].cols))) * self.weights[None, :, None]
        return a.reshape(-1, a.shape[-1]) * (self.size if self.size.size else 1.0)

    def condition(self, s: Samples | list[Block]) -> float:
        """s_1 / s_r of the weighted, column-scaled regressor (inf when it identifies fewer than r directions)."""
        sv = np.linalg.svd(self.matrix(s if isinstance(s, list) else self.blocks(s)), compute_uv=False)
        return float(sv[0] / sv[self.rank - 1]) if sv[self.rank - 1] > RANK_TOL * sv[0] else float("inf")

    def fit_limits(self, a: np.ndarray, b: np.ndarray, u: np.ndarray, amp: float) -> Fourier:
        """Coefficients made to start at rest, each joint scaled to its range and velocity limit, times `amp`."""
        ell = np.arange(1, a.shape[1] + 1)
        a, b = a - a.mean(axis=1, keepdims=True), b - np.outer(b @ ell / (ell @ ell), ell)
        q0 = (self.lim.lo + self.lim.hi) / 2 + u * (self.lim.hi - self.lim.lo) / 2
        unit = Fourier(self.period, q0, a, b).at(self.grid)
        up = (self.lim.hi - q0) / np.maximum((unit.q - q0).max(axis=0), 1e-12)
        down = (q0 - self.lim.lo) / np.maximum((q0 - unit.q).max(axis=0), 1e-12)
        fast = self.lim.velocity / np.maximum(np.abs(unit.dq).max(axis=0), 1e-12)
        k = np.minimum(np.minimum(up, down), fast) * SAFETY * amp
        return Fourier(self.period, q0, a * k[:, None], b * k[:, None])

    def ratio(self, fr: Fourier) -> float:
        """The largest share of a torque limit the trajectory needs on the grid (one trajectory tried)."""
        self.evaluations += 1
        return float((np.abs(self.torque(fr.at(self.grid))) / self.lim.torque).max())

    def reference(self, rng: np.random.Generator) -> None:
        """Plausible sizes and the structural rank, from three random rich trajectories (torque not checked)."""
        n, L = len(self.am.joints), self.harmonics
        draws = [(rng.normal(size=(n, L)), rng.normal(size=(n, L)), rng.uniform(-0.3, 0.3, n)) for _ in range(3)]
        parts = [self.fit_limits(a, b, u, 1.0).at(self.grid) for a, b, u in draws]
        s = Samples(*(np.concatenate([getattr(p, k) for p in parts]) for k in ("q", "dq", "ddq")))
        blocks = self.blocks(s)
        if not blocks:
            raise SpecError("spec fields 'inertia', 'friction' and 'effects' leave no parameter to identify")
        spread = np.maximum(self.torque(s).std(axis=0), 1e-3 * self.lim.torque)
        self.size = plausible_sizes(blocks, np.arange(len(s.q)), spread)
        sv = np.linalg.svd(self.matrix(blocks), compute_uv=False)
        self.rank = int(np.sum(sv > RANK_TOL * sv[0]))


def check_rest(p: DesignProblem, rng: np.random.Generator) -> None:
    """Refuse torque limits that gravity alone exceeds at every pose tried (the range's centre first)."""
    lim, n = p.lim, len(p.am.joints)
    poses = np.vstack([(lim.lo + lim.hi) / 2, lim.lo + rng.uniform(size=(REST_POSES - 1, n)) * (lim.hi - lim.lo)])
    need = np.abs(p.dyn.torques(poses, 0 * poses, 0 * poses)) / lim.torque
    best = int(np.argmin(need.max(axis=1)))
    if need[best].max() > 1.0:
        j = int(np.argmax(need[best]))
        raise ConfigError(
            f"key 'torque': joint {p.am.joints[j]}'s limit {lim.torque[j]:.4g} N·m (from {lim.source['torque']}) "
            f"is below what gravity alone needs at rest ({need[best, j] * lim.torque[j]:.4g} N·m at the best of "
            f"{REST_POSES} poses in the range, {need[0, j] * lim.torque[j]:.4g} at its centre): no trajectory meets it"
        )


def search(
    p: DesignProblem, rng: np.random.Generator, tries: int, log: Callable[[str], None]
) -> tuple[Fourier, Fourier]:
    """The first feasible random start, and the design: the best start improved by a (1+1) evolution strategy."""
    n, L = len(p.am.joints), p.harmonics
    ell, first, best, worst = np.arange(1, L + 1), None, None, np.inf
    for _ in range(STARTS):
        a, b, u, amp = rng.normal(size=(n, L)) / ell, rng.normal(size=(n, L)) / ell, rng.uniform(-0.3, 0.3, n), 1.0
        while (r := p.ratio(fr := p.fit_limits(a, b, u, amp))) > SAFETY and amp > 0.05:
            amp *= 0.8
        worst = min(worst, r)
        if r > SAFETY:
            continue
        c = p.condition(fr.at(p.grid))
        first = first or fr
        if best is None or c < best[0]:
            best = (c, a, b, u, amp, fr)
    if best is None or first is None:
        raise ConfigError(
            f"key 'torque': none of {STARTS} random trajectories meets the torque limits even at 5% of the "
            f"amplitude the range and velocity allow (the best needs {worst:.3g}x a limit); raise torque= or "
            "lower velocity="
        )
    c, a, b, u, amp, fr = best
    log(f"design: best of {STARTS} random starts: condition {c:.4g}; searching ({tries} tries)")
    step = 0.3
    for _ in range(tries):
        norm = np.sqrt(np.sum(a**2 + b**2, axis=1, keepdims=True) / (2 * L))  # each joint's own scale
        a2, b2 = a + step * norm * rng.normal(size=(n, L)), b + step * norm * rng.normal(size=(n, L))
        u2 = np.clip(u + step * rng.normal(0, 0.2, n), -0.6, 0.6)
        amp2 = float(min(1.0, amp * np.exp(step * rng.normal(0, 0.3)))) if amp < 1.0 else amp
        fr2 = p.fit_limits(a2, b2, u2, amp2)
        c2 = p.condition(fr2.at(p.grid)) if p.ratio(fr2) <= SAFETY else np.inf
        if c2 < c:  # the step grows on success and shrinks on failure
            c, a, b, u, amp, fr, step = c2, a2, b2, u2, amp2, fr2, min(1.0, step * 1.5)
        else:
            step = max(0.02, step * 0.92)
    return first, fr


def finalise(p: DesignProblem, fr: Fourier) -> tuple[Fourier, dict[str, object]]:
    """The design shrunk until it meets every limit on the 1 kHz grid; what it reaches there."""
    t = np.arange(int(round(p.period * CSV_RATE))) / CSV_RATE
    for _ in range(40):
        s = fr.at(t)
        tau, lim = np.abs(p.torque(s)), p.lim
        if np.all((s.q >= lim.lo) & (s.q <= lim.hi) & (np.abs(s.dq) <= lim.velocity) & (tau <= lim.torque)):
            span, top = np.c_[s.q.min(axis=0), s.q.max(axis=0)], lambda x: np.abs(x).max(axis=0).tolist()
            return fr, {
                "position": span.tolist(),
                "velocity": top(s.dq),
                "acceleration": top(s.ddq),
                "torque": top(tau),
            }
        fr = fr.shrunk(0.98)
    raise ConfigError("key 'torque': the design cannot be brought within the limits on the 1 kHz grid")


class Side(TypedDict):
    """An excitation as the design compares it: its name, condition number and what it identifies."""

    of: str
    condition: float
    ident: Identifiability


class Gain(TypedDict):
    block: str
    parameters: dict[str, dict[str, str]]  # label -> {before, after}: its identifiability status in each


@dataclass
class Design:
    """A designed excitation and how it compares with what came before (a log, or a random trajectory)."""

    fourier: Fourier
    limits: Limits
    reached: dict[str, object]  # on the 1 kHz grid: position span, largest |dq|, |ddq|, |torque| per joint
    before: Side
    after: Side
    parameters: int
    rank: int  # directions a motion identifies at all
    gained: list[Gain]  # per block: parameters the design identifies better than before
    warnings: list[str]
    evaluations: int
    wall: float


def identify(p: DesignProblem, blocks: list[Block], rate: float, duration: float) -> Identifiability:
    """`identifiability.analyse` of samples at `rate` as if recorded for `duration` s (NOISE_SHARE noise)."""
    rows = np.arange(len(blocks[0].cols))
    x = np.concatenate([b.prior for b in blocks])
    return analyse(blocks, x, rows, p.weights, len(rows) / (rate * duration), np.ones(len(p.am.joints)))


def gained(before: Identifiability, after: Identifiability, blocks: list[Block]) -> list[Gain]:
    """Per block, the parameters `after` identifies better than `before` (alone > in combination > not)."""
    out: list[Gain] = []
    for b in blocks:
        pair = {lab: (before.status[lab]["status"], after.status[lab]["status"]) for lab in b.labels}
        better = {lab: {"before": x, "after": y} for lab, (x, y) in pair.items() if RANK[y] > RANK[x]}
        if better:
            out.append({"block": b.name, "parameters": better})
    return out


def _phrase(entry: Gain) -> str:
    kind, _, who = entry["block"].partition(":")
    params = entry["parameters"]
    names = ", ".join(lab.rsplit(".", 1)[1] for lab in params)
    if kind == "payload":
        mass = next((v for lab, v in params.items() if lab.endswith(".mass")), None)
        if mass is not None and mass["before"] == "in combination":
            return "the payload's mass apart from its centre of mass"
        return f"the payload's {names} (mass, and mass x centre of mass)"
    return f"link {who} ({len(params)} of 10 inertial parameters)" if kind == "link" else f"{who}'s {names}"


def design_spec(spec_file: str, harmonics: int, period: float) -> ArmSpec:
    """The arm spec a design is for, refused with one line naming the field when it is not `method: idim` or when
    the harmonics reach half its filter's cut-off (the calibration's own filter would damp them)."""
    raw, spec_path = read_spec_file(Path(spec_file).expanduser())
    if not is_arm_spec(raw):
        got = raw.get("method") if isinstance(raw, dict) else None
        raise SpecError(
            f"spec field 'method': bench calibrate design needs an arm spec (method: idim); {spec_file!r} has "
            + (f"method: {got}" if got is not None else "no method (a forward spec)")
        )
    spec = parse_arm_spec(raw, spec_path.parent, spec_path)
    if harmonics / period >= spec.filter_hz / 2:
        raise ConfigError(
            f"key 'harmonics': {harmonics} harmonics of a {period:g} s period reach "
            f"{harmonics / period:g} Hz, not below {spec.filter_hz / 2:g} Hz (half the spec's filter_hz): "
            "the calibration's filter would damp them; give fewer harmonics or a longer period"
        )
    return spec


@one_blas_thread()
def run_design(
    spec: ArmSpec,
    am: ArmModel,
    lim: Limits,
    *,
    period: float,
    harmonics: int,
    seed: int,
    log_samples: tuple[Samples, float, str] | None = None,
    evaluations: int = EVALUATIONS,
    progress: Callable[[str], None] = lambda msg: None,
) -> Design:
    """The design of the module docstring; `log_samples` (samples, rate, name) is the log it is compared with.
    One thread, as a calibration (`bench.core.threads`)."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    p = DesignProblem(spec, am, lim, period, harmonics)
    check_rest(p, rng)
    p.reference(rng)
    k, structural = len(p.size), len(p.size) - p.rank
    progress(f"design: {k} parameters, {p.rank} directions a motion identifies (the rest: rigid-chain combinations)")
    first, fr = search(p, rng, evaluations, progress)
    fr, reached = finalise(p, fr)
    t = np.arange(int(round(period * spec.rate))) / spec.rate
    if log_samples is not None:
        s0, rate0, name = log_samples
        duration, b0, of = max(len(s0.q) / rate0, period), p.blocks(s0), f"log {name}"
    else:
        rate0, duration, b0, of = spec.rate, period, p.blocks(first.at(t)), "the first feasible random trajectory"
    b1 = p.blocks(fr.at(t))
    i0, i1 = identify(p, b0, rate0, duration), identify(p, b1, spec.rate, duration)
    found, warnings = gained(i0, i1, b1), []
    if log_samples is not None and (found or i0.unidentified > i1.unidentified):
        what = [_phrase(e) for e in found[:6]] + ([f"{len(found) - 6} more block(s)"] if len(found) > 6 else [])
        left = i1.unidentified - structural
        warnings.append(
            f"the log's excitation leaves {i0.unidentified - structural} direction(s) unidentified that a motion "
            f"can identify ({i0.unidentified} of {k}, {structural} by any motion): "
            f"{'; '.join(what) or 'combinations of parameters'}; the design identifies "
            + ("them" if left <= 0 else f"all but {left} of them")
        )
    before: Side = {"of": of, "condition": p.condition(b0), "ident": i0}
    after: Side = {"of": "the design", "condition": p.condition(b1), "ident": i1}
    return Design(fr, lim, reached, before, after, k, p.rank, found, warnings, p.evaluations, time.perf_counter() - t0)


def samples_of_log(
    spec: ArmSpec, am: ArmModel, episodes: list[dict[str, np.ndarray]], fps: float
) -> tuple[Samples, float]:
    """A log's samples as the calibration processes them (`load_arm_log`), and their rate."""
    data = load_arm_log(spec, episodes, fps, seed=0)
    check_positions(am, data.q, spec.signals["qpos"].column)
    return Samples(data.q, data.dq, data.ddq), data.rate


def _side(x: Side) -> dict[str, object]:
    i = x["ident"]
    return {
        "of": x["of"],
        "condition_number": finite_or_none(x["condition"]),  # null: unbounded (directions left unidentified)
        "identified_directions": len(i.labels) - i.unidentified,
        "parameters": {lab: st["status"] for lab, st in i.status.items()},
    }


def write_design(
    d: Design, out: Path, spec: ArmSpec, am: ArmModel, seed: int, inputs: Mapping[str, str | None]
) -> None:
    """OUT/design.json and OUT/trajectory.csv (t, q1..qn, dq1..dqn, ddq1..ddqn over one period at CSV_RATE)."""
    fr, lim, n = d.fourier, d.limits, len(am.joints)
    t = np.arange(int(round(fr.period * CSV_RATE))) / CSV_RATE
    s = fr.at(t)
    head = ["t"] + [f"{k}{j + 1}" for k in ("q", "dq", "ddq") for j in range(n)]
    rows = np.column_stack([t, s.q, s.dq, s.ddq])
    rows[np.abs(rows) < 1e-12] = 0.0  # the rest at t = 0 is exact
    np.savetxt(out / "trajectory.csv", rows, fmt="%.9g", delimiter=",", header=",".join(head), comments="")
    doc = {
        "schema": SCHEMA,
        "spec": spec.to_json(),
        "joints": am.joints,
        "trajectory": {
            "form": "q_j(t) = q0_j + sum_l a_jl/(w l) sin(w l t) - b_jl/(w l) cos(w l t), w = 2 pi / period_s",
            "period_s": fr.period,
            "harmonics": int(fr.a.shape[1]),
            "q0": fr.q0.tolist(),
            "a": fr.a.tolist(),
            "b": fr.b.tolist(),
            "start": s.q[0].tolist(),  # at rest: move there first; each period ends there, at rest
            "csv": {"file": "trajectory.csv", "rate_hz": CSV_RATE, "columns": head},
        },
        "limits": {
            "position": {"range": lim.range.tolist(), "margin": lim.margin, "used": np.c_[lim.lo, lim.hi].tolist()},
            "velocity": lim.velocity.tolist(),
            "torque": lim.torque.tolist(),
            "source": lim.source,
            "torque_model": "declared rigid body + friction" + (" + rotor inertia" if spec.armature else ""),
        },
        "reached": d.reached,
        "condition": {
            "definition": "s_1 / s_r, regressor rows / (noise_share x torque limit), columns x plausible size",
            "parameters": d.parameters,
            "structural_rank": d.rank,  # r: the directions a motion identifies at all
            "noise_share": NOISE_SHARE,
        },
        "before": _side(d.before),
        "after": _side(d.after),
        "gained": d.gained,
        "warnings": d.warnings,
        "search": {"seed": seed, "starts": STARTS, "evaluations": d.evaluations, "wall_seconds": d.wall},
        "provenance": {
            "bench": __version__,
            "git_sha": git_sha(),
            "packages": package_versions(),
            "inputs": {k: portable(v) for k, v in inputs.items() if v is not None},
        },
    }
    write_atomic(out / "design.json", doc)
