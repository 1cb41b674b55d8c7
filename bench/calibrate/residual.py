"""A learned residual: a small model of what the calibrated physics still gets wrong, kept apart from it.

After the loop, the calibrated model is stepped one frame from every logged training state; the
velocity it misses, divided by the frame period and mapped through the mass matrix at that state,
is the generalised force the physics lacks there. A ridge regression on additive random Fourier
features of the logged state and command (`Residual`: a sum of smooth functions of each joint's
position, velocity and command, the shape most unmodelled joint forces have: cogging and cable
forces of a position, friction of a velocity, drive non-linearity of a command) learns that
force; added to the simulation as a
state-dependent force (`bench.replay.simulate.Variant.force`), it is evaluated on the held-out
data like the physical model, with and without it.

It is never part of the physics: the effects found, their parameters and the `final` errors are
those of the physical model alone; the residual has its own section in calibration.json
(`learned_residual`) and report.md. Every random draw (the features) comes from the calibration
seed; the regularisation is chosen by cross-validation over contiguous blocks of training frames.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, TypedDict

import mujoco
import numpy as np

from bench.core.io import finite_or_none as finite
from bench.replay.metrics import horizon_errors
from bench.replay.simulate import Simulator, StateForce, Variant, horizons

FEATURES = 32  # random Fourier features per input (plus the inputs themselves and a constant)
FREQUENCY = 2.0  # spread of their frequencies, in radians per standardised input unit
LAMBDAS = tuple(10.0**k for k in range(-4, 4))  # ridge strengths tried (relative to the mean feature energy)
FOLDS = 5


@dataclass(frozen=True)
class Residual:
    """Generalised force f(q, qd, u) = features(q, qd, u) @ weights, on the logged dofs."""

    mean: np.ndarray  # (d,) input standardisation
    std: np.ndarray
    freq: np.ndarray  # (d, FEATURES): each input's own frequencies
    phase: np.ndarray  # (d, FEATURES)
    weights: np.ndarray  # (d * FEATURES + d + 1, ndof)
    lam: float

    def features(self, x: np.ndarray) -> np.ndarray:
        z = (x - self.mean) / self.std
        rff = np.sqrt(2.0 / self.freq.shape[1]) * np.cos(z[:, :, None] * self.freq + self.phase)
        return np.concatenate([rff.reshape(len(z), -1), z, np.ones((len(z), 1))], axis=1)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.features(x) @ self.weights


def _inputs(qpos: np.ndarray, qvel: np.ndarray, ctrl: np.ndarray) -> np.ndarray:
    return np.concatenate([qpos, qvel, ctrl], axis=1)


def _ridge(phi: np.ndarray, y: np.ndarray, lam: float) -> np.ndarray:
    scale = float(np.mean(np.sum(phi * phi, axis=1)))
    a = phi.T @ phi + lam * scale * np.eye(phi.shape[1])
    return np.linalg.solve(a, phi.T @ y)


# how the residual's strength was chosen: the ridge penalty, and R^2 on the training data and in blocked CV
Stats = TypedDict("Stats", {"lambda": float, "train_r2": np.ndarray, "cv_r2": float})


def fit_residual(x: np.ndarray, y: np.ndarray, seed: int) -> tuple[Residual, Stats]:
    """Ridge on random Fourier features of inputs x (n, d) to targets y (n, ndof); strength by blocked CV."""
    rng = np.random.default_rng([seed, 19])
    d = x.shape[1]
    mean, std = x.mean(axis=0), np.maximum(x.std(axis=0), 1e-9)
    freq = rng.normal(0.0, FREQUENCY, (d, FEATURES))
    phase = rng.uniform(0.0, 2.0 * np.pi, (d, FEATURES))
    model = Residual(mean, std, freq, phase, np.zeros((d * FEATURES + d + 1, y.shape[1])), 0.0)
    phi = model.features(x)
    folds = np.array_split(np.arange(len(x)), FOLDS)  # contiguous blocks: neighbouring frames are not independent
    cv = []
    for lam in LAMBDAS:
        sse = 0.0
        for f in folds:
            keep = np.ones(len(x), bool)
            keep[f] = False
            w = _ridge(phi[keep], y[keep], lam)
            sse += float(np.sum((phi[f] @ w - y[f]) ** 2))
        cv.append(sse)
    lam = LAMBDAS[int(np.argmin(cv))]
    weights = _ridge(phi, y, lam)
    fitted = phi @ weights
    r2 = 1.0 - np.sum((y - fitted) ** 2, axis=0) / np.maximum(np.sum((y - y.mean(axis=0)) ** 2, axis=0), 1e-300)
    cv_r2 = 1.0 - min(cv) / max(float(np.sum((y - y.mean(axis=0)) ** 2)), 1e-300)
    return replace(model, weights=weights, lam=lam), {"lambda": lam, "train_r2": r2, "cv_r2": cv_r2}


def _targets(sim: Simulator, v: Variant, nq: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(start frames, inputs, generalised-force residual) over one-frame steps from every training state."""
    rec = sim.rec
    segs = horizons(rec, rec.train, 1)
    start = segs.start
    pred = sim.run([v], segs)[0][:, 0]  # (n, nq + nv) after one frame
    accel = (rec.qvel[start + 1] - pred[:, nq:]) * rec.fps
    m = v.model
    dof = np.arange(m.nv) if v.coords is None else v.coords.dof_adr
    d = mujoco.MjData(m)
    force = np.empty_like(accel)
    full = np.zeros((m.nv, m.nv))
    qpos = (
        rec.qpos[start]
        if v.coords is None
        else v.coords.init(start, rec.qpos[start], rec.qvel[start], rec.ctrl[start])[0]
    )
    for i, q in enumerate(qpos):
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, full, d.qM)
        force[i] = full[np.ix_(dof, dof)] @ accel[i]
    ctrl = v.ctrl[start * sim.substeps]
    return start, _inputs(rec.qpos[start], rec.qvel[start], ctrl), force


def _hook(model: Residual, v: Variant, nq: int) -> StateForce:
    """The residual as a force hook (added to the variant's own force, e.g. Stribeck friction)."""
    qadr = np.arange(nq) if v.coords is None else v.coords.qpos_adr
    dadr = np.arange(nq) if v.coords is None else v.coords.dof_adr
    own = v.force

    def force(qpos: np.ndarray, qvel: np.ndarray, ctrl: np.ndarray) -> np.ndarray:
        out = np.zeros_like(qvel) if own is None else own(qpos, qvel, ctrl).copy()
        out[:, dadr] += model(_inputs(qpos[:, qadr], qvel[:, dadr], ctrl))
        return out

    return force


def _summary(errors: dict) -> dict[str, Any]:
    return {
        f"{label}_{m}": finite(float(getattr(e, m).mean())) for label, e in errors.items() for m in ("nrmse", "rmse")
    }


def learn(sim: Simulator, v: Variant, k: int, seed: int) -> dict[str, Any]:
    """Fit the residual on the training logs; held-out errors of the physics with and without it."""
    rec = sim.rec
    nq = rec.qpos.shape[1]
    _, x, y = _targets(sim, v, nq)
    model, stats = fit_residual(x, y, seed)
    physics = horizon_errors(sim, v, rec, rec.holdout, k)
    hybrid = horizon_errors(sim, replace(v, force=_hook(model, v, nq)), rec, rec.holdout, k)
    without, with_ = _summary(physics), _summary(hybrid)
    cut = {
        label: (
            None
            if not without[f"{label}_nrmse"] or with_[f"{label}_nrmse"] is None
            else 1.0 - with_[f"{label}_nrmse"] / without[f"{label}_nrmse"]
        )
        for label in physics
    }
    k_cut = cut["k_step"]
    verdict = (
        "cannot be evaluated"
        if k_cut is None
        else f"lowers the held-out k-step error by {100 * k_cut:.0f}%: the effect library leaves this much unexplained"
        if k_cut > 0.05
        else f"does not help on held-out data (k-step error {100 * -k_cut:+.0f}%): nothing the library misses is "
        "learnable from these logs"
    )
    return {
        "model": f"ridge regression on {FEATURES} random Fourier features of each input (frequencies drawn from "
        f"N(0, {FREQUENCY:g}²) per standardised unit; an additive model) of the logged qpos, qvel and the "
        "applied command, plus those inputs and a constant",
        "target": "generalised force the calibrated physics misses over one frame from each training state "
        "(M(q) x missed velocity / frame period)",
        "samples": int(len(x)),
        "seed": seed,
        "lambda": stats["lambda"],
        "cv_r2": finite(stats["cv_r2"]),
        "train_r2": [finite(v) for v in stats["train_r2"]],
        "heldout": {"physics": without, "physics_plus_residual": with_, "nrmse_cut": cut, "k": k},
        "verdict": verdict,
        "note": "not part of the physical model: effects_added and errors.final are the physics alone",
    }
