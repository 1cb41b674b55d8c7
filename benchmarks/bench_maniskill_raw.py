"""Harness ÷ a bare ManiSkill step loop on the same task, measured in one run (CPU, no renderer).

    python benchmarks/bench_maniskill_raw.py [task=PickCube] [episodes=8] [horizon=100] [seed=0] [reset=both]

Bare loop: `gym.make("<task>-v1", obs_mode="state", control_mode="pd_joint_pos",
sim_backend="physx_cpu", render_backend="none", reward_mode=<the task's>)`, then `env.reset(seed=s)`
and `env.step(action)` in a Python loop, as a ManiSkill user writes it. Harness: the runner's
per-episode path on suite=maniskill_tasks (`bench.api.worker(plan).run(job)`: perturbation
dispatch, policy, adapter, non-finite checks, success, the record written, flushed and fsynced).
Both get the same seeds and the same action sequences (the random policy's, which depend only on
the episode seed); episodes alternate harness / bare so load drifts hit both alike, both are warmed
up first. Measured for both of the suites'
reset modes (`reset=both`, or one of them): `soft` is ManiSkill's own reset, as in the bare loop;
`rebuild` (the default) also rebuilds the PhysX scene every episode so that the same seed and
actions give the same trajectory whatever ran before, which the bare loop does not do.
Prints env-steps/s of both and their ratio (target >= 0.95).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def main(argv: list[str]) -> int:
    opts = dict(a.split("=", 1) for a in argv)
    modes = ("soft", "rebuild") if opts.get("reset", "both") == "both" else (opts["reset"],)
    for mode in modes:
        measure(
            opts.get("task", "PickCube"),
            int(opts.get("episodes", 8)),
            int(opts.get("horizon", 100)),
            int(opts.get("seed", 0)),
            mode,
        )
    return 0


def measure(task: str, episodes: int, horizon: int, seed: int, mode: str) -> None:
    import gymnasium as gym

    from bench import api
    from bench.perf import PerfConfig, make_plan
    from bench.records import RecordWriter
    from bench.sim_maniskill import reward_mode
    from suites.maniskill_common import TASKS

    p = make_plan(
        PerfConfig(suite="maniskill_tasks", task=task, episodes=episodes, horizon=horizon, seed=seed),
        episodes,
        {"reset": mode},
    )
    worker = api.worker(p)
    env, policy = worker.built(p.jobs[0])  # the adapter (and, in this process, the SAPIEN stand-ins if needed)
    env_id = TASKS[task].env_id
    raw = gym.make(
        env_id,
        robot_uids=p.cells[0].robot,
        obs_mode="state",
        control_mode="pd_joint_pos",
        sim_backend="physx_cpu",
        render_backend="none",
        reward_mode=reward_mode(env_id),
    )
    actions = []
    for job in p.jobs:
        policy.reset(job.seed)
        actions.append(np.stack([policy.act({}) for _ in range(p.horizon)]))  # random: ignores the observation
    worker.run(p.jobs[0])  # warm-up both
    raw.reset(seed=p.jobs[0].seed)
    for a in actions[0][:20]:
        raw.step(a)
    harness_s = bare_s = 0.0
    steps = bare_steps = 0
    try:
        with tempfile.TemporaryDirectory() as tmp, RecordWriter(Path(tmp) / "e.jsonl") as writer:
            for job, acts in zip(p.jobs, actions):
                t0 = time.perf_counter()
                rec = worker.run(job)
                writer.write(rec)
                harness_s += time.perf_counter() - t0
                steps += rec.length
                t0 = time.perf_counter()
                raw.reset(seed=job.seed)
                for a in acts[: rec.length]:
                    raw.step(a)
                bare_s += time.perf_counter() - t0
                bare_steps += rec.length
    finally:
        worker.close()
        raw.close()
    h, b = steps / harness_s, bare_steps / bare_s
    print(
        f"{env_id} on physx_cpu, {episodes} episodes x {p.horizon} steps, random actions (pd_joint_pos), "
        f"renderer: {getattr(env, 'render', '?')}, suite reset={mode}"
    )
    print(f"  harness {h:.0f} env-steps/s, bare ManiSkill loop {b:.0f} env-steps/s: harness / bare = {h / b:.3f}")


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
