"""`bench perf`: harness throughput against a bare loop over the same env, measured in one run.

Works on any suite (one cell, the random policy, whose actions depend only on the episode seed):

1. harness ÷ bare loop, one process: the same env object, the same seeds and the same action
   sequences. Bare loop = `env.reset(seed)` + `env.step(action)` in a Python loop (the env
   adapter and simulator alone); harness = the runner's path per episode (policy, perturbation
   wrapper, non-finite checks, success, record written, flushed and fsynced). Episodes alternate
   harness / bare so drifts in machine speed hit both alike, and which side goes first alternates
   too (the second episode of a pair runs faster); both time steady state (env built and warmed first).
2. N workers ÷ 1 worker on the same jobs, in steady state (each worker's steps over its episodes'
   wall time, summed over workers) and end to end (worker start-up and env builds included: what
   a short run gets). N workers = this process and N-1 children; this process runs episodes from
   the start while the children spawn, import and build (bench.execution.local.LocalExecutor). Also
   printed: the share of the workers' wall time spent inside episodes (end to end ÷ steady
   state, roughly), which other load on the machine changes much less than the throughputs.
3. `vector=[1,8,32]`: env-steps/s of one worker stepping N envs of the cell in lockstep (`bench run vector=N`),
   its policy (`vector_policy=`, default the packaged torch BC checkpoint, which answers a batch in one
   forward pass) asked once per step for all of them, and each N's ratio to the first: the same episodes
   for every N, every env built before the timing, the sizes' order alternating between two rounds.
4. With cameras (`obs=rgb` or `obs=state+rgb`, suites built on `bench.sims.camera_env`): the cost of
   rendering one frame of each camera (ms, median over frames of a reset/step sequence), the
   harness ÷ bare loop ratio of 1. where both render the cameras every step (the bare loop steps
   the same camera-wrapped env), and the cost of `video=N` (the harness with every episode filmed
   ÷ without, same episodes).

`benchmarks/bench_robosuite_raw.py` compares against bare robosuite (`robosuite.make` + step).
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray

from bench.api import Plan, RunConfig, RunContext, context, plan
from bench.api import worker as api_worker
from bench.core import outputs
from bench.core.errors import ConfigError
from bench.core.io import write_atomic
from bench.execution.local import LocalExecutor
from bench.execution.run_config import MAX_VECTOR
from bench.protocols import batchable
from bench.records import EpisodeRecord, RecordWriter
from bench.sims.camera import SCENE_FLAGS

__all__ = [
    "SCENE_FLAGS",
    "SCHEMA_ID",
    "PerfConfig",
    "PerfResult",
    "harness_vs_bare",
    "make_plan",
    "per_worker",
    "perf",
    "render_cost",
    "steady_rate",
    "vector_gain",
    "video_overhead",
    "workers_scaling",
]

SCHEMA_ID = "bench.perf/1"


@dataclass(frozen=True)
class PerfConfig:
    """Keys of `bench perf`."""

    suite: str = "held_out_robots"  # suite (registered or package.module:Class)
    robot: Optional[str] = None  # the cell's robot (default: the suite's first cell)
    task: Optional[str] = None  # the cell's task
    env: Optional[str] = None  # the cell's env
    episodes: int = 8  # episodes for harness ÷ bare loop
    horizon: int = 0  # control steps per episode (0 = the suite's default)
    seed: int = 0  # run seed
    workers: int = 2  # workers for the scaling measurement
    scaling_episodes: int = 40  # episodes for the scaling measurement (0 = skip it)
    obs: str = "state"  # state | rgb | state+rgb: measure with camera images (suites with cameras)
    cameras: Optional[list[str]] = None  # cameras to render (default: the suite's)
    image_size: int = 128  # image height and width in pixels
    video: bool = True  # with cameras: also measure the cost of filming every episode (video=N)
    vector: Optional[list[int]] = None  # env counts to time vectorised episodes at, e.g. [1,8,32] (none: skip)
    vector_policy: str = "bc"  # the policy of the vector measurement (bc: the packaged torch checkpoint)
    out: Optional[str] = None  # also write the measurements as JSON (schema bench.perf/1) to this new file


def make_plan(
    cfg: PerfConfig, episodes: int, suite_options: dict[str, Any] | None = None, policy: str = "random"
) -> Plan:
    """A plan of one cell (the random policy unless told); nothing is written (its run directory is never made:
    the episodes are timed in this process and their records go to a private temporary file)."""
    scratch = tempfile.mkdtemp(prefix="bench-perf-")  # new and empty: whatever the temporary folder holds
    try:
        return _one_cell(cfg, episodes, suite_options, scratch, policy)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _one_cell(cfg: PerfConfig, episodes: int, suite_options: dict[str, Any] | None, scratch: str, policy: str) -> Plan:
    run = RunConfig(
        suite=cfg.suite,
        policy=policy,
        episodes=episodes,
        seed=cfg.seed,
        horizon=cfg.horizon,
        out=scratch,
        run_id="perf",
        suite_options=dict(suite_options or {}),
        robots=[cfg.robot] if cfg.robot else None,
        tasks=[cfg.task] if cfg.task else None,
        envs=[cfg.env] if cfg.env else None,
    )
    p = plan(run)
    first = p.cells[0]
    return dataclasses.replace(p, cells=[first], jobs=[j for j in p.jobs if j.cell == first])


def harness_vs_bare(p: Plan, ctx: RunContext | None = None, bare: Callable[[], Any] | None = None) -> dict[str, float]:
    """Steps/s of the harness's per-episode path and of a bare loop over the same seeds and actions.

    The bare loop drives the suite's own env adapter (`bench perf`), or, given `bare`, what that
    factory returns (the simulator alone, benchmarks/bench_*_raw.py): anything with `reset(seed)`,
    `step(action)` and `close()`, made after the harness's env (which may prepare the process, e.g.
    ManiSkill's stand-ins for a missing renderer) and closed at the end.
    """
    worker = api_worker(p, ctx)
    jobs = p.jobs
    env, policy = worker.built(jobs[0])
    own = bare() if bare is not None else None
    env = env if own is None else own
    actions: list[NDArray[np.float64]] = []
    for job in jobs:  # the random policy's actions depend only on the episode seed
        policy.reset(job.seed)
        actions.append(np.stack([policy.act({}) for _ in range(p.horizon)]))
    worker.run(jobs[0])  # warm-up: env built, caches filled
    env.reset(jobs[0].seed)
    for a in actions[0][:20]:
        env.step(a)
    harness_s = bare_s = 0.0
    steps = bare_steps = 0
    try:
        with tempfile.TemporaryDirectory() as tmp, RecordWriter(Path(tmp) / "e.jsonl") as writer:
            for i, (job, acts) in enumerate(zip(jobs, actions)):
                # the second episode of a pair runs measurably faster (10-30 % with cameras on): alternate the order
                for side in ("harness", "bare") if i % 2 == 0 else ("bare", "harness"):
                    t0 = time.perf_counter()
                    if side == "harness":
                        rec = worker.run(job)
                        writer.write(rec)
                        harness_s += time.perf_counter() - t0
                        steps += rec.length
                    else:
                        env.reset(job.seed)
                        for a in acts:
                            env.step(a)
                        bare_s += time.perf_counter() - t0
                        bare_steps += len(acts)
    finally:
        worker.close()
        if own is not None:
            own.close()
    return {
        "harness_steps_per_s": steps / harness_s,
        "bare_steps_per_s": bare_steps / bare_s,
        "ratio": (steps / harness_s) / (bare_steps / bare_s),
        "steps": steps,
    }


def per_worker(records: list[EpisodeRecord]) -> dict[int, tuple[int, float]]:
    """Per worker process: the env steps its episodes took and the seconds they ran (`wall_s`)."""
    out: dict[int, tuple[int, float]] = {}
    for r in records:
        steps, secs = out.get(r.worker_pid, (0, 0.0))
        out[r.worker_pid] = (steps + r.length, secs + r.wall_s)
    return out


def steady_rate(per_pid: dict[int, tuple[int, float]]) -> float:
    """Steady-state throughput: the sum over workers of their own steps per second while running episodes."""
    return sum(steps / secs for steps, secs in per_pid.values() if secs > 0)


def workers_scaling(p: Plan, workers: int) -> dict[str, Any]:
    """Env-steps/s with 1 worker and with `workers` workers on the same jobs, two ways.

    end to end: all steps / wall time of the executor, worker start-up (spawn, imports, env
    builds) included. steady state: for each worker process, its steps / the wall time of its
    episodes (from the records), summed over the workers.
    """
    spec = p.worker_spec(context(p))
    out: dict[int, dict[str, float]] = {}
    for w in (1, workers):
        records: list[EpisodeRecord] = []
        t0 = time.perf_counter()
        LocalExecutor(w).execute(p.jobs, spec, records.append)
        wall = time.perf_counter() - t0
        per_pid = per_worker(records)
        out[w] = {
            "end_to_end": sum(r.length for r in records) / wall,
            "steady": steady_rate(per_pid),
            "busy": sum(secs for _, secs in per_pid.values()) / (w * wall),
            "wall": wall,
        }
    return {
        "one": out[1],
        "many": out[workers],
        "ratio_end_to_end": out[workers]["end_to_end"] / out[1]["end_to_end"],
        "ratio_steady": out[workers]["steady"] / out[1]["steady"],
    }


def vector_gain(p: Plan, sizes: list[int], rounds: int = 2) -> dict[str, Any]:
    """Env-steps/s of one worker running the plan's episodes N at a time in lockstep (`Worker.run_vector`), per N.

    The same episodes for every N (the plan's, one cell and condition), every slot's env and policy built and
    warmed first (a run at max(sizes)), then `rounds` passes over the sizes, the order reversed every other pass
    so a drift in machine speed hits all alike. `ratio`: each N's rate over the first size's.
    `policy_ms_per_step`: the policy's answers per env-step at each N (`_policy_ms`), which bounds what batching
    can save.
    """
    worker = api_worker(p)
    jobs = p.jobs
    secs = dict.fromkeys(sizes, 0.0)
    steps = dict.fromkeys(sizes, 0)
    try:
        worker.run_vector(jobs[: max(sizes)])  # warm-up: every slot built
        for r in range(rounds):
            for n in sizes if r % 2 == 0 else sizes[::-1]:
                for i in range(0, len(jobs), n):
                    t0 = time.perf_counter()
                    records = worker.run_vector(jobs[i : i + n])
                    secs[n] += time.perf_counter() - t0
                    steps[n] += sum(rec.length for rec in records)
        policy_ms = _policy_ms(worker, jobs[: max(sizes)], sizes)
    finally:
        worker.close()
    rates = {n: steps[n] / secs[n] for n in sizes}
    return {
        "policy": str(p.config.policy),
        "episodes": len(jobs),
        "steps_per_s": {str(n): rates[n] for n in sizes},
        "ratio": {str(n): rates[n] / rates[sizes[0]] for n in sizes},
        "policy_ms_per_step": {str(n): policy_ms[n] for n in sizes},
    }


def _policy_ms(worker: Any, jobs: list[Any], sizes: list[int], repeats: int = 50) -> dict[int, float]:
    """Milliseconds of policy answers per env-step when N envs are answered together (`act_batch` for a policy
    that declares batches, else `act` per env), on the first observations of the jobs' episodes."""
    policies = [worker.built(job, slot)[1] for slot, job in enumerate(jobs)]
    obs = [worker.built(job, slot)[0].reset(job.seed) for slot, job in enumerate(jobs)]
    out: dict[int, float] = {}
    for n in sizes:
        t0 = time.perf_counter()
        for _ in range(repeats):
            for i in range(0, len(obs), n):
                if n > 1 and batchable(policies[i]):
                    policies[i].act_batch(obs[i : i + n])
                else:
                    for k in range(i, min(i + n, len(obs))):
                        policies[k].act(obs[k])
        out[n] = (time.perf_counter() - t0) / (repeats * len(obs)) * 1e3
    return out


def render_cost(p: Plan, frames: int = 30) -> dict[str, float]:
    """Median ms to render one frame of each camera of the plan's first cell (states of a random rollout)."""
    worker = api_worker(p)
    env, policy = worker.built(p.jobs[0])
    assert env.mujoco is not None, "camera observations come from a MuJoCo env"
    rig = env.mujoco.cameras
    out: dict[str, list[float]] = {c: [] for c in rig.cameras}
    try:
        obs = env.reset(p.jobs[0].seed)
        policy.reset(p.jobs[0].seed)
        for _ in range(frames):
            obs = env.step(policy.act(obs))[0]
            for cam in rig.cameras:
                t0 = time.perf_counter()
                rig.render_one(cam)
                out[cam].append(time.perf_counter() - t0)
    finally:
        worker.close()
    return {c: float(np.median(v[3:])) * 1e3 for c, v in out.items()}  # first frames warm the GL caches


def video_overhead(p: Plan) -> dict[str, float]:
    """Harness steps/s with every episode filmed (video=N) and without, same episodes, alternating."""
    with tempfile.TemporaryDirectory() as tmp:
        plain = context(p)
        filmed = dataclasses.replace(plain, video_dir=tmp, video_episodes=len(p.jobs))
        workers = {"plain": api_worker(p, plain), "video": api_worker(p, filmed)}
        secs = {"plain": 0.0, "video": 0.0}
        steps = {"plain": 0, "video": 0}
        try:
            for w in workers.values():
                w.run(p.jobs[0])  # warm-up
            for i, job in enumerate(p.jobs):
                for name in ("plain", "video") if i % 2 == 0 else ("video", "plain"):  # alternate who goes first
                    w = workers[name]
                    t0 = time.perf_counter()
                    rec = w.run(job)
                    secs[name] += time.perf_counter() - t0
                    steps[name] += rec.length
        finally:
            for w in workers.values():
                w.close()
    plain_rate, video_rate = steps["plain"] / secs["plain"], steps["video"] / secs["video"]
    return {"plain_steps_per_s": plain_rate, "video_steps_per_s": video_rate, "wall_ratio": plain_rate / video_rate}


def _loadavg() -> list[float] | None:
    """The machine's load averages (1, 5, 15 min) while measuring: other load changes every ratio."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


@dataclass(frozen=True)
class PerfResult:
    """The measurements (schema bench.perf/1) and the file they were written to (None: no out=)."""

    doc: dict[str, Any]
    path: Path | None


def perf(cfg: PerfConfig, on_step: Callable[[str, dict[str, Any]], None] | None = None) -> PerfResult:
    """The measurements of `bench perf` (schema bench.perf/1), also written to `cfg.out` (a new .json file).

    `on_step(stage, doc)` is called as each measurement is done, with the document so far: "start" (the suite,
    cell and horizon), then "render_ms" (with cameras), "harness_vs_bare", "video" (with cameras and video=true),
    "vector" (vector=[...]) and "scaling" (scaling_episodes > 0); `bench perf` prints a line for each.
    """
    step = on_step or (lambda _stage, _doc: None)
    for key in ("episodes", "workers"):
        if not 1 <= getattr(cfg, key) <= 10_000:
            raise ConfigError(f"{key}={getattr(cfg, key)}: must be in [1, 10000]")
    if not 0 <= cfg.scaling_episodes <= 10_000:
        raise ConfigError(f"scaling_episodes={cfg.scaling_episodes}: must be in [0, 10000]")
    out = outputs.check("out", cfg.out, {}, kind="file", can_overwrite=False) if cfg.out else None
    sizes = list(cfg.vector or [])
    if any(not 1 <= n <= MAX_VECTOR for n in sizes) or len(set(sizes)) != len(sizes):
        raise ConfigError(f"vector={sizes}: give distinct env counts in [1, {MAX_VECTOR}], e.g. [1,8,32]")
    if out is not None and out.suffix != ".json":
        raise ConfigError(f"out={cfg.out!r}: the measurements are written as JSON; give a file name ending in .json")
    cams = {"obs": cfg.obs, "image_size": cfg.image_size, **({"cameras": cfg.cameras} if cfg.cameras else {})}
    options = cams if cfg.obs != "state" else {}
    p = make_plan(cfg, cfg.episodes, options)
    doc: dict[str, Any] = {
        "schema": SCHEMA_ID,
        "config": dataclasses.asdict(cfg),
        "machine": {"cores": os.cpu_count(), "loadavg": _loadavg()},
        "suite": p.suite.name,
        "cell": p.cells[0].key,
        "horizon": p.horizon,
    }
    step("start", doc)
    if options:
        doc["render_ms"] = render_cost(p)
        step("render_ms", doc)
    doc["harness_vs_bare"] = harness_vs_bare(p)
    step("harness_vs_bare", doc)
    if options and cfg.video:
        doc["video"] = video_overhead(p)
        step("video", doc)
    if sizes:
        doc["vector"] = vector_gain(make_plan(cfg, max(sizes), options, cfg.vector_policy), sizes)
        step("vector", doc)
    if cfg.scaling_episodes:
        b = workers_scaling(make_plan(cfg, cfg.scaling_episodes, options), cfg.workers)
        doc["scaling"] = {"workers": cfg.workers, **b}
        step("scaling", doc)
    if out is not None:
        write_atomic(out, doc)
    return PerfResult(doc, out)
