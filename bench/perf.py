"""`bench perf`: harness throughput against raw robosuite stepping, measured in one run.

Two ratios, both printed with their raw figures:

1. harness ÷ raw, one process: the same env (Lift on one arm), the same seeds and the
   same action sequences (the random policy's, which depend only on the episode seed);
   raw = `robosuite.make(...)` + soft reset + `env.step` in a bare loop; harness = the
   runner's serial path (policy, agnostic observation, success check, record written,
   flushed and fsynced). Both time steady state: each env is built and warmed first.
2. 2 workers ÷ 1 worker: `bench.runner.execute` on the same jobs, reported in steady
   state (each worker's steps over its episodes' wall time, summed over workers) and end
   to end (worker start-up and env builds included: what a short run gets).
"""
from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import config as config_mod
from bench.errors import ConfigError


def _jobs(suite, robot: str, episodes: int, seed: int):
    from bench.run import RunConfig
    from bench.suite import NOMINAL

    cfg = config_mod.build(RunConfig, [f"robots=[{robot}]", f"episodes={episodes}", f"seed={seed}", "policy=random"])
    return cfg, suite.jobs(cfg, [NOMINAL])


def _ctx(suite, horizon: int):
    from bench.provenance import package_versions
    from bench.rollout import RunContext

    return RunContext(run_id="perf", suite_version=suite.version, policy_id="random", checkpoint_sha256=None,
                      versions=package_versions(), horizon=horizon, timeout_s=0)


def harness_vs_raw(robot: str, episodes: int, horizon: int, seed: int) -> dict:
    """Steps/s of the harness's serial path and of bare robosuite on identical work."""
    from baselines.random_policy import RandomPolicy
    from bench import registry, runner
    from bench.records import RecordWriter
    from bench.sim_robosuite import _quiet_robosuite

    suite = registry.make_suite("held_out_robots")
    cfg, jobs = _jobs(suite, robot, episodes, seed)
    ctx = _ctx(suite, horizon)

    # both envs built and warmed first; then episodes alternate harness / raw so that drifts in
    # machine speed (other processes, frequency) hit both sides alike
    runner._init_worker("held_out_robots", "random", cfg, ctx)
    runner._run_job(jobs[0])
    env = runner._W["cache"][jobs[0].cell.key][0]
    _quiet_robosuite()
    import robosuite

    raw = robosuite.make("Lift", robots=robot, has_renderer=False, has_offscreen_renderer=False,
                         use_camera_obs=False, hard_reset=False, ignore_done=True, reward_shaping=True,
                         horizon=horizon, seed=0)
    policy = RandomPolicy(env.action_low, env.action_high)
    actions = []
    for job in jobs:  # the random policy's actions depend only on the episode seed
        policy.reset(job.seed)
        actions.append(np.stack([policy.act(None) for _ in range(horizon)]).astype(np.float64))
    raw.reset()
    for a in actions[0][:20]:
        raw.step(a)  # warm-up
    harness_s = raw_s = 0.0
    steps = raw_steps = 0
    with tempfile.TemporaryDirectory() as tmp, RecordWriter(Path(tmp) / "e.jsonl") as writer:
        for job, acts in zip(jobs, actions):
            t0 = time.perf_counter()
            rec = runner._run_job(job)
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
    runner._close_cache()
    raw.close()
    return {"harness_steps_per_s": steps / harness_s, "raw_steps_per_s": raw_steps / raw_s,
            "ratio": (steps / harness_s) / (raw_steps / raw_s), "steps": steps}


def workers_scaling(robot: str, episodes: int, horizon: int, seed: int, workers: int) -> dict:
    """Env-steps/s with 1 worker and with `workers` workers on the same jobs, two ways.

    end to end: all steps / wall time of `execute`, worker start-up (spawn, imports, env
    builds) included. steady state: for each worker process, its steps / the wall time of its
    episodes (from the records), summed over the workers that ran at the same time.
    """
    from bench import registry
    from bench.runner import execute

    suite = registry.make_suite("held_out_robots")
    cfg, jobs = _jobs(suite, robot, episodes, seed)
    ctx = _ctx(suite, horizon)
    out = {}
    for w in (1, workers):
        records = []
        t0 = time.perf_counter()
        execute(jobs, suite_name="held_out_robots", policy_name="random", cfg=cfg, ctx=ctx, workers=w,
                on_record=records.append)
        wall = time.perf_counter() - t0
        per_pid: dict[int, list[float]] = {}
        for r in records:
            acc = per_pid.setdefault(r.worker_pid, [0.0, 0.0])
            acc[0] += r.length
            acc[1] += r.wall_s
        out[w] = {"end_to_end": sum(r.length for r in records) / wall,
                  "steady": sum(steps / secs for steps, secs in per_pid.values())}
    return {"one": out[1], "many": out[workers],
            "ratio_end_to_end": out[workers]["end_to_end"] / out[1]["end_to_end"],
            "ratio_steady": out[workers]["steady"] / out[1]["steady"]}


def main(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        print("usage: bench perf [robot=Panda] [episodes=8] [horizon=250] [seed=0] [workers=2] [scaling_episodes=40]\n\n"
              + __doc__)
        return 0
    from bench.config import parse_kv

    positional, kv = parse_kv(argv)
    allowed = {"robot", "episodes", "horizon", "seed", "workers", "scaling_episodes"}
    bad = [k for k in kv if k not in allowed] + positional
    if bad:
        raise ConfigError(f"perf: unknown argument {bad[0]!r}; valid keys: {', '.join(sorted(allowed))}")
    robot = str(kv.get("robot", "Panda"))
    episodes, horizon = int(kv.get("episodes", 8)), int(kv.get("horizon", 250))
    seed, workers = int(kv.get("seed", 0)), int(kv.get("workers", 2))
    scaling_episodes = int(kv.get("scaling_episodes", 40))
    print(f"machine: {os.cpu_count()} cores; robosuite Lift/{robot}, horizon {horizon}, random policy")
    a = harness_vs_raw(robot, episodes, horizon, seed)
    print(f"harness {a['harness_steps_per_s']:.1f} env-steps/s, raw robosuite {a['raw_steps_per_s']:.1f} env-steps/s "
          f"({a['steps']} steps each): harness / raw = {a['ratio']:.3f}  (target >= 0.97)")
    b = workers_scaling(robot, scaling_episodes, horizon, seed, workers)
    print(f"steady state: 1 worker {b['one']['steady']:.1f} env-steps/s, {workers} workers {b['many']['steady']:.1f} "
          f"env-steps/s: {workers} / 1 = {b['ratio_steady']:.3f}  (target >= 1.8 on 2 cores)")
    print(f"end to end ({scaling_episodes} episodes, worker start-up and env builds included): 1 worker "
          f"{b['one']['end_to_end']:.1f}, {workers} workers {b['many']['end_to_end']:.1f} env-steps/s: "
          f"{workers} / 1 = {b['ratio_end_to_end']:.3f}")
    return 0
