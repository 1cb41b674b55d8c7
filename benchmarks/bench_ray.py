"""Ray executor against the local executor on this machine, in one run; and a 10,000-episode projection.

    python benchmarks/bench_ray.py [episodes=40] [workers=2] [tiny=300] [rounds=1]

It re-runs itself inside a loopback-only Linux namespace (tests/ray_sandbox.py: Ray would
otherwise bind the machine's interface address) and starts a private Ray there
(`ray_address=local`). Measured, on the same jobs (held_out_robots, cell Lift/Panda, random
policy, horizon 250: what `bench perf` runs), with the same number of workers (local: this
process + workers-1 children; Ray: `workers` actors):

1. throughput, env-steps/s: end to end (worker/actor start-up and env builds included; the
   Ray cluster is already up, as a user's would be) and steady state (each worker's steps
   over its episodes' wall time, summed), Ray / local;
2. scheduling overhead per episode: `tiny` one-step toy episodes (tests/toy_suite.py) on both
   executors; after the first record, the driver's seconds per episode times the workers,
   minus the episodes' own wall time, is what the executor adds to each episode;
3. a projection of a 10,000-episode evaluation on 100 cores (100 actors, 1 CPU each) from the
   measured per-episode costs: start-up + env builds per actor + episodes per actor x
   (episode + overhead); the driver's serial work (receiving and fsyncing each record) is
   checked against it.

Ratios are measured in one run; rounds > 1 alternates local and Ray to spread drift.
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

from bench.api.scripts import script_keys

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

INSIDE = "BENCH_RAY_SANDBOXED"


def timed(executor, jobs, spec) -> dict:
    from bench.api.throughput import per_worker, steady_rate

    records: list = []
    arrivals: list[float] = []

    def on_record(r):
        arrivals.append(time.perf_counter())
        records.append(r)

    t0 = time.perf_counter()
    executor.execute(jobs, spec, on_record)
    wall = time.perf_counter() - t0
    steps = sum(r.length for r in records)
    return {
        "wall": wall,
        "steps": steps,
        "end_to_end": steps / wall,
        "first": arrivals[0] - t0,
        "steady": steady_rate(per_worker(records)),
        "records": records,
        "arrivals": arrivals,
        "episode_s": statistics.mean(r.wall_s for r in records),
    }


def overhead(run: dict, workers: int) -> float:
    """Seconds the executor adds per episode: driver interval x workers - the episodes' own wall time.

    Counted from the moment every worker has delivered a record (all busy), to the last record.
    """
    first: dict[int, float] = {}
    for r, t in zip(run["records"], run["arrivals"]):
        first.setdefault(r.worker_pid, t)
    start = max(first.values())
    later = [(r, t) for r, t in zip(run["records"], run["arrivals"]) if t > start]
    interval = (later[-1][1] - start) / len(later)
    return interval * workers - statistics.mean(r.wall_s for r, _ in later)


def main(argv: list[str]) -> int:
    from bench import api
    from bench.api import throughput as perf
    from bench.execution.local import LocalExecutor
    from bench.execution.ray_executor import RayExecutor
    from bench.records import RecordWriter, comparable

    kv = script_keys(argv, __doc__, ("episodes", "rounds", "tiny", "workers"))
    episodes, workers = int(kv.get("episodes", 40)), int(kv.get("workers", 2))
    tiny, rounds = int(kv.get("tiny", 300)), int(kv.get("rounds", 1))

    p = perf.make_plan(perf.PerfConfig(), episodes)
    spec = p.worker_spec(api.context(p))
    toy = api.plan(
        api.RunConfig(
            suite="tests.toy_suite:ToySuite",
            policy="scripted",
            robots=["a"],
            episodes=tiny,
            horizon=1,
            out="/tmp",
            run_id="toy-bench",
            suite_options={"step_delay": 0.02},
        )
    )
    toy_spec = toy.worker_spec(api.context(toy))
    t0 = time.perf_counter()
    ray_ex = RayExecutor("local", actors=workers)
    ray_ex.connect(len(p.jobs), spec.suite_ref, spec.policy_ref)  # kept up across the runs below
    cluster_s = time.perf_counter() - t0
    env = p.suite.make_env(p.cells[0], p.horizon)  # first build imports the simulator
    env.close()
    t0 = time.perf_counter()
    p.suite.make_env(p.cells[0], p.horizon).close()
    build_s = time.perf_counter() - t0
    print(
        f"machine: {os.cpu_count()} cores; Ray {__import__('ray').__version__} private cluster up in "
        f"{cluster_s:.1f} s; {episodes} episodes of {p.cells[0].key} (random policy, horizon {p.horizon}), "
        f"{workers} workers",
        flush=True,
    )

    local_runs, ray_runs = [], []
    for _ in range(rounds):
        local_runs.append(timed(LocalExecutor(workers), p.jobs, spec))
        ray_runs.append(timed(ray_ex, p.jobs, spec))
    same = sorted(map(comparable, local_runs[0]["records"]), key=lambda d: d["job_id"]) == sorted(
        map(comparable, ray_runs[0]["records"]), key=lambda d: d["job_id"]
    )
    loc = {k: statistics.mean(r[k] for r in local_runs) for k in ("end_to_end", "steady", "first", "episode_s")}
    ray = {k: statistics.mean(r[k] for r in ray_runs) for k in ("end_to_end", "steady", "first", "episode_s")}
    print(f"records identical (timing aside): {same}")
    print(
        f"end to end: local {loc['end_to_end']:.1f} env-steps/s, Ray {ray['end_to_end']:.1f} env-steps/s: "
        f"Ray / local = {ray['end_to_end'] / loc['end_to_end']:.3f}"
    )
    print(
        f"steady state: local {loc['steady']:.1f}, Ray {ray['steady']:.1f} env-steps/s: "
        f"Ray / local = {ray['steady'] / loc['steady']:.3f}"
    )
    print(
        f"first record after: local {loc['first']:.1f} s, Ray {ray['first']:.1f} s (worker start-up + env build "
        f"+ one episode of {loc['episode_s']:.2f} s)"
    )

    tl = timed(LocalExecutor(workers), toy.jobs, toy_spec)
    tr = timed(ray_ex, toy.jobs, toy_spec)
    o_local, o_ray = overhead(tl, workers), overhead(tr, workers)
    print(
        f"scheduling overhead per episode ({tiny} one-step 20 ms toy episodes, {workers} workers busy): local "
        f"{o_local * 1e3:.2f} ms, Ray {o_ray * 1e3:.2f} ms (Ray - local = {(o_ray - o_local) * 1e3:.2f} ms)"
    )

    with RecordWriter(Path("/tmp") / f"bench-ray-{os.getpid()}.jsonl") as writer:
        t0 = time.perf_counter()
        for r in tr["records"]:
            writer.write(r)
        write_s = (time.perf_counter() - t0) / len(tr["records"])
    os.unlink(writer.path)
    ray_ex.close()

    E, C, cells = 10_000, 100, len(p.suite.all_cells())
    start_s = max(0.0, ray["first"] - build_s - ray["episode_s"])  # actor process, imports, Worker
    per_actor = -(-E // C)
    t = start_s + cells * build_s + per_actor * (ray["episode_s"] + max(o_ray, 0.0))
    driver = E * write_s
    print(
        f"projection, {E} episodes on {C} cores ({C} actors of 1 CPU; {cells} cells of {p.suite.name}, "
        f"cell-major, so each actor builds each cell once): actor start {start_s:.1f} s + {cells} env builds "
        f"x {build_s:.1f} s + {per_actor} episodes x ({ray['episode_s']:.2f} s + {max(o_ray, 0) * 1e3:.1f} ms "
        f"overhead) = {t / 60:.1f} min (one core: {E * ray['episode_s'] / 3600:.1f} h); the driver writes a "
        f"record in {write_s * 1e3:.2f} ms (fsync): {driver:.0f} s in all, {100 * driver / t:.1f}% of one core"
    )
    return 0


if __name__ == "__main__":
    if os.environ.get(INSIDE) != "1":
        from tests import ray_sandbox

        why = ray_sandbox.unavailable()
        if why:
            sys.exit(f"bench_ray: {why}")
        os.environ[INSIDE] = "1"
        res = ray_sandbox.run([sys.executable, __file__, *sys.argv[1:]], timeout=3600)
        print(res.stdout, end="")
        print(
            "\n".join(ln for ln in res.stderr.splitlines() if "network_util.cc" not in ln and "WARNING" not in ln),
            file=sys.stderr,
        )
        sys.exit(res.returncode)
    sys.exit(main(sys.argv[1:]))
