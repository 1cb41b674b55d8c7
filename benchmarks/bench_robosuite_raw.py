"""Harness throughput against bare robosuite (`robosuite.make` + soft reset + `env.step`), in one run.

    python benchmarks/bench_robosuite_raw.py [robot=Panda] [episodes=8] [horizon=250] [seed=0]

The same arm, seeds and action sequences (the random policy's, which depend only on the episode
seed); episodes alternate harness / raw so that drifts in machine speed hit both alike; both time
steady state (envs built and warmed first). Harness = `bench.api.worker` running one episode
(agnostic observation, policy, perturbation wrapper, non-finite checks, record written and
fsynced); raw = robosuite alone. `bench perf` measures the same against the suite's own env
adapter, for any suite.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def main(argv: list[str]) -> int:
    from bench import api
    from bench.records import RecordWriter
    from bench.sim_robosuite import _quiet_robosuite

    kv = dict(a.split("=", 1) for a in argv)
    robot, episodes = kv.get("robot", "Panda"), int(kv.get("episodes", 8))
    horizon, seed = int(kv.get("horizon", 250)), int(kv.get("seed", 0))
    plan = api.plan(
        api.RunConfig(
            suite="held_out_robots",
            policy="random",
            robots=[robot],
            episodes=episodes,
            seed=seed,
            horizon=horizon,
            out=tempfile.gettempdir(),
            run_id="raw-bench",
        )
    )
    worker = api.worker(plan)
    env, policy = worker.built(plan.jobs[0])
    actions = []
    for job in plan.jobs:
        policy.reset(job.seed)
        actions.append(np.stack([policy.act(None) for _ in range(horizon)]).astype(np.float64))
    _quiet_robosuite()
    import robosuite

    from bench.sim_robosuite import MAKE_OPTIONS

    raw = robosuite.make("Lift", robots=robot, horizon=horizon, **MAKE_OPTIONS)
    worker.run(plan.jobs[0])
    raw.reset()
    for a in actions[0][:20]:
        raw.step(a)
    harness_s = raw_s = 0.0
    steps = raw_steps = 0
    with tempfile.TemporaryDirectory() as tmp, RecordWriter(Path(tmp) / "e.jsonl") as writer:
        for job, acts in zip(plan.jobs, actions):
            t0 = time.perf_counter()
            rec = worker.run(job)
            writer.write(rec)
            harness_s += time.perf_counter() - t0
            steps += rec.length
            t0 = time.perf_counter()
            raw.rng = np.random.default_rng(job.seed)
            raw.placement_initializer.rng = raw.rng
            raw.reset()
            for a in acts:
                raw.step(a)
            raw_s += time.perf_counter() - t0
            raw_steps += len(acts)
    worker.close()
    raw.close()
    h, r = steps / harness_s, raw_steps / raw_s
    print(f"robosuite Lift/{robot}, {episodes} episodes x {horizon} steps, random policy")
    print(f"harness {h:.1f} env-steps/s, raw robosuite {r:.1f} env-steps/s: harness / raw = {h / r:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
