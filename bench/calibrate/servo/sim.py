"""Batched simulation of a servo driving its load: many windows of the logs stepped at once with numpy.

Each window starts from a logged state (position and its derivative) and is driven by the logged goal, torque enable
and supply; the servo's torque law (`bench.calibrate.servo.law`) is evaluated from the simulated state at every
substep, friction as BAM's budget (the torque that stops the output within the step, clipped to the budget: true
sticking), integrated by semi-implicit Euler. With play, motor and output are two bodies coupled at the gap's ends.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from bench.calibrate.servo.data import ServoRun
from bench.calibrate.servo.law import (
    ServoParams,
    coupling,
    duty,
    friction,
    friction_budget,
    gravity_torque,
    motor_torque,
    play_side,
    play_torque,
)

MAX_SUBSTEP = 0.0055  # s, the longest physics step (the 200 Hz XL330 logs: one step per frame, the 50 Hz STS3250: 4)
RUN_GAP = 1000.0  # s between runs on the shared time axis the goal is interpolated on


@dataclass(frozen=True)
class Windows:
    """Windows of logged runs, each `horizon` frames long, ready to simulate (W windows, S = horizon x substeps)."""

    run: np.ndarray  # (W,) index of the run
    start: np.ndarray  # (W,) first frame
    q0: np.ndarray
    dq0: np.ndarray
    times: np.ndarray  # (W, S) time of each substep on the shared axis
    run_start: np.ndarray  # (W,) the run's first time on the shared axis (a delayed goal is held before it)
    enable: np.ndarray  # (W, S), zero-order hold
    vin: np.ndarray  # (W, S)
    target: np.ndarray  # (W, H) logged positions at frames 1..H
    mask: np.ndarray  # (W, H) frames inside the run
    label: np.ndarray  # (W,) index of the gain setting
    axis_t: np.ndarray  # shared time axis of every run's frames
    axis_goal: np.ndarray
    axis_reset: np.ndarray  # frames where the firmware's internal target is reset (a run's first, torque off)
    axis_q: np.ndarray  # the logged position (what the internal target is reset to while the torque is off)
    goal0: np.ndarray  # (W, S) the goal with no delay
    substeps: int
    dt: float  # substep

    @property
    def horizon(self) -> int:
        return int(self.target.shape[1])

    def subset(self, keep: np.ndarray) -> Windows:
        """Only the windows `keep` selects (a boolean or index array)."""
        pick = np.asarray(keep)
        per = {k: getattr(self, k)[pick] for k in ("run", "start", "q0", "dq0", "times", "run_start", "enable", "vin")}
        per.update(target=self.target[pick], mask=self.mask[pick], label=self.label[pick])
        return Windows(
            **per,
            axis_t=self.axis_t,
            axis_goal=self.axis_goal,
            axis_reset=self.axis_reset,
            axis_q=self.axis_q,
            goal0=self.goal0[pick],
            substeps=self.substeps,
            dt=self.dt,
        )


def substeps_for(fps: float) -> int:
    return max(1, int(np.ceil(1.0 / (fps * MAX_SUBSTEP) - 1e-9)))


def make_windows(runs: list[ServoRun], labels: list[str], horizon: int, stride: int | None = None) -> Windows:
    """Windows of `horizon` frames every `stride` frames over `runs` (`horizon` <= 0: one window per whole run)."""
    fps = runs[0].fps
    n = substeps_for(fps)
    dt = 1.0 / (fps * n)
    offs = [i * RUN_GAP for i in range(len(runs))]
    axis_t = np.concatenate([r.t + o for r, o in zip(runs, offs)])
    axis_goal = np.concatenate([r.goal for r in runs])
    axis_reset = np.concatenate([(r.enable < 0.5) | (np.arange(r.frames) == 0) for r in runs])
    axis_q = np.concatenate([np.where(r.enable < 0.5, r.q, r.goal) for r in runs])
    H = max(r.frames for r in runs) - 1 if horizon <= 0 else horizon
    starts: list[tuple[int, int]] = []
    for i, r in enumerate(runs):
        if horizon <= 0:
            starts.append((i, 0))
        else:
            starts += [(i, s) for s in range(0, r.frames - horizon, stride or horizon)]
    W, S = len(starts), H * n
    sub = (np.arange(1, S + 1) - 1) / n  # substep k acts over frames k // n (its start, in frames)
    out = {k: np.zeros((W, S)) for k in ("times", "enable", "vin")}
    target, mask = np.zeros((W, H)), np.zeros((W, H), dtype=bool)
    q0, dq0, run_start = np.zeros(W), np.zeros(W), np.zeros(W)
    for w, (i, s) in enumerate(starts):
        r = runs[i]
        fr = s + sub
        idx = np.minimum(np.floor(fr + 1e-9).astype(int), r.frames - 1)
        out["times"][w] = offs[i] + fr / fps
        out["enable"][w] = r.enable[idx]
        out["vin"][w] = r.vin[idx]
        m = min(H, r.frames - 1 - s)
        target[w, :m] = r.q[s + 1 : s + 1 + m]
        mask[w, :m] = True
        q0[w], dq0[w], run_start[w] = r.q[s], r.dq[s], offs[i]
    return Windows(
        run=np.array([i for i, _ in starts]),
        start=np.array([s for _, s in starts]),
        q0=q0,
        dq0=dq0,
        run_start=run_start,
        target=target,
        mask=mask,
        label=np.array([labels.index(runs[i].label) for i, _ in starts]),
        axis_t=axis_t,
        axis_goal=axis_goal,
        axis_reset=axis_reset,
        axis_q=axis_q,
        goal0=np.interp(np.maximum(out["times"], run_start[:, None]), axis_t, axis_goal),
        substeps=n,
        dt=dt,
        **out,
    )


def target_axis(w: Windows, slowness: float) -> np.ndarray:
    """The firmware's internal target on every frame of the shared axis: the logged goal, followed at most at
    1/`slowness` rad/s (`law.goal_step` per frame), reset to the logged position while the torque is off.

    Sequential only where the limit binds: frames where the goal outruns the target, until it catches up."""
    g = w.axis_goal
    y = np.where(w.axis_reset, w.axis_q, g)
    if slowness <= 0.0:
        return y
    frame = float(np.min(np.diff(w.axis_t))) if g.size > 1 else 1.0  # the uniform frame period
    reach = frame / slowness
    late = np.flatnonzero(~w.axis_reset[1:] & (np.abs(g[1:] - y[:-1]) > reach)) + 1
    done = 0
    for k0 in late:
        k = int(max(k0, done))
        while k < g.size and not w.axis_reset[k]:
            y[k] = min(max(g[k], y[k - 1] - reach), y[k - 1] + reach)
            k += 1
            if y[k - 1] == g[k - 1]:
                break
        done = k
    return y


def goal_at(w: Windows, delay: Any, slowness: Any = 0.0) -> np.ndarray:
    """The goal each substep acts on: the firmware's internal target (`target_axis`) `delay` seconds earlier
    (held at the run's first value); (W, S), or (P, W, S) for a batch of delays or slownesses of shape (P, 1)."""
    d, sl = np.ravel(np.asarray(delay, dtype=float)), np.ravel(np.asarray(slowness, dtype=float))
    if np.all(sl == 0.0) and (np.ndim(delay) == 0 or np.all(d == d[0])):
        if d[0] == 0.0:
            return w.goal0
        return np.interp(np.maximum(w.times - d[0], w.run_start[:, None]), w.axis_t, w.axis_goal)
    P = max(d.size, sl.size)
    d, sl = np.broadcast_to(d, (P,)), np.broadcast_to(sl, (P,))
    out = np.empty((P, *w.times.shape))
    axes: dict[float, np.ndarray] = {}
    for i in range(P):
        if float(sl[i]) not in axes:
            axes[float(sl[i])] = target_axis(w, float(sl[i]))
        ax = axes[float(sl[i])]
        out[i] = np.interp(np.maximum(w.times - d[i], w.run_start[:, None]), w.axis_t, ax)
    return out if np.ndim(delay) or np.ndim(slowness) else out[0]


def simulate(p: ServoParams, w: Windows) -> np.ndarray:
    """Simulated positions at frames 1..H of every window, (W, H); `p.kp` is one gain per window.

    A batch of P parameter sets at once (the fit's finite differences): every field of `p` of shape (P, 1), `kp`
    (P, W); the result is then (P, W, H)."""
    goal = goal_at(w, p.delay, p.goal_slowness)
    shape = np.broadcast_shapes(np.shape(p.kp), np.shape(p.inertia), w.q0.shape)
    q, dq = np.broadcast_to(w.q0, shape).copy(), np.broadcast_to(w.dq0, shape).copy()
    S = goal.shape[-1]
    n, dt = w.substeps, w.dt
    out = np.empty((*shape, S // n))
    if np.any(np.asarray(p.play) > 0):
        return _simulate_play(p, w, goal, out)
    J = p.inertia
    for s in range(S):
        tm = motor_torque(p, duty(p, goal[..., s], q), w.vin[:, s], dq, w.enable[:, s])
        te = gravity_torque(p, q)
        net = tm + te
        f = friction(friction_budget(p, dq, tm, te), J / dt * dq + net)
        dq = dq + (net + f) / J * dt
        q = q + dq * dt
        if (s + 1) % n == 0:
            out[..., s // n] = q
    return out


def _simulate_play(p: ServoParams, w: Windows, goal: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Motor (rotor share of the inertia) and output coupled across the play; the encoder reads the output."""
    n, dt = w.substeps, w.dt
    c = coupling(p, dt)
    half = 0.5 * p.play
    j_m, j_l = p.rotor_share * p.inertia, (1.0 - p.rotor_share) * p.inertia
    shape = np.broadcast_shapes(np.shape(p.kp), np.shape(p.inertia), w.q0.shape)
    q, dq = np.broadcast_to(w.q0, shape).copy(), np.broadcast_to(w.dq0, shape).copy()
    d0 = duty(p, goal[..., 0], q)
    side = play_side(d0, gravity_torque(p, q))
    qm, dqm = q + side * half, dq.copy()
    for s in range(goal.shape[-1]):
        tm = motor_torque(p, duty(p, goal[..., s], q), w.vin[:, s], dqm, w.enable[:, s])
        tc = play_torque(c, qm, q, dqm, dq, half)
        te = gravity_torque(p, q)
        net = tc + te
        f = friction(friction_budget(p, dq, tc, te), j_l / dt * dq + net)
        dq = dq + (net + f) / j_l * dt
        dqm = dqm + (tm - tc) / j_m * dt
        q = q + dq * dt
        qm = qm + dqm * dt
        if (s + 1) % n == 0:
            out[..., s // n] = q
    return out
