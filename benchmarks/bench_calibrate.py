"""Wall time of the whole Real2Sim loop (declared fit, trace, refits, held-out errors), measured in one run.

    python benchmarks/bench_calibrate.py [case=all|emps|arm] [threads=2] [effect=coulomb_friction]

Cases:
  - emps: the EMPS estimation run (24,841 frames at 1 kHz, last 30% held out), imported from
    ../shared/data/real/emps/DATA_EMPS.mat; target < 10 s.
  - arm: 8 episodes x 6 s at 100 Hz of the 3-joint arm with one hidden effect; target < 60 s.
Each line gives wall and CPU seconds (on a shared machine the wall clock also counts waiting for a
core), the simulator steps the loop took, and the loop's cost per step against raw `mujoco.rollout`
stepping of the same model measured in the same run (100% = the loop does nothing but simulate).
Default threads: min(2, cores); results do not depend on the thread count.
"""
from __future__ import annotations

import copy
import os
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
from mujoco import rollout

from bench.calibrate.generate import MODELS, declared_files, simulate_arm
from bench.calibrate.spec import load_spec
from bench.calibrate.trace import Calibration, run

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def raw_steps_per_second(model: mujoco.MjModel, timestep: float, threads: int, seconds: float = 1.0) -> float:
    """Raw rollout throughput of a model with friction loss switched on (as after the first effect)."""
    m = copy.copy(model)
    m.opt.timestep = timestep
    m.dof_frictionloss[:] = 0.1
    nstate = mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    spec = int(mujoco.mjtState.mjSTATE_CTRL) | int(mujoco.mjtState.mjSTATE_QFRC_APPLIED)
    rng = np.random.default_rng(0)
    b, n = 256, 100
    init = np.zeros((b, nstate))
    ctrl = np.zeros((b, n, m.nu + m.nv))
    ctrl[..., : m.nu] = rng.normal(0.0, 1.0, (b, n, m.nu))
    datas = [mujoco.MjData(m) for _ in range(threads)]
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        rollout.rollout(m, datas, init, ctrl, control_spec=spec)
        steps += b * n
    return steps / (time.perf_counter() - t0)


def timed(label: str, fn, target: float, threads: int) -> Calibration:
    w0, c0 = time.perf_counter(), time.process_time()
    cal = fn()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    model = cal.plant.model
    raw = raw_steps_per_second(model, model.opt.timestep, threads)
    steps = cal.wall["sim_steps"]
    e = cal.errors
    added = ", ".join(f"{a['name']}@{a['target']}" for a in cal.added) or "none"
    verdict = "ok" if wall < target else "MISSED"
    print(f"{label} ({threads} rollout thread{'s' if threads > 1 else ''}): wall {wall:.2f} s "
          f"(target < {target:g} s: {verdict}), cpu {cpu:.2f} s; declared fit {cal.wall['declared_fit']:.2f} s, trace {cal.wall['trace']:.2f} s")
    print(f"  {steps / 1e6:.2f} M simulator steps; raw rollout {raw / 1e3:.0f} k steps/s -> pure simulation "
          f"{steps / raw:.2f} s = {steps / raw / wall:.0%} of the wall time")
    print(f"  added: {added}; held-out free-run NRMSE {e['declared']['free_run_nrmse']:.4g} -> "
          f"{e['final']['free_run_nrmse']:.4g}, RMSE {e['declared']['free_run_rmse']:.4g} -> "
          f"{e['final']['free_run_rmse']:.4g} (nominal {e['nominal']['free_run_rmse']:.4g})")
    return cal


def bench_emps(threads: int) -> None:
    mat = SHARED / "data/real/emps/DATA_EMPS.mat"
    if not mat.is_file():
        print(f"emps: skipped, {mat} not found (../shared is only beside the checkout)")
        return
    from bench.logs import import_mat

    t0 = time.perf_counter()
    ds = import_mat(mat, {"observation.state": ["qm"], "action": ["vir"]})
    print(f"emps: import {time.perf_counter() - t0:.2f} s ({ds.num_frames} frames at {ds.fps:g} Hz)")
    spec = load_spec(MODELS / "emps.yaml")
    timed("emps loop", lambda: run(spec, [e.data for e in ds.episodes], ds.fps, threads=threads), 10.0, threads)


def bench_arm(threads: int, effect: str) -> None:
    import tempfile

    t0 = time.perf_counter()
    episodes, truth = simulate_arm(effect, episodes=8, duration=6.0, fps=100.0, seed=0)
    print(f"arm: generated 8 x 6 s at 100 Hz with hidden {truth.effect}@{truth.target} {truth.params} "
          f"in {time.perf_counter() - t0:.2f} s")
    with tempfile.TemporaryDirectory() as tmp:
        spec = load_spec(declared_files(tmp, effect))
        timed("arm loop", lambda: run(spec, episodes, 100.0, threads=threads), 60.0, threads)


def main(argv: list[str]) -> int:
    kv = dict(a.split("=", 1) for a in argv if "=" in a)
    case = kv.get("case", "all")
    threads = int(kv.get("threads", min(2, os.cpu_count() or 1)))
    if case in ("all", "emps"):
        bench_emps(threads)
    if case in ("all", "arm"):
        bench_arm(threads, kv.get("effect", "coulomb_friction"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
