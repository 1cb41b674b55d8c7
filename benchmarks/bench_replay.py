"""Batched replay (`mujoco.rollout`) against Python step loops on the same episodes, measured in one run.

    python benchmarks/bench_replay.py [case=both|arm|suite] [k=10] [repeats=5] [threads=1,2]
        arm:   [episodes=8] [duration=6] [fps=100]
        suite: [suite_episodes=6] [horizon=100]

case=suite (what `bench replay suite=held_out_robots` runs on `bench run record=` logs): Panda Lift
episodes of the scripted policy are recorded (`bench run ... record=`, nominal), then the same
segments of all three horizons are replayed in the nominal env three ways:

- action loop (`commands=action`): `env.step` with the logged policy actions, robosuite's OSC
  controller in Python at every physics step (25 per frame);
- mj_step loop: a Python loop calling `mujoco.mj_step` with the logged ctrl of every physics step;
- batched (`commands=ctrl`, `bench.replay.replay_ctrl`): the same logged ctrl, every segment of a
  horizon in one `mujoco.rollout` call, `threads` threads.

It prints seconds per replayed frame for each, the speed-ups of the batched replay over both
loops, the physics floor, and the largest difference between the loops' and the batched positions.

case=arm, data: `bench.calibrate.generate` logs of the 3-joint arm (models/arm3.xml, plain, no hidden effect),
`episodes` x `duration` s at `fps` Hz, 5 substeps per frame (2 ms steps). Both sides replay the
same segments of all three horizons (one-step, k-step, free run: one segment per frame, per k
frames and per episode) in the same model from the same logged initial states under the same
logged commands:

- batched: `bench.replay.metrics.horizon_errors` (what `bench replay spec=` runs): one
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

import contextlib
import io
import os
import sys
import time
from dataclasses import dataclass, field

import mujoco
import numpy as np

from bench.calibrate.generate import ARM, simulate_arm, spec_dict
from bench.replay.data import Recording, extract
from bench.replay.metrics import horizon_errors, horizon_segments
from bench.replay.simulate import Simulator, as_given, prepare_model
from bench.replay.spec import SignalMap, load_model, map_fields


def step_loop(m: mujoco.MjModel, rec: Recording, s: int, segments: dict) -> tuple[dict[str, np.ndarray], int]:
    """Predicted qpos per segment (as `horizon_errors` gives them) from a Python mj_step loop; and steps taken."""
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


def _timed(fn) -> tuple[float, object]:
    t0 = time.perf_counter()
    result = fn()
    return time.perf_counter() - t0, result


def mj_step_loop(logs, segments: dict) -> tuple[dict[str, np.ndarray], int]:
    """Predicted positions per segment from a Python loop over physics steps applying the logged ctrl."""
    env = logs.envs[0]
    m = env.model
    d = mujoco.MjData(m)
    d.mocap_pos[:], d.mocap_quat[:] = env.data.mocap_pos, env.data.mocap_quat
    sub, nu = logs.substeps, m.nu
    out, frames = {}, 0
    for label, segs in segments.items():
        pred = np.zeros((len(segs), segs.length, len(logs.idx)))
        for i, start in enumerate(segs.start):
            n = segs.length if segs.mask is None else int(segs.mask[i].sum())
            d.qpos[:] = logs.full[start, : m.nq]
            d.qvel[:] = logs.full[start, m.nq :]
            for f in range(n):
                u = logs.ctrl[start + f].reshape(sub, nu)
                for j in range(sub):
                    d.ctrl[:] = u[j]
                    mujoco.mj_step(m, d)
                pred[i, f] = d.qpos[logs.idx]
            frames += n
        out[label] = pred
    return out, frames


def _frames(segments: dict) -> int:
    return int(sum(len(s) * s.length if s.mask is None else s.mask.sum() for s in segments.values()))


def suite_case(args: Args, k: int, repeats: int, threads: list[int]) -> None:
    import tempfile
    from pathlib import Path

    from bench.cli import main as bench_main
    from bench.logs import read_dataset
    from bench.replay import ReplayConfig, load_suite_logs, replay_actions, replay_ctrl, suite_segments

    n_eps, horizon = args.suite_episodes, args.horizon
    with tempfile.TemporaryDirectory() as tmp:
        rec_dir = Path(tmp) / "rec"
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):  # the run's own tables are not the benchmark's
            rc = bench_main(
                [
                    "run",
                    "robots=[Panda]",
                    f"episodes={n_eps}",
                    f"horizon={horizon}",
                    "workers=2",
                    "policy=scripted",
                    "run_id=bench",
                    f"out={Path(tmp) / 'runs'}",
                    f"record={rec_dir}",
                ]
            )
        assert rc == 0, rc
        t_record = time.perf_counter() - t0
        ds = read_dataset(rec_dir)
        cfg = ReplayConfig(logs=str(rec_dir), suite="held_out_robots", k=k)
        logs = load_suite_logs(cfg, ds, list(ds.episodes), need_ctrl=True)
    try:
        seg_a, seg_c = suite_segments(logs, k, "action"), suite_segments(logs, k, "ctrl")
        fr_a, fr_c = _frames(seg_a), _frames(seg_c)
        best = {key: float("inf") for key in ["action", "mj_step", *threads]}
        preds = {}
        for _ in range(repeats):  # interleaved
            t, (preds["action"], _) = _timed(
                lambda: replay_actions(logs.envs, logs.seeds, logs.full, logs.act, logs.offsets, seg_a, logs.idx)
            )
            best["action"] = min(best["action"], t)
            t, (preds["mj_step"], _) = _timed(lambda: mj_step_loop(logs, seg_c))
            best["mj_step"] = min(best["mj_step"], t)
            for n in threads:
                t, (preds[n], _) = _timed(
                    lambda n=n: replay_ctrl(
                        n, logs.envs, logs.full, logs.ctrl, logs.offsets, seg_c, logs.substeps, logs.idx, logs.ctrl_spec
                    )
                )
                best[n] = min(best[n], t)
        m = logs.envs[0].model
        floor = physics_floor(m, logs.ctrl[0, : m.nu])
    finally:
        logs.close()
    sub = logs.substeps
    print(
        f"\nsuite: held_out_robots Panda Lift, {n_eps} scripted episodes x {horizon} frames recorded in "
        f"{t_record:.1f} s; {sub} physics steps/frame (dt {m.opt.timestep * 1e3:g} ms), k = {k}; frames replayed "
        f"over the three horizons: action loop {fr_a:,}, ctrl {fr_c:,}; best of {repeats}"
    )
    per = {"action": best["action"] / fr_a, "mj_step": best["mj_step"] / fr_c, **{n: best[n] / fr_c for n in threads}}
    print(f"  action loop (env.step, OSC in Python)  {best['action']:7.2f} s   {per['action'] * 1e3:6.3f} ms/frame")
    print(f"  mj_step loop (logged ctrl)             {best['mj_step']:7.2f} s   {per['mj_step'] * 1e3:6.3f} ms/frame")
    for n in threads:
        print(
            f"  mujoco.rollout, {n} thread{'s' if n > 1 else ' '} (logged ctrl)  {best[n]:7.2f} s   "
            f"{per[n] * 1e3:6.3f} ms/frame   speed-up x{per['action'] / per[n]:5.1f} over the action loop, "
            f"x{per['mj_step'] / per[n]:4.2f} over the mj_step loop"
        )
    diff = max(float(np.abs(preds[n][h] - preds["mj_step"][h]).max()) for n in threads for h in seg_c)
    same = max(float(np.abs(preds[threads[0]][h] - preds["action"][h]).max()) for h in ("one_step", "free_run"))
    cores = os.cpu_count() or 1
    print(
        f"  max |qpos difference|: batched vs mj_step loop {diff:.1e}; batched vs action loop (one-step, free "
        f"run; nominal logs) {same:.1e}"
    )
    print(
        f"  physics alone: {floor * 1e6:.1f} us/step = {floor * sub * 1e3:.3f} ms/frame -> on {cores} cores the "
        f"ceiling over the mj_step loop is x{per['mj_step'] / (floor * sub / cores):.1f}, over the action loop "
        f"x{per['action'] / (floor * sub / cores):.1f}"
    )


def physics_floor(model, ctrl: np.ndarray, steps: int = 20_000) -> float:
    """Seconds per step of the physics alone: one `mj_step(nstep=...)` C call, no Python per step."""
    d = mujoco.MjData(model)
    d.ctrl[:] = ctrl
    best = float("inf")
    for _ in range(3):
        mujoco.mj_resetData(model, d)
        d.ctrl[:] = ctrl
        t0 = time.perf_counter()
        mujoco.mj_step(model, d, nstep=steps)
        best = min(best, time.perf_counter() - t0)
    return best / steps


@dataclass(frozen=True)
class Args:
    """Keys of this benchmark (key=value)."""

    case: str = "both"  # both | arm | suite
    k: int = 10  # k-step horizon (frames)
    repeats: int = 5  # best of this many timings
    threads: list[int] = field(default_factory=lambda: [1, 2])  # rollout thread counts to time
    episodes: int = 8  # arm case: episodes
    duration: float = 6.0  # arm case: seconds per episode
    fps: float = 100.0  # arm case: log rate
    suite_episodes: int = 6  # suite case: recorded held_out_robots episodes
    horizon: int = 100  # suite case: steps per episode


def main(argv: list[str]) -> int:
    from bench.core.config import build_from_argv

    args: Args = build_from_argv(Args, argv, "python benchmarks/bench_replay.py")
    if args.case not in ("both", "arm", "suite"):
        print(f"error: case is {args.case!r}; valid: both, arm, suite", file=sys.stderr)
        return 2
    if args.case in ("both", "arm"):
        arm_case(args, args.k, args.repeats, list(args.threads))
    if args.case in ("both", "suite"):
        suite_case(args, args.k, args.repeats, list(args.threads))
    return 0


def arm_case(args: Args, k: int, repeats: int, threads: list[int]) -> None:
    episodes, duration, fps = args.episodes, args.duration, args.fps

    eps, _ = simulate_arm(None, episodes=episodes, duration=duration, fps=fps, seed=0)
    spec = SignalMap(**map_fields(spec_dict(None, model_file=str(ARM)), "."))
    model = load_model(spec.model)
    rec = extract(spec, eps, fps, nq=model.nq, nv=model.nv, nu=model.nu)
    model, substeps = prepare_model(model, fps, spec.substeps)
    variant = as_given(model, rec, substeps)
    windows = rec.episodes()
    segments = horizon_segments(rec, windows, k)
    nseg = {h: len(s) for h, s in segments.items()}
    print(
        f"arm3 (3 hinge joints), {episodes} episodes x {duration:g} s at {fps:g} Hz = {len(rec.qpos)} frames, "
        f"{substeps} substeps/frame (dt {model.opt.timestep * 1e3:g} ms), k = {k}; "
        f"segments: {nseg}; mujoco {mujoco.__version__}; best of {repeats}"
    )

    sims = {n: Simulator(model, rec, substeps, n) for n in threads}
    best = {key: float("inf") for key in ["loop", *threads]}
    try:
        for _ in range(repeats):  # interleaved, so load from other processes hits both sides alike
            t, (ref, steps) = _timed(lambda: step_loop(model, rec, substeps, segments))
            best["loop"] = min(best["loop"], t)
            for n, sim in sims.items():
                t, errors = _timed(lambda sim=sim: horizon_errors(sim, variant, rec, windows, k))
                best[n] = min(best[n], t)
    finally:
        for sim in sims.values():
            sim.close()
    t_loop = best["loop"]
    print(f"  python mj_step loop      {t_loop:8.3f} s   {steps:,} steps   {t_loop / steps * 1e6:6.2f} us/step")
    diff = max(float(np.abs(errors[h].pred[errors[h].mask] - ref[h][errors[h].mask]).max()) for h in errors)
    for n in threads:
        t_batch = best[n]
        print(
            f"  mujoco.rollout, {n} thread{'s' if n > 1 else ' '} {t_batch:8.3f} s   {steps:,} steps   "
            f"{t_batch / steps * 1e6:6.2f} us/step   speed-up x{t_loop / t_batch:5.2f}"
        )
    print(f"  max |qpos difference| between the two: {diff:.1e} rad (all segments of all three horizons)")
    floor, cores = physics_floor(model, rec.ctrl[0], 100_000), os.cpu_count() or 1
    print(
        f"  physics alone (mj_step nstep, one C call): {floor * 1e6:.2f} us/step -> on {cores} "
        f"core{'s' if cores > 1 else ''} "
        f"no batching can beat {floor / cores * 1e6:.2f} us/step: ceiling of the speed-up "
        f"x{t_loop / steps / (floor / cores):.1f} (x{t_loop / steps / floor:.1f} per core)"
    )


if __name__ == "__main__":
    from bench.core.guard import guarded  # bad keys: one line, exit 2, as bench's commands

    raise SystemExit(guarded(lambda: main(sys.argv[1:])))
