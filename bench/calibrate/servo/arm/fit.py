"""The arm's servos fitted to its log: a linear start by inverse dynamics, then refinement on simulated windows.

Linear start (per joint, `linear_start`): MuJoCo's inverse dynamics (`mj_inverse`, the arm's mass matrix,
gravity and coupling, with the servos' own terms zeroed) gives the torque each joint's servo delivered at
every frame; the law's unsaturated form is linear in the parameters,
    tau = K (goal - q) - D dq - C sign(dq) - A ddq,
solved by bounded least squares over the frames where the declared servo is not saturated.

Refinement (`refine`): windows of `horizon` seconds start from the logged positions (velocity by central
difference) and are simulated in `mujoco.rollout` under the logged goals (held over each frame's physics
steps, as the suite steps them); the position error over every frame of every window is minimised by a
Levenberg-Marquardt iteration whose Jacobian perturbs each parameter kind on every joint at once (one rollout
per kind): joint j's trajectory answers to joint j's parameter, and the coupling through the mass matrix, which
the simulation keeps, is left out of the Jacobian only. Intervals: the Gauss-Newton covariance of each
joint's block, scaled by the window length (the errors along one window are not independent).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import rollout
from scipy.optimize import lsq_linear

from bench.calibrate.servo.arm.data import ArmLog
from bench.calibrate.servo.arm.model import KINDS, Arm, ArmServos

# bounds of each kind as multiples of the declared value (Coulomb from zero: a servo may have none)
BOUNDS = {"stiffness": (0.05, 20.0), "damping": (0.0, 20.0), "coulomb": (0.0, 40.0), "armature": (0.0, 20.0)}
STEP = 0.03  # finite-difference step, relative to the declared value
ITERATIONS = 25
MOVING = 0.05  # rad/s: slower frames carry no sign of the Coulomb friction (left out of the linear start)


@dataclass(frozen=True)
class Windows:
    """Simulated windows: their initial states, the goals of every physics step, and the logged positions."""

    state: np.ndarray  # (W, nstate) mjSTATE_FULLPHYSICS
    ctrl: np.ndarray  # (W, frames * substeps, nu)
    target: np.ndarray  # (W, frames, J) rad
    frames: int


def velocity(q: np.ndarray, fps: float) -> np.ndarray:
    """Central differences (one-sided at the ends), rad/s."""
    return np.gradient(q, 1.0 / fps, axis=0)


def windows(arm: Arm, log: ArmLog, episodes: list[int], frames: int, stride: int | None = None) -> Windows:
    """Windows of `frames` frames from frame 1 of each listed episode (every `stride` frames; whole episodes
    from frame 1 when `frames` is 0)."""
    m = arm.model
    data = mujoco.MjData(m)
    spec = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
    states, ctrls, targets = [], [], []
    for e in episodes:
        q, g = log.q[e], log.goal[e]
        dq = velocity(q, log.fps)
        n = frames or len(q) - 2
        for k in range(1, len(q) - n, stride or n):
            mujoco.mj_resetData(m, data)
            data.qpos[arm.qadr] = q[k]
            data.qvel[arm.dadr] = dq[k]
            state = np.empty(mujoco.mj_stateSize(m, spec))
            mujoco.mj_getState(m, data, state, spec)
            u = np.zeros((n * arm.substeps, m.nu))
            u[:, arm.actuators] = np.repeat(g[k : k + n], arm.substeps, axis=0)
            states.append(state)
            ctrls.append(u)
            targets.append(q[k + 1 : k + 1 + n])
    return Windows(np.array(states), np.array(ctrls), np.array(targets), frames)


def simulate(arm: Arm, servos: list[ArmServos], win: Windows) -> np.ndarray:
    """Positions (len(servos), W, frames, J) of every window under each parameter set, one `mujoco.rollout`."""
    models = [arm.with_servos(s) for s in servos]
    n_win, n_steps = win.ctrl.shape[:2]
    batch = [m for m in models for _ in range(n_win)]
    data = mujoco.MjData(arm.model)
    state, _ = rollout.rollout(
        batch,
        data,
        np.tile(win.state, (len(models), 1)),
        np.tile(win.ctrl, (len(models), 1, 1)),
        control_spec=int(mujoco.mjtState.mjSTATE_CTRL),
    )
    qpos0 = mujoco.mj_stateSize(arm.model, int(mujoco.mjtState.mjSTATE_TIME))
    at = np.arange(arm.substeps - 1, n_steps, arm.substeps)  # the last physics step of each frame
    q = state[:, at][:, :, qpos0 + arm.qadr]
    return q.reshape(len(models), n_win, len(at), len(arm.joints))


def linear_start(
    arm: Arm, log: ArmLog, episodes: list[int], declared: ArmServos, free: tuple[str, ...] = KINDS
) -> ArmServos:
    """Per joint, bounded least squares of the law's unsaturated form on inverse-dynamics torques (the kinds not
    `free` held at their declared values)."""
    m = arm.with_servos(declared.with_vector(np.concatenate([declared.stiffness, np.zeros(3 * len(arm.joints))])))
    data = mujoco.MjData(m)
    rows: list[list[np.ndarray]] = [[] for _ in arm.joints]
    taus: list[list[float]] = [[] for _ in arm.joints]
    for e in episodes:
        q, g = log.q[e], log.goal[e]
        dq, ddq = velocity(q, log.fps), np.gradient(velocity(q, log.fps), 1.0 / log.fps, axis=0)
        for k in range(1, len(q) - 1):
            mujoco.mj_resetData(m, data)
            data.qpos[arm.qadr], data.qvel[arm.dadr], data.qacc[arm.dadr] = q[k], dq[k], ddq[k]
            mujoco.mj_inverse(m, data)
            tau = data.qfrc_inverse[arm.dadr]
            err = 0.5 * (g[k - 1] + g[k]) - q[k]  # the goal over the differences' span
            for j in range(len(arm.joints)):
                if abs(declared.stiffness[j] * err[j]) > 0.9 * declared.max_torque[j] or abs(dq[k, j]) < MOVING:
                    continue
                rows[j].append(np.array([err[j], -dq[k, j], -np.sign(dq[k, j]), -ddq[k, j]]))
                taus[j].append(float(tau[j]))
    x = declared.vector().reshape(len(KINDS), -1).copy()
    on = np.array([k in free for k in KINDS])
    for j in range(len(arm.joints)):
        if len(rows[j]) < 4 * len(KINDS):
            continue  # too few moving, unsaturated frames: the declared servo stays the start
        nominal = x[:, j].copy()
        scale = np.where(nominal > 0, nominal, 1.0)
        a = np.array(rows[j])
        tau = np.array(taus[j]) - a[:, ~on] @ nominal[~on]  # the held terms moved to the torque's side
        lo = np.array([BOUNDS[k][0] for k in KINDS])[on]
        hi = np.array([BOUNDS[k][1] for k in KINDS])[on]
        sol = lsq_linear(a[:, on] * scale[on], tau, bounds=(lo, hi))
        x[on, j] = sol.x * scale[on]
    return declared.with_vector(x.ravel())


@dataclass(frozen=True)
class Fit:
    """The refined servos, their covariance per joint (KINDS x KINDS, natural units) and the fit's history."""

    servos: ArmServos
    covariance: np.ndarray  # (J, 4, 4)
    cost: list[float]  # mean squared window error (rad²) per accepted iteration
    rollouts: int


def refine(
    arm: Arm,
    start: ArmServos,
    declared: ArmServos,
    win: Windows,
    free: tuple[str, ...] = KINDS,
    log_fn: Callable[[str], None] = lambda msg: None,
) -> Fit:
    """Levenberg-Marquardt on the windows' position error over the `free` kinds (module docstring)."""
    n_j, n_k = len(arm.joints), len(KINDS)
    ks = [KINDS.index(k) for k in KINDS if k in free]
    scale = declared.vector().reshape(n_k, n_j)
    scale = np.where(scale > 0, scale, 1.0)
    lo = np.array([BOUNDS[k][0] for k in KINDS])[:, None] * np.ones(n_j)
    hi = np.array([BOUNDS[k][1] for k in KINDS])[:, None] * np.ones(n_j)
    u = np.clip(start.vector().reshape(n_k, n_j) / scale, lo, hi)

    def servos_of(v: np.ndarray) -> ArmServos:
        return declared.with_vector((v * scale).ravel())

    def residual(batch: list[np.ndarray]) -> np.ndarray:
        return simulate(arm, [servos_of(v) for v in batch], win) - win.target[None]

    r0 = residual([u])[0]
    rollouts = 1
    cost = [float(np.mean(r0**2))]
    lam = 1e-2
    blocks = np.zeros((n_j, r0[..., 0].size, len(ks)))
    for it in range(ITERATIONS):
        h = STEP * np.maximum(u, 0.1)
        probes = []
        for k in ks:
            v = u.copy()
            v[k] = np.minimum(u[k] + h[k], hi[k])
            probes.append(v)
        rs = residual(probes)
        rollouts += len(ks)
        for i, k in enumerate(ks):
            step = probes[i][k] - u[k]
            blocks[:, :, i] = ((rs[i] - r0).reshape(-1, n_j) / np.where(step > 0, step, 1.0)).T
        accepted = False
        while lam < 1e8:
            v = u.copy()
            for j in range(n_j):
                jj, rj = blocks[j], r0[..., j].ravel()
                a = jj.T @ jj
                delta = -np.linalg.solve(a + lam * np.diag(np.diag(a) + 1e-12), jj.T @ rj)
                v[ks, j] = np.clip(u[ks, j] + delta, lo[ks, j], hi[ks, j])
            r1 = residual([v])[0]
            rollouts += 1
            if np.mean(r1**2) < cost[-1]:
                u, r0, lam, accepted = v, r1, max(lam / 4.0, 1e-6), True
                cost.append(float(np.mean(r1**2)))
                break
            lam *= 5.0
        log_fn(f"  refinement {it + 1}: window RMSE {np.sqrt(cost[-1]):.4g} rad ({rollouts} rollouts)")
        if not accepted or cost[-2] - cost[-1] < 1e-4 * cost[-2]:
            break
    cov = np.zeros((n_j, n_k, n_k))
    for j in range(n_j):
        jj, rj = blocks[j], r0[..., j].ravel()
        dof = max(rj.size - n_k, 1)
        s2 = float(rj @ rj) / dof * win.frames  # the frames of a window are not independent errors
        cov[j][np.ix_(ks, ks)] = np.linalg.pinv(jj.T @ jj) * s2 * np.outer(scale[ks, j], scale[ks, j])
    return Fit(servos_of(u), cov, cost, rollouts)
