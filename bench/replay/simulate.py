"""Batched multi-step simulation from logged states with `mujoco.rollout`.

A *segment* starts at a logged frame, takes the logged position and velocity as its initial state
and is simulated `length` frames ahead under the applied command (truncated horizons: no
integrator drift accumulates across segments). A `Variant` is what one rollout needs: a model, the
command per substep, a constant generalised force, optionally a gain on the log's extra inputs and
a state-dependent force. All segments of all variants run in one rollout call per model structure;
variants with a state-dependent force run in a stepped rollout that advances every segment one
substep per call and adds that force in between. Callers (replay as given, calibration's
parameter variants) build the variants; this module only runs them.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import mujoco
import numpy as np
from mujoco import rollout

from bench.core.errors import SpecError
from bench.replay.data import Recording, Window

CONTROL_SPEC = int(mujoco.mjtState.mjSTATE_CTRL) | int(mujoco.mjtState.mjSTATE_QFRC_APPLIED)

# generalised force (rows, nv) from the rows' (qpos, qvel) and the command applied at this substep
StateForce = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Segments:
    """Initial frames (global indices) of equal-length segments; `mask` marks frames that exist."""

    start: np.ndarray  # (n,)
    length: int
    mask: np.ndarray | None = None  # (n, length)

    def __len__(self) -> int:
        return len(self.start)


@dataclass(frozen=True)
class Coordinates:
    """Where the logged coordinates sit in a model that has more of them (e.g. a motor behind a play).

    `init(frames, qpos, qvel, ctrl)` maps the logged rows of global frames `frames` (n,): positions
    (n, nq_log), velocities (n, nv_log) and commands (n, nu), to full rows (n, model.nq),
    (n, model.nv) (from the rows, or from whatever else the caller keeps of those frames, e.g. the
    full logged MuJoCo state of a suite's scene); the simulated output is read
    back at `qpos_adr` and `dof_adr`. The unlogged coordinates (`hidden`, each moving with the logged
    coordinate `follows`) can be found by simulation instead: with `warmup` > 0 each segment is
    preceded by up to that many frames simulated from `init` at an earlier logged frame; at the
    segment's start the logged coordinates are set to the log and the hidden ones keep their
    simulated offset from the coordinate they follow (an open-loop observer of the hidden state).
    """

    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    init: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
    hidden: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # full qpos (= dof) adr
    follows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # logged index
    warmup: int = 0

    def anchor(
        self, q: np.ndarray, v: np.ndarray, log_q: np.ndarray, log_v: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Simulated full rows moved onto the logged coordinates, hidden ones keeping their offsets."""
        q, v = q.copy(), v.copy()
        q[:, self.hidden] += log_q[:, self.follows] - q[:, self.qpos_adr[self.follows]]
        v[:, self.hidden] += log_v[:, self.follows] - v[:, self.dof_adr[self.follows]]
        q[:, self.qpos_adr], v[:, self.dof_adr] = log_q, log_v
        return q, v


@dataclass
class Variant:
    """Everything one rollout needs for one model variant."""

    model: mujoco.MjModel
    ctrl: np.ndarray  # (N*S, nu) applied command per substep, all episodes concatenated
    qfrc_const: np.ndarray  # (nv,) constant generalised force
    input_gain: np.ndarray | None = None  # (m, nv): qfrc += inputs @ input_gain
    force: StateForce | None = None  # state-dependent generalised force, added every substep
    coords: Coordinates | None = None  # None: the model's coordinates are the logged ones


def hold(ctrl: np.ndarray, substeps: int) -> np.ndarray:
    """Per-frame commands held for each frame's substeps (zero-order hold): (N * substeps, nu)."""
    return np.repeat(ctrl, substeps, axis=0)


def prepare_model(model: mujoco.MjModel, fps: float, substeps: int | None) -> tuple[mujoco.MjModel, int]:
    """A copy of the model stepping exactly `substeps` times per log frame, and that number.

    Without `substeps`, round(1 / (fps * timestep)). Only hinge and slide joints (one qpos per dof,
    as the log has) and actuators without activation state (the state is set from the log).
    """
    if np.any((model.jnt_type == mujoco.mjtJoint.mjJNT_FREE) | (model.jnt_type == mujoco.mjtJoint.mjJNT_BALL)):
        raise SpecError("spec field 'model': free and ball joints are not supported; use hinge and slide joints")
    if model.na:
        raise SpecError("spec field 'model': actuators with activation state are not supported")
    substeps = substeps or max(1, int(round(1.0 / (fps * model.opt.timestep))))
    out = copy.copy(model)
    out.opt.timestep = 1.0 / (fps * substeps)  # exactly one log frame per `substeps`
    return out, substeps


def as_given(model: mujoco.MjModel, rec: Recording, substeps: int) -> Variant:
    """The model as it is, driven by the logged command held over each frame's substeps."""
    return Variant(model, hold(rec.ctrl, substeps), np.zeros(model.nv))


def horizons(rec: Recording, windows: list[Window], k: int, *, limit: int | None = None, seed: int = 0) -> Segments:
    """Back-to-back k-frame horizons covering each window (the last one overlaps to reach its end).

    A window shorter than k frames gets one horizon to its end; the frames past it (which would run
    into the next episode) are masked out. With `limit`, a seeded subset of at most that many
    horizons (the fit's cost is linear in them).
    """
    starts, ends, longest = [], [], 1
    for w in windows:
        first, last = rec.offsets[w.episode] + w.start, rec.offsets[w.episode] + w.stop - 1  # last frame
        kk = min(k, last - first)
        if kk < 1:
            continue
        longest = max(longest, kk)
        s = list(range(first, last - kk + 1, kk))
        if s[-1] + kk < last:
            s.append(last - kk)
        starts.extend(s)
        ends.extend([last] * len(s))
    start, end = np.array(starts, dtype=np.int64), np.array(ends, dtype=np.int64)
    if limit is not None and len(start) > limit:
        keep = np.random.default_rng(seed).choice(len(start), size=limit, replace=False)  # as choice(start, ...)
        keep = keep[np.argsort(start[keep], kind="stable")]  # in the order of their start frames
        start, end = start[keep], end[keep]
    k = min(k, longest)  # no segment is longer than its window: frames past every window's end are never simulated
    mask = start[:, None] + 1 + np.arange(k)[None, :] <= end[:, None]
    return Segments(start, k, None if mask.all() else mask)


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
    """Runs variants over segments of a recording; owns the rollout thread pool and MjData instances.

    `model` is the prepared model (`prepare_model`); the output is the recording's (logged)
    coordinates: the model's own, or where `Variant.coords` puts them in a larger model.
    """

    def __init__(self, model: mujoco.MjModel, rec: Recording, substeps: int, threads: int = 1) -> None:
        self.model, self.rec, self.substeps = model, rec, substeps
        self.nq, self.nv, self.nu = rec.qpos.shape[1], rec.qvel.shape[1], model.nu  # the logged coordinates
        self.threads = max(1, threads)
        self.pool = rollout.Rollout(nthread=threads if threads > 1 else 0)
        self.base_inputs = None if rec.inputs is None else hold(rec.inputs, substeps)
        self._datas: dict[tuple, list[mujoco.MjData]] = {}
        self._templates: dict[tuple, np.ndarray] = {}
        self.steps = 0  # simulator steps taken, for throughput figures

    def close(self) -> None:
        self.pool.close()

    @staticmethod
    def _structure(m: mujoco.MjModel) -> tuple:
        return (m.nq, m.nv, m.nu, m.na, m.nsensordata)

    def _prepare(self, m: mujoco.MjModel) -> tuple[list[mujoco.MjData], np.ndarray]:
        """MjData instances and the initial-state template for a model structure (made once)."""
        key = self._structure(m)
        if key not in self._datas:
            self._datas[key] = [mujoco.MjData(m) for _ in range(self.threads)]
            template = np.zeros(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
            mujoco.mj_getState(m, mujoco.MjData(m), template, mujoco.mjtState.mjSTATE_FULLPHYSICS)
            template[0] = 0.0
            self._templates[key] = template
        return self._datas[key], self._templates[key]

    def _initial(self, v: Variant, segs: Segments) -> np.ndarray:
        """Initial full states of one variant's segments: the logged state (mapped, warmed up)."""
        m, rec = v.model, self.rec
        _, template = self._prepare(m)
        st = np.repeat(template[None, :], len(segs), axis=0)
        qp, qv = slice(1, 1 + m.nq), slice(1 + m.nq, 1 + m.nq + m.nv)
        if v.coords is None:
            st[:, qp] = rec.qpos[segs.start]
            st[:, qv] = rec.qvel[segs.start]
            return st
        st[:, qp], st[:, qv] = v.coords.init(
            segs.start, rec.qpos[segs.start], rec.qvel[segs.start], rec.ctrl[segs.start]
        )
        w = v.coords.warmup
        if w <= 0:
            return st
        episode = np.searchsorted(rec.offsets, segs.start, side="right") - 1
        first = np.maximum(rec.offsets[episode], segs.start - w)
        lead = segs.start - first  # frames of warm-up each segment gets (0 at an episode's start)
        pre = Segments(first, w)
        unwarmed = replace(v, coords=replace(v.coords, warmup=0))
        frames = self._full([unwarmed], pre, self._initial(unwarmed, pre))
        has = lead > 0
        sim = frames[has, lead[has] - 1]
        st[has, qp], st[has, qv] = v.coords.anchor(
            sim[:, : m.nq], sim[:, m.nq :], rec.qpos[segs.start[has]], rec.qvel[segs.start[has]]
        )
        return st

    def _controls(self, v: Variant, segs: Segments) -> np.ndarray:
        s, nu, nv = self.substeps, v.model.nu, v.model.nv
        total = len(v.ctrl)
        idx = np.minimum(segs.start[:, None] * s + np.arange(segs.length * s)[None, :], total - 1)
        out = np.empty((len(segs), segs.length * s, nu + nv))
        out[..., :nu] = v.ctrl[idx]
        out[..., nu:] = v.qfrc_const
        if v.input_gain is not None:
            assert self.base_inputs is not None, "an input gain needs logged inputs (signals.inputs)"
            out[..., nu:] += self.base_inputs[idx] @ v.input_gain
        return out

    def _readout(self, v: Variant, qv: np.ndarray) -> np.ndarray:
        """Logged coordinates [qpos, qvel] out of full (…, model.nq + model.nv) rows."""
        if v.coords is None:
            return qv
        nq = v.model.nq
        return np.concatenate([qv[..., v.coords.qpos_adr], qv[..., nq + v.coords.dof_adr]], axis=-1)

    def run(self, variants: list[Variant], segs: Segments) -> np.ndarray:
        """Simulated [qpos, qvel] at the frames each segment predicts: (V, n, length, nq + nv)."""
        out = np.empty((len(variants), len(segs), segs.length, self.nq + self.nv))
        if len(segs) == 0 or not variants:  # nothing to simulate (MuJoCo's rollout crashes on an empty batch)
            return out
        groups: dict[tuple, list[int]] = {}
        for i, v in enumerate(variants):
            groups.setdefault((v.force is not None, self._structure(v.model)), []).append(i)
        for group in groups.values():
            out[group] = self._logged([variants[i] for i in group], segs)
        return out

    def _logged(self, variants: list[Variant], segs: Segments) -> np.ndarray:
        """Logged coordinates of variants of one structure: (V, n, length, nq + nv)."""
        init = np.ascontiguousarray(np.concatenate([self._initial(v, segs) for v in variants]))
        frames = self._full(variants, segs, init).reshape(len(variants), len(segs), segs.length, -1)
        if all(v.coords is None for v in variants):
            return frames
        return np.stack([self._readout(v, f) for v, f in zip(variants, frames)])

    def _full(self, variants: list[Variant], segs: Segments, init: np.ndarray) -> np.ndarray:
        """Full [qpos, qvel] of the variants' models after each frame: (V * n, length, nq + nv).

        One rollout call for all; with a force hook, one call per substep with the force added.
        """
        s, n, m = self.substeps, len(segs), variants[0].model
        datas, template = self._prepare(m)
        models = [v.model for v in variants for _ in range(n)]
        ctrl = np.ascontiguousarray(np.concatenate([self._controls(v, segs) for v in variants]))
        nstep = segs.length * s
        self.steps += len(models) * nstep
        if all(v.force is None for v in variants):
            state = np.empty((len(models), nstep, len(template)))
            sens = np.empty((len(models), nstep, m.nsensordata))
            self.pool.rollout(
                models,
                datas,
                init,
                ctrl,
                control_spec=CONTROL_SPEC,
                skip_checks=True,
                nstep=nstep,
                state=state,
                sensordata=sens,
            )
            return state[:, s - 1 :: s, 1 : 1 + m.nq + m.nv]
        st = init
        frames = np.empty((len(models), segs.length, m.nq + m.nv))
        state = np.empty((len(models), 1, len(template)))
        sens = np.empty((len(models), 1, m.nsensordata))
        qp, qv = slice(1, 1 + m.nq), slice(1 + m.nq, 1 + m.nq + m.nv)
        rows = [slice(i * n, (i + 1) * n) for i in range(len(variants))]
        for k in range(nstep):
            u = ctrl[:, k : k + 1].copy()
            for v, r in zip(variants, rows):
                if v.force is not None:
                    u[r, 0, m.nu :] += v.force(st[r, qp], st[r, qv], u[r, 0, : m.nu])
            self.pool.rollout(
                models, datas, st, u, control_spec=CONTROL_SPEC, skip_checks=True, nstep=1, state=state, sensordata=sens
            )
            st = np.ascontiguousarray(state[:, 0])
            if k % s == s - 1:
                frames[:, k // s] = st[:, 1 : 1 + m.nq + m.nv]
        return frames
