"""Batched replay (`mujoco.rollout`) against a Python `mj_step` loop on the same episodes, measured in one run.

    python benchmarks/bench_replay.py [episodes=8] [duration=6] [fps=100] [k=10] [repeats=5] [threads=1,2]

Data: `bench.calibrate.generate` logs of the 3-joint arm (models/arm3.xml, plain, no hidden effect),
`episodes` x `duration` s at `fps` Hz, 5 substeps per frame (2 ms steps). Both sides replay the
same segments of all three horizons (one-step, k-step, free run: one segment per frame, per k
frames and per episode) in the same model from the same logged initial states under the same
logged commands:

- batched: `bench.calibrate.metrics.horizon_errors` (what `bench replay spec=` runs): one
  `mujoco.rollout` call per horizon kind, `threads` rollout threads;
- loop: for each segment, `mj_resetData`, set qpos / qvel, then per frame set ctrl and call
  `mujoco.mj_step` once per substep, keeping qpos at the end of each frame.

Prints the best of `repeats` wall times of each (interleaved; on a shared machine the best is the one
least disturbed by other processes), their ratio, and the largest difference between the trajectories.

It also prints the ceiling any batching can reach on this machine: the physics alone (`mj_step` with
`nstep`, one C call, no Python per step) costs F us/step, so a batched replay on c cores cannot beat
F / c us/step, and the loop / batched ratio cannot exceed loop us/step / (F / c). On the 3-joint arm
F is about 0.9 us and the loop about 2 us, so 2 cores cap the ratio near 4-5x whatever the batching.
"""
from __future__ import annotations

import os
import sys
import time

import mujoco
import numpy as np

from bench.calibrate.data import Window, extract
from bench.calibrate.generate import ARM, simulate_arm, spec_dict
from bench.calibrate.metrics import horizon_errors, horizon_segments
from bench.calibrate.model import Layout, Plant, load_model
from bench.calibrate.simulate import Simulator
from bench.calibrate.spec import parse_spec


def step_loop(plant: Plant, segments: dict) -> tuple[dict[str, np.ndarray], int]:
    """Predicted qpos per segment (as `horizon_errors` gives them) from a Python mj_step loop; and steps taken."""
    m, rec, s = plant.model, plant.rec, plant.substeps
    d = mujoco.MjData(m)
    out, steps = {}, 0
    for label, segs in segments.items():
        pred = np.zeros((len(segs), segs.length, m.nq))
        for i, start in enumerate(segs.start):
            n = segs.length if segs.mask is None else int(segs.mask[i].sum())
            mujoco.mj_resetData(m, d)
            d.qpos[:] = rec.qpos[start]
            d.qvel[:] = rec.qvel[start]
            for f in range(n):
                d.ctrl[:] = rec.ctrl[start + f]
                for _ in range(s):
                    mujoco.mj_step(m, d)
                pred[i, f] = d.qpos
            steps += n * s
        out[label] = pred
    return out, steps


def physics_floor(plant: Plant, steps: int = 100_000) -> float:
    """Seconds per step of the physics alone: one `mj_step(nstep=...)` C call, no Python per step."""
    d = mujoco.MjData(plant.model)
    d.ctrl[:] = plant.rec.ctrl[0]
    best = float("inf")
    for _ in range(3):
        mujoco.mj_resetData(plant.model, d)
        t0 = time.perf_counter()
        mujoco.mj_step(plant.model, d, nstep=steps)
        best = min(best, time.perf_counter() - t0)
    return best / steps


def _timed(fn) -> tuple[float, object]:
    t0 = time.perf_counter()
    result = fn()
    return time.perf_counter() - t0, result


def main(argv: list[str]) -> int:
    from bench.config import parse_kv

    _, kv = parse_kv(argv)
    episodes, duration, fps = int(kv.get("episodes", 8)), float(kv.get("duration", 6.0)), float(kv.get("fps", 100.0))
    k, repeats = int(kv.get("k", 10)), int(kv.get("repeats", 5))
    threads = kv.get("threads", [1, 2])
    threads = threads if isinstance(threads, list) else [threads]

    eps, _ = simulate_arm(None, episodes=episodes, duration=duration, fps=fps, seed=0)
    raw = spec_dict(None, model_file=str(ARM))
    raw["params"] = []
    spec = parse_spec(raw)
    model = load_model(spec.model)
    rec = extract(spec, eps, fps, nq=model.nq, nv=model.nv, nu=model.nu)
    plant = Plant(spec, model, rec)
    variant = Layout(plant).realise(np.zeros(0))
    windows = [Window(i, 0, int(rec.offsets[i + 1] - rec.offsets[i])) for i in range(rec.n_episodes)]
    segments = horizon_segments(rec, windows, k)
    nseg = {h: len(s) for h, s in segments.items()}
    print(f"arm3 (3 hinge joints), {episodes} episodes x {duration:g} s at {fps:g} Hz = {len(rec.qpos)} frames, "
          f"{plant.substeps} substeps/frame (dt {plant.model.opt.timestep * 1e3:g} ms), k = {k}; "
          f"segments: {nseg}; mujoco {mujoco.__version__}; best of {repeats}")

    sims = {n: Simulator(plant, n) for n in threads}
    best = {key: float("inf") for key in ["loop", *threads]}
    try:
        for _ in range(repeats):  # interleaved, so load from other processes hits both sides alike
            t, (ref, steps) = _timed(lambda: step_loop(plant, segments))
            best["loop"] = min(best["loop"], t)
            for n, sim in sims.items():
                t, errors = _timed(lambda: horizon_errors(sim, variant, rec, windows, k))
                best[n] = min(best[n], t)
    finally:
        for sim in sims.values():
            sim.close()
    t_loop = best["loop"]
    print(f"  python mj_step loop      {t_loop:8.3f} s   {steps:,} steps   {t_loop / steps * 1e6:6.2f} us/step")
    diff = max(float(np.abs(errors[h].pred[errors[h].mask] - ref[h][errors[h].mask]).max()) for h in errors)
    for n in threads:
        t_batch = best[n]
        print(f"  mujoco.rollout, {n} thread{'s' if n > 1 else ' '} {t_batch:8.3f} s   {steps:,} steps   "
              f"{t_batch / steps * 1e6:6.2f} us/step   speed-up x{t_loop / t_batch:5.2f}")
    print(f"  max |qpos difference| between the two: {diff:.1e} rad (all segments of all three horizons)")
    floor, cores = physics_floor(plant), os.cpu_count() or 1
    print(f"  physics alone (mj_step nstep, one C call): {floor * 1e6:.2f} us/step -> on {cores} core{'s' if cores > 1 else ''} "
          f"no batching can beat {floor / cores * 1e6:.2f} us/step: ceiling of the speed-up "
          f"x{t_loop / steps / (floor / cores):.1f} (x{t_loop / steps / floor:.1f} per core)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
