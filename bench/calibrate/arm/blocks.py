"""The regression of a real arm's calibration: regressor blocks of the declared model and of candidate effects.

`regression` builds, from processed samples (logged, or simulated by the forward refinement), the
columns the torque signal is fitted on (`bench.calibrate.arm.idim`): each link's ten standard
parameters (the link and what is fixed to it), each joint's friction, offset and rotor inertia, and
the candidate effects (a payload at the flange or tool frame, a drive gain, Stribeck and asymmetric
friction, a joint spring); `values_of` turns a fit back into what `realise` writes into the model.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from bench.calibrate.arm.dynamics import Dynamics
from bench.calibrate.arm.idim import FRICTION_V, Block, Fit, fit, predict, prior_scale
from bench.calibrate.arm.inertial import STD_NAMES
from bench.calibrate.arm.model import ArmModel, Values, group_std
from bench.calibrate.arm.spec import ArmSpec
from bench.calibrate.fit import information

STRIBECK_VS = (0.01, 0.03, 0.1, 0.3)  # rad/s: Stribeck velocities tried (the best on training data is kept)


class Samples(Protocol):
    """Processed samples the regression is built on (an `ArmLog`, or simulated ones): (N, n) arrays."""

    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray


@dataclass
class Candidate:
    """One effect on one target, as regressor blocks."""

    name: str
    target: str
    blocks: list[Block]
    amplitude: list[str]  # labels whose interval must exclude zero
    payload: bool = False
    note: dict[str, object] = field(default_factory=dict)


def joint_cols(n_rows: int, n: int, j: int, col: np.ndarray) -> np.ndarray:
    out = np.zeros((n_rows, n, 1))
    out[:, j, 0] = col
    return out


def declared_blocks(spec: ArmSpec, am: ArmModel, log: Samples, body_cols: dict[int, np.ndarray]) -> list[Block]:
    n_rows, n = log.q.shape
    m = am.model
    blocks: list[Block] = []
    wanted = None if spec.inertia is None else set(spec.inertia)
    for name, b in zip(am.links, am.link_ids):
        if wanted is not None and name not in wanted and not any(name.endswith(w) for w in wanted):
            continue
        cols = body_cols[int(b)]
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
        cols = np.concatenate([joint_cols(n_rows, n, j, c) for _, c, _, _ in terms], axis=-1)
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


def payload_block(
    am: ArmModel, body_cols: dict[int, np.ndarray], region: tuple[tuple[float, float, float], float]
) -> tuple[Block, np.ndarray]:
    p = body_cols[am.payload_body]
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
        region=(np.asarray(region[0], dtype=np.float64), float(region[1])),
    )
    return blk, p[..., 4:]


def effect_block(name: str, label: str, cols: np.ndarray, lo: float, hi: float = np.inf) -> Block:
    """A searched effect of one parameter in [lo, hi], absent in the declared model (prior 0, no pull toward it)."""
    return Block(name, [label], cols, np.array([lo]), np.array([hi]), np.zeros(1), np.full(1, np.inf), kind="effect")


def candidates(
    spec: ArmSpec,
    am: ArmModel,
    log: Samples,
    body_cols: dict[int, np.ndarray],
    base: np.ndarray,
    signal: np.ndarray,
    train: np.ndarray,
) -> tuple[list[Candidate], list[str], np.ndarray | None]:
    n_rows, n = log.q.shape
    out: list[Candidate] = []
    searched: list[str] = []
    payload_inertia = None
    if "payload" in spec.effects:
        blk, payload_inertia = payload_block(am, body_cols, spec.payload_region)
        out.append(Candidate("payload", am.payload_name, [blk], [blk.labels[0]], payload=True))
        searched.append(f"payload at {am.payload_name} (mass and centre of mass)")
    for j, jn in enumerate(am.joints):
        dq, sgn = log.dq[:, j], np.tanh(log.dq[:, j] / FRICTION_V)
        if "actuator_gain" in spec.effects and spec.torque != "measured":
            blk = effect_block(f"gain:{jn}", f"{jn}.gain_error", joint_cols(n_rows, n, j, -signal[:, j]), -0.9, 5.0)
            out.append(Candidate("actuator_gain", jn, [blk], blk.labels))
        if "stribeck_friction" in spec.effects:
            best = None
            for vs in STRIBECK_VS:
                col = joint_cols(n_rows, n, j, sgn * np.exp(-((dq / vs) ** 2)))
                c = col[train, j, 0]
                r = signal[train, j] - base[train, j]
                score = float(abs(c @ r) / max(np.linalg.norm(c), 1e-12))
                if best is None or score > best[0]:
                    best = (score, vs, col)
            assert best is not None
            blk = effect_block(f"stribeck:{jn}", f"{jn}.stribeck_excess", best[2], 0.0)
            out.append(Candidate("stribeck_friction", jn, [blk], blk.labels, note={"stribeck_velocity": best[1]}))
        if "asymmetric_friction" in spec.effects:
            blk = effect_block(f"asym:{jn}", f"{jn}.asymmetry", joint_cols(n_rows, n, j, np.abs(sgn)), -np.inf)
            out.append(Candidate("asymmetric_friction", jn, [blk], blk.labels))
        if "joint_spring" in spec.effects:
            q0 = float(am.model.qpos_spring[am.qadr[j]])
            blk = effect_block(f"spring:{jn}", f"{jn}.stiffness", joint_cols(n_rows, n, j, -(log.q[:, j] - q0)), 0.0)
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


def values_of(am: ArmModel, f: Fit) -> Values:
    """What `realise` writes, from a fit's parameter vector."""
    out: Values = {"joints": {}, "links": {}}
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


def nominal_torque(am: ArmModel, data: Samples, base: np.ndarray) -> np.ndarray:
    """The declared model's torque as given: rigid body plus its own rotor inertia, damping and friction loss."""
    m, d = am.model, am.dadr
    return (
        base
        + m.dof_armature[d] * data.ddq
        + m.dof_damping[d] * data.dq
        + m.dof_frictionloss[d] * np.tanh(data.dq / FRICTION_V)
    )


@dataclass
class Regression:
    """Everything the fits of one set of samples need."""

    declared: list[Block]
    candidates: list[Candidate]
    searched: list[str]
    base: np.ndarray  # (N, n) the declared model's rigid-body torque
    base_free: np.ndarray  # ... less the declared links' own torque (link blocks hold absolute parameters)
    payload_inertia: np.ndarray | None  # (N, n, 6) torque per unit of the payload's rotational inertia

    def blocks_of(self, added: Sequence[Mapping[str, object]]) -> list[Block]:
        """The declared blocks and those of the effects `added` (by name and target), in the fit's order."""
        out = list(self.declared)
        for a in added:
            c = next(c for c in self.candidates if c.name == a["name"] and c.target == a["target"])
            out += c.blocks
        return out


def regression(
    spec: ArmSpec, am: ArmModel, s: Samples, dyn: Dynamics, signal: np.ndarray, train: np.ndarray
) -> Regression:
    """Regressor blocks and fixed torques of `s` (the candidates' Stribeck velocity chosen on `train` rows)."""
    base = dyn.torques(s.q, s.dq, s.ddq)
    body_cols = dyn.body_columns([*am.link_ids.tolist(), am.payload_body], s.q, s.dq, s.ddq)
    declared = declared_blocks(spec, am, s, body_cols)
    cands, searched, payload_inertia = candidates(spec, am, s, body_cols, base, signal, train)
    links0 = [b for b in declared if b.pseudo]
    base_free = base - sum((np.einsum("njk,k->nj", b.cols, b.prior) for b in links0), np.zeros_like(base))
    return Regression(declared, cands, searched, base, base_free, payload_inertia)


def torque_error(measured: np.ndarray, predicted: np.ndarray, spread: np.ndarray) -> tuple[float, np.ndarray]:
    """(mean over joints of RMSE / spread, per-joint RMSE) of predicted against measured torque rows: the one
    score of every model on held-out torque (ours, the declared one, a repeat baseline, a reference's table)."""
    rmse = np.sqrt(np.mean((measured - predicted) ** 2, axis=0))
    return float(np.mean(rmse / spread)), rmse


class Fitter:
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
        self, blocks: list[Block], x0: np.ndarray | None = None, hold_links: bool = False, fences: bool = True
    ) -> tuple[Fit, np.ndarray]:
        w = self.weights
        f = fit(blocks, self.signal, self.base, self.train, weights=w, x0=x0, hold_links=hold_links, fences=fences)
        fixed = self.base
        if any(b.name == "payload" for b in blocks):
            for _ in range(4):  # the payload's own inertia: a fixed point in its mass and centre
                fixed = self.fixed(f, blocks)
                f = fit(blocks, self.signal, fixed, self.train, weights=w, x0=f.x, hold_links=hold_links, fences=fences)
        return f, fixed

    def error(self, f: Fit, fixed: np.ndarray) -> tuple[float, np.ndarray]:
        """Held-out normalised error (mean over joints of RMSE / spread) and per-joint RMSE."""
        return torque_error(self.signal[self.hold], predict(f.blocks, f.x, fixed)[self.hold], self.spread)

    def ic(self, f: Fit, n_eff: float) -> float:
        return information(f.ssr * n_eff / max(f.n, 1), len(f.x), n_eff, self.criterion)
