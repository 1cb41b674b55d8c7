"""Env-steps/s of MJX against the CPU MuJoCo loop and `mujoco.rollout` on the same model, in one run.

    python benchmarks/bench_mjx.py [model=panda|arm3] [worlds=[1,64,1024,4096]] [steps=100] [x64=false]

Model: robosuite's Panda as a dynamics-only model (`bench.sims.panda_dynamics`: 7 joints, torque
motors, no contact), or the calibration's 3-joint arm (`bench/calibrate/models/arm3.xml`). Each world
starts from its own seeded random state and is driven by its own random torques for `steps` physics
steps. Per world count, interleaved in this process:

  - `mj_step` loop: one CPU core stepping the worlds one after another (a few worlds are enough to time it);
  - `mujoco.rollout`: all worlds in one call on every CPU thread of this machine;
  - MJX: all worlds in one compiled `jax.vmap` x `lax.scan` call on JAX's default device (the CPU here, a
    GPU where JAX finds one, unchanged), after a first call that compiles (its time is printed apart).

and the ratios MJX / mj_step and MJX / rollout. Then the gradient: value and gradient of a trajectory
loss over 64 worlds x `steps` steps with respect to every dof's damping (reverse mode; the model has no
constraint rows, so `opt.iterations = 1` changes nothing), per step. float32 by default (what a GPU runs
fast); x64=true for float64.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
from mujoco import rollout

REPO = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Keys:
    """Keys of this benchmark."""

    model: str = "panda"  # panda (robosuite's Panda, dynamics only) | arm3
    worlds: list[int] = field(default_factory=lambda: [1, 64, 1024, 4096])  # world counts
    steps: int = 100  # physics steps per world
    x64: bool = False  # float64 in MJX (default float32)
    grad_worlds: int = 64  # worlds of the gradient timing


def load(name: str) -> mujoco.MjModel:
    if name == "panda":
        from bench.sims import panda_dynamics

        return panda_dynamics.model()
    if name == "arm3":
        return mujoco.MjModel.from_xml_path(str(REPO / "bench/calibrate/models/arm3.xml"))
    raise SystemExit(f"error: model is {name!r}; valid: panda, arm3")


def inputs(m: mujoco.MjModel, n: int, steps: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    qpos = m.qpos0[None] + 0.2 * rng.standard_normal((n, m.nq))
    qvel = 0.2 * rng.standard_normal((n, m.nv))
    ctrl = np.zeros((n, steps, m.nu + m.nv))
    ctrl[..., : m.nu] = 2.0 * rng.standard_normal((n, steps, m.nu))
    return qpos, qvel, ctrl


def loop_rate(m: mujoco.MjModel, qpos, qvel, ctrl, budget: float = 1.0) -> float:
    """mj_step steps/s on one core (as many worlds as fit the time budget)."""
    d = mujoco.MjData(m)
    done, t0 = 0, time.perf_counter()
    for w in range(len(qpos)):
        mujoco.mj_resetData(m, d)
        d.qpos[:], d.qvel[:] = qpos[w], qvel[w]
        for k in range(ctrl.shape[1]):
            d.ctrl[:] = ctrl[w, k, : m.nu]
            mujoco.mj_step(m, d)
        done += ctrl.shape[1]
        if time.perf_counter() - t0 > budget:
            break
    return done / (time.perf_counter() - t0)


def rollout_rate(m: mujoco.MjModel, qpos, qvel, ctrl, threads: int) -> float:
    n, steps = len(qpos), ctrl.shape[1]
    size = mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    init = np.zeros((n, size))
    init[:, 1 : 1 + m.nq], init[:, 1 + m.nq : 1 + m.nq + m.nv] = qpos, qvel
    datas = [mujoco.MjData(m) for _ in range(threads)]
    with rollout.Rollout(nthread=threads if threads > 1 else 0) as r:
        t0 = time.perf_counter()
        r.rollout([m] * n, datas, init, np.ascontiguousarray(ctrl[..., : m.nu]), nstep=steps)
        return n * steps / (time.perf_counter() - t0)


def main(argv: list[str]) -> int:
    from bench.core.config import build_from_argv
    from bench.sims import mjx as mjx_backend

    cfg = build_from_argv(Keys, argv, "bench_mjx")
    mjx_backend.require(x64=cfg.x64)
    m = load(cfg.model)
    threads = os.cpu_count() or 1
    print(
        f"model {cfg.model} (nq {m.nq}, nu {m.nu}, timestep {m.opt.timestep}); MJX on {mjx_backend.device()}, "
        f"{'float64' if cfg.x64 else 'float32'}; {threads} CPU threads; {cfg.steps} steps per world; "
        f"load {' '.join(open('/proc/loadavg').read().split()[:3])}"
    )
    sim = mjx_backend.Rollouts(m, 1)
    print(
        f"{'worlds':>7} {'mj_step loop':>14} {'mujoco.rollout':>15} {'MJX':>12} {'MJX compile':>12} {'MJX/loop':>9} {'MJX/rollout':>12}"
    )
    for n in cfg.worlds:
        qpos, qvel, ctrl = inputs(m, n, cfg.steps)
        c0 = sim.compile_s
        sim.simulate(qpos, qvel, ctrl, per_world=False)  # compiles this shape
        compile_s = sim.compile_s - c0
        loop = loop_rate(m, qpos, qvel, ctrl)
        roll = rollout_rate(m, qpos, qvel, ctrl, threads)
        t0 = time.perf_counter()
        reps = 0
        while reps < 1 or time.perf_counter() - t0 < 1.0:
            sim.simulate(qpos, qvel, ctrl, per_world=False)
            reps += 1
        mjx = reps * n * cfg.steps / (time.perf_counter() - t0)
        print(
            f"{n:7d} {loop:14,.0f} {roll:15,.0f} {mjx:12,.0f} {compile_s:11.1f}s {mjx / loop:9.3g} {mjx / roll:12.3g}",
            flush=True,
        )
    n = cfg.grad_worlds
    qpos, qvel, ctrl = inputs(m, n, cfg.steps, seed=1)
    target = sim.simulate(qpos, qvel, ctrl, per_world=False)
    params = {"model": {"dof_damping": np.full(m.nv, 0.5)}, "qfrc": np.zeros(m.nv)}
    batch = {
        "qpos0": qpos,
        "qvel0": qvel,
        "ctrl": ctrl,
        "target": target,
        "weight": np.ones(m.nq + m.nv),
        "mask": np.ones(target.shape, bool),
        "channels": np.arange(m.nq + m.nv),
    }
    c0 = sim.compile_s
    sim.value_and_grad(params, batch)
    compile_s = sim.compile_s - c0
    t0, reps = time.perf_counter(), 0
    while reps < 2 or time.perf_counter() - t0 < 2.0:
        value, grad = sim.value_and_grad(params, batch)
        reps += 1
    per = (time.perf_counter() - t0) / reps
    finite = bool(np.all(np.isfinite(grad["model"]["dof_damping"])))
    print(
        f"gradient of a trajectory loss over {n} worlds x {cfg.steps} steps w.r.t. {m.nv} dampings: {per:.3f} s "
        f"per value-and-gradient ({per / (n * cfg.steps) * 1e6:.2f} us per world-step; compile {compile_s:.1f} s; "
        f"finite: {finite})"
    )
    print(f"load at the end {' '.join(open('/proc/loadavg').read().split()[:3])}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
