"""Batched multi-step simulation from logged states with `mujoco.rollout`.

A *segment* starts at a logged frame, takes the logged position and velocity as its initial state
and is simulated `length` frames ahead under the applied command (truncated horizons: no
integrator drift accumulates across segments). All segments of all variants run in one rollout
call; variants with Stribeck friction, whose force depends on the simulated velocity, run in a
stepped rollout that advances every segment one substep per call and adds that force in between.
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import rollout

from bench.calibrate.data import Recording, Window
from bench.calibrate.effects import stribeck_force
from bench.calibrate.model import Plant, Variant

CONTROL_SPEC = int(mujoco.mjtState.mjSTATE_CTRL) | int(mujoco.mjtState.mjSTATE_QFRC_APPLIED)


@dataclass(frozen=True)
class Segments:
    """Initial frames (global indices) of equal-length segments; `mask` marks frames that exist."""

    start: np.ndarray  # (n,)
    length: int
    mask: np.ndarray | None = None  # (n, length)

    def __len__(self) -> int:
        return len(self.start)


def horizons(rec: Recording, windows: list[Window], k: int, *, limit: int | None = None,
             seed: int = 0) -> Segments:
    """Back-to-back k-frame horizons covering each window (the last one overlaps to reach its end).

    With `limit`, a seeded subset of at most that many horizons (the fit's cost is linear in them).
    """
    starts = []
    for w in windows:
        first, last = rec.offsets[w.episode] + w.start, rec.offsets[w.episode] + w.stop - 1  # last frame
        kk = min(k, last - first)
        if kk < 1:
            continue
        s = list(range(first, last - kk + 1, kk))
        if s[-1] + kk < last:
            s.append(last - kk)
        starts.extend(s)
    start = np.array(starts, dtype=np.int64)
    if limit is not None and len(start) > limit:
        start = np.sort(np.random.default_rng(seed).choice(start, size=limit, replace=False))
    return Segments(start, k)


def free_runs(rec: Recording, windows: list[Window]) -> Segments:
    """One segment per window, from its first logged state to its end (padded, with a mask)."""
    lengths = np.array([len(w) - 1 for w in windows])
    n = int(lengths.max())
    mask = np.arange(n)[None, :] < lengths[:, None]
    start = np.array([rec.offsets[w.episode] + w.start for w in windows], dtype=np.int64)
    return Segments(start, n, mask)


def logged(rec: Recording, segs: Segments) -> np.ndarray:
    """Logged [qpos, qvel] at the frames each segment predicts: (n, length, nq + nv)."""
    idx = np.minimum(segs.start[:, None] + 1 + np.arange(segs.length)[None, :], len(rec.qpos) - 1)
    return np.concatenate([rec.qpos[idx], rec.qvel[idx]], axis=-1)


class Simulator:
    """Runs variants over segments; owns the rollout thread pool and MjData instances."""

    def __init__(self, plant: Plant, threads: int = 1) -> None:
        self.plant = plant
        m = plant.model
        self.nq, self.nv, self.nu = m.nq, m.nv, m.nu
        self.datas = [mujoco.MjData(m) for _ in range(max(1, threads))]
        self.pool = rollout.Rollout(nthread=threads if threads > 1 else 0)
        template = np.zeros(plant.nstate)
        mujoco.mj_getState(m, mujoco.MjData(m), template, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        template[0] = 0.0
        self.template = template
        self.steps = 0  # simulator steps taken, for throughput figures

    def close(self) -> None:
        self.pool.close()

    def _initial(self, segs: Segments) -> np.ndarray:
        rec = self.plant.rec
        st = np.repeat(self.template[None, :], len(segs), axis=0)
        st[:, 1:1 + self.nq] = rec.qpos[segs.start]
        st[:, 1 + self.nq:1 + self.nq + self.nv] = rec.qvel[segs.start]
        return st

    def _controls(self, v: Variant, segs: Segments) -> np.ndarray:
        s = self.plant.substeps
        total = len(v.ctrl)
        idx = np.minimum(segs.start[:, None] * s + np.arange(segs.length * s)[None, :], total - 1)
        out = np.empty((len(segs), segs.length * s, self.nu + self.nv))
        out[..., : self.nu] = v.ctrl[idx]
        out[..., self.nu:] = v.qfrc_const
        if v.input_gain is not None:
            out[..., self.nu:] += self.plant.base_inputs[idx] @ v.input_gain
        return out

    def run(self, variants: list[Variant], segs: Segments) -> np.ndarray:
        """Simulated [qpos, qvel] at the frames each segment predicts: (V, n, length, nq + nv)."""
        out = np.empty((len(variants), len(segs), segs.length, self.nq + self.nv))
        smooth = [i for i, v in enumerate(variants) if v.stribeck is None]
        stepped = [i for i, v in enumerate(variants) if v.stribeck is not None]
        for group, fn in ((smooth, self._rollout), (stepped, self._stepped)):
            if group:
                out[group] = fn([variants[i] for i in group], segs)
        return out

    def _batch(self, variants: list[Variant], segs: Segments) -> tuple[list, np.ndarray, np.ndarray]:
        n = len(segs)
        models = [v.model for v in variants for _ in range(n)]
        init = np.tile(self._initial(segs), (len(variants), 1))
        ctrl = np.concatenate([self._controls(v, segs) for v in variants])
        return models, np.ascontiguousarray(init), np.ascontiguousarray(ctrl)

    def _rollout(self, variants: list[Variant], segs: Segments) -> np.ndarray:
        s = self.plant.substeps
        models, init, ctrl = self._batch(variants, segs)
        nstep = segs.length * s
        state = np.empty((len(models), nstep, self.plant.nstate))
        sens = np.empty((len(models), nstep, self.plant.model.nsensordata))
        self.pool.rollout(models, self.datas, init, ctrl, control_spec=CONTROL_SPEC, skip_checks=True,
                          nstep=nstep, state=state, sensordata=sens)
        self.steps += len(models) * nstep
        frames = state[:, s - 1::s, 1:1 + self.nq + self.nv]
        return frames.reshape(len(variants), len(segs), segs.length, -1)

    def _stepped(self, variants: list[Variant], segs: Segments) -> np.ndarray:
        s, n = self.plant.substeps, len(segs)
        models, st, ctrl = self._batch(variants, segs)
        fs = np.repeat(np.stack([v.stribeck[0] for v in variants]), n, axis=0)
        vs = np.repeat(np.stack([v.stribeck[1] for v in variants]), n, axis=0)
        frames = np.empty((len(models), segs.length, self.nq + self.nv))
        state = np.empty((len(models), 1, self.plant.nstate))
        sens = np.empty((len(models), 1, self.plant.model.nsensordata))
        qv = slice(1 + self.nq, 1 + self.nq + self.nv)
        for k in range(segs.length * s):
            u = ctrl[:, k:k + 1].copy()
            u[:, 0, self.nu:] += stribeck_force(st[:, qv], fs, vs)
            self.pool.rollout(models, self.datas, st, u, control_spec=CONTROL_SPEC, skip_checks=True,
                              nstep=1, state=state, sensordata=sens)
            st = np.ascontiguousarray(state[:, 0])
            if k % s == s - 1:
                frames[:, k // s] = st[:, 1:1 + self.nq + self.nv]
        self.steps += len(models) * segs.length * s
        return frames.reshape(len(variants), n, segs.length, -1)
