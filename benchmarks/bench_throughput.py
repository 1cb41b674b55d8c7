"""Throughput per core, every figure a ratio measured in this one run (issue 29).

    python benchmarks/bench_throughput.py [parts=[fast,workers,remote,batch]] [episodes=6] [horizon=250]
        [scaling_episodes=12] [repeats=1] [suite_policy=] [profile=false]   (parts: fast, workers, suite, remote, batch)

Parts (each printed with the machine's load, /proc/loadavg, before and after):
  fast     held_out_robots, random policy, Panda: the harness on bench's robosuite fast path ÷ a bare
           robosuite loop (`robosuite.make` + soft reset + `env.step`, nothing else), episodes
           interleaved (`bench.api.throughput.harness_vs_bare`), and the same with `fast_path=false` as a
           control; then the fast path ÷ robosuite's `env.step` at the adapter, per arm (all 7), with
           the records' equality checked on the way. `profile=true` adds where a step's time goes,
           by cProfile, with and without the fast path.
  workers  held_out_robots (Panda, random policy, `scaling_episodes` episodes): 2 workers ÷ 1, end to end
           (worker start-up, imports and env builds included) and in steady state (`bench.api.throughput`).
  suite    the main job as a command, `bench run suite=held_out_robots episodes=<scaling_episodes>`
           (all 7 arms, the default policy bc, or `suite_policy=`, e.g. scripted) with workers=1 and
           workers=2, alternating `repeats` times (default 1): wall time from the command's start to its
           exit, 2 workers ÷ 1.
  remote   see benchmarks/bench_remote.py's throughput, here with overlapped (`overlap=true`) requests.
  batch    `bench serve batch=N` against each worker holding its own policy copy.
Targets: fast >= 2.0x bare robosuite; workers >= 1.9x end to end; remote >= 1.0 (chunked) and >= 0.95
(per step); batch: a table.
"""

from __future__ import annotations

import cProfile
import dataclasses
import io
import os
import pstats
import sys
import tempfile
import time

import numpy as np
from bench_robosuite_raw import Bare as RawBare  # the same folder (run as a script): the one bare loop
from bench_robosuite_raw import plan  # ... and the plan it times

from bench.api.scripts import script_keys

ARMS = ("Panda", "Sawyer", "IIWA", "UR5e", "Kinova3", "Jaco", "XArm7")


def load() -> str:
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def part_fast(episodes: int, horizon: int, profile: bool) -> None:
    from bench.api.throughput import harness_vs_bare

    for fast in (True, False):
        res = harness_vs_bare(
            plan("Panda", episodes, horizon, run_id="throughput-bench", fast=fast),
            bare=lambda: RawBare.make("Panda", horizon),
        )
        h, r = res["harness_steps_per_s"], res["bare_steps_per_s"]
        name = "fast path" if fast else "fast_path=false (control)"
        print(
            f"  harness, {name}: {h:.1f} env-steps/s; bare robosuite loop {r:.1f} env-steps/s; "
            f"harness / bare = {h / r:.3f}   [load {load()}]"
        )
    print("  adapter: fast path ÷ robosuite env.step per arm (same env seeds and actions, interleaved; equal bytes?)")
    from bench.api.sims import RobosuiteEnv
    from suites.lift import LiftObserver

    for arm in ARMS:
        fast_env = RobosuiteEnv("Lift", arm, horizon, LiftObserver())
        plain_env = RobosuiteEnv("Lift", arm, horizon, LiftObserver(), fast=False)
        secs = {"fast": 0.0, "plain": 0.0}
        same = True
        for ep in range(2):
            rng = np.random.default_rng(ep)
            fast_env.reset(ep)
            plain_env.reset(ep)
            for t in range(min(horizon, 100)):
                action = rng.uniform(-1, 1, 7)
                order = (
                    (("fast", fast_env), ("plain", plain_env))
                    if t % 2 == 0
                    else (("plain", plain_env), ("fast", fast_env))
                )
                out = {}
                for name, env in order:
                    t0 = time.perf_counter()
                    out[name] = env.step(action)
                    secs[name] += time.perf_counter() - t0
                same &= out["fast"][0]["state"].tobytes() == out["plain"][0]["state"].tobytes()
                same &= out["fast"][1] == out["plain"][1]
                same &= fast_env.mujoco.data.qpos.tobytes() == plain_env.mujoco.data.qpos.tobytes()
        print(f"    {arm:8s} fast / env.step = {secs['plain'] / secs['fast']:.2f}x   identical: {same}")
        fast_env.close()
        plain_env.close()
        if profile and arm == "Panda":
            for label, fast in (("robosuite env.step", False), ("fast path", True)):
                print(f"  profile, {label} (Panda, 200 steps; top 12 by own time):")
                print(_profile(fast, horizon))


def _profile(fast: bool, horizon: int) -> str:
    from bench.api.sims import RobosuiteEnv
    from suites.lift import LiftObserver

    env = RobosuiteEnv("Lift", "Panda", horizon, LiftObserver(), fast=fast)
    env.reset(0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        env.step(rng.uniform(-1, 1, 7))
    prof = cProfile.Profile()
    t0 = time.perf_counter()
    prof.enable()
    for _ in range(200):
        env.step(rng.uniform(-1, 1, 7))
    prof.disable()
    wall = time.perf_counter() - t0
    env.close()
    buf = io.StringIO()
    stats = pstats.Stats(prof, stream=buf)
    stats.sort_stats("tottime").print_stats(12)
    lines = [ln for ln in buf.getvalue().splitlines() if ln.strip()]
    start = next(i for i, ln in enumerate(lines) if ln.lstrip().startswith("ncalls"))
    body = "\n".join("    " + ln.replace(sys.prefix, "<venv>") for ln in lines[start:])
    return f"    {wall / 200 * 1e3:.2f} ms per step under the profiler\n{body}"


def part_workers(episodes: int, horizon: int) -> None:
    from bench.api.throughput import workers_scaling

    p = plan("Panda", episodes, horizon, run_id="throughput-bench")
    p = dataclasses.replace(p, cells=p.cells[:1], jobs=[j for j in p.jobs if j.cell == p.cells[0]])
    print(f"  load before: {load()}")
    b = workers_scaling(p, 2)
    print(
        f"  end to end ({episodes} episodes x {horizon} steps, start-up and env builds included): "
        f"1 worker {b['one']['end_to_end']:.1f} ({b['one']['wall']:.1f} s), 2 workers {b['many']['end_to_end']:.1f} "
        f"env-steps/s ({b['many']['wall']:.1f} s): 2 / 1 = {b['ratio_end_to_end']:.3f}"
    )
    print(
        f"  steady state: 1 worker {b['one']['steady']:.1f}, 2 workers {b['many']['steady']:.1f} env-steps/s: "
        f"2 / 1 = {b['ratio_steady']:.3f}   [load after {load()}]"
    )


def part_suite(episodes: int, repeats: int, policy: str = "") -> None:
    """The whole main job end to end: `bench run suite=held_out_robots episodes=N workers=1` and `workers=2`
    as commands (interpreter start-up, imports, plan, every worker's start-up and env builds, all 7 arms,
    the summary and leaderboard included), alternating, `repeats` times each; wall time and env-steps/s."""
    import json
    import subprocess

    walls: dict[int, list[float]] = {1: [], 2: []}
    steps: dict[int, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(repeats):
            for w in (1, 2) if rep % 2 == 0 else (2, 1):
                run_id = f"w{w}-{rep}"
                argv = [
                    "suite=held_out_robots",
                    *([f"policy={policy}"] if policy else []),
                    f"episodes={episodes}",
                    f"workers={w}",
                    f"out={tmp}",
                    f"run_id={run_id}",
                ]
                t0 = time.perf_counter()
                res = subprocess.run([sys.executable, "-m", "bench", "run", *argv], capture_output=True, text=True)
                wall = time.perf_counter() - t0
                if res.returncode != 0:
                    raise SystemExit(f"bench run {' '.join(argv)} exited {res.returncode}: {res.stderr.strip()[-400:]}")
                with open(os.path.join(tmp, run_id, "episodes.jsonl")) as f:
                    steps[w] = sum(json.loads(line)["length"] for line in f if line.strip())
                walls[w].append(wall)
                print(f"  workers={w}: {wall:.1f} s, {steps[w] / wall:.1f} env-steps/s   [load {load()}]", flush=True)
    one, two = (float(np.median(walls[w])) for w in (1, 2))
    print(
        f"  held_out_robots end to end (7 arms x {episodes} episodes, policy={policy or 'bc (default)'}, the "
        "`bench run` command, median of "
        f"{repeats}): 1 worker {one:.1f} s, 2 workers {two:.1f} s: 2 / 1 = {one / two:.3f}"
    )


PARTS = ("fast", "workers", "suite", "remote", "batch")
KEYS = (
    "parts", "episodes", "horizon", "scaling_episodes", "repeats", "suite_policy", "profile",
    "remote_episodes", "batch_seconds", "batch_horizon", "batch_workers",
)  # fmt: skip


def main(argv: list[str]) -> int:
    kv = script_keys(argv, __doc__, KEYS)
    parts = kv.get("parts", "[fast,workers,remote,batch]").strip("[]").split(",")
    episodes, horizon = int(kv.get("episodes", 6)), int(kv.get("horizon", 250))
    scaling = int(kv.get("scaling_episodes", 12))
    profile = kv.get("profile", "false") == "true"
    unknown = [p for p in parts if p not in PARTS]
    if unknown:  # checked before any part runs
        print(f"error: parts: {unknown[0]!r} is not a part; valid: {', '.join(PARTS)}", file=sys.stderr)
        return 2
    print(f"machine: {os.cpu_count()} cores, load {load()} (1/5/15 min)")
    for part in parts:
        t0 = time.perf_counter()
        print(f"[{part}]")
        if part == "fast":
            part_fast(episodes, horizon, profile)
        elif part == "workers":
            part_workers(scaling, horizon)
        elif part == "suite":
            part_suite(scaling, int(kv.get("repeats", 1)), kv.get("suite_policy", ""))
        elif part in ("remote", "batch"):
            import bench_throughput_remote as remote  # the same folder: run as a script

            remote.PARTS[part](kv)
        print(f"  ({time.perf_counter() - t0:.0f} s)")
    print(f"load at the end: {load()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
