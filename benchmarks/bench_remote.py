"""Remote policies: round-trip latency over localhost and harness throughput, remote vs in process, in one run.

    python benchmarks/bench_remote.py [requests=2000] [robots=[Panda,UR5e]] [episodes=6] [horizon=150]

1. Round trip: `bench serve policy=scripted` (held_out_robots, Panda) runs in its own process on 127.0.0.1;
   the `policy=remote` client (the same `RemotePolicy.act` a run calls: obs_map, msgpack-numpy, the
   server's checks of the observation against the cell's spec, validation of the answer, latency
   bookkeeping) sends the cell's first observation `requests` times, in two sizes:
     state   obs=state: the 18-float32 agnostic state + the task string
     images  obs=state+rgb image_size=224: the same plus the two default cameras (agentview,
             robot0_eye_in_hand), 224x224x3 uint8 each, rendered by the suite (LIBERO/DROID-sized)
   and the median is reported. openpi-client's own `WebsocketClientPolicy` against the same server is
   printed for reference (the floor: no validation, no bookkeeping).
2. Throughput: held_out_robots with the scripted expert, in process vs `policy=remote` against
   `bench serve policy=scripted` in another process (state observations), same seeds; envs built and
   warmed on both sides first (steady state), each episode runs both ways back to back (which goes first
   alternates) so drifts in machine speed hit both alike. The remote records must equal the in-process
   ones (policy name and latency extras aside); the script says so.

Targets (issue 16): round-trip median <= 1 ms (state), <= 5 ms (two images); remote >= 0.9x in-process.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.api.scripts import script_keys

REPO = Path(__file__).resolve().parents[1]
IMAGES = {"obs": "state+rgb", "image_size": 224}  # two cameras: the suite's default agentview + wrist view


@contextlib.contextmanager
def serve(*keys: str):
    """`bench serve` in its own process on 127.0.0.1 (port chosen by the OS); yields the port."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench", "serve", "port=0", *keys],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        line = proc.stdout.readline()
        if "ws://127.0.0.1:" not in line:
            raise RuntimeError(f"bench serve did not start: {line!r}")
        yield int(line.split("ws://127.0.0.1:")[1].split(" ")[0])
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def seconds_per_call(call, requests: int, warmup: int = 50) -> np.ndarray:
    """Seconds of each of `requests` calls of `call`, after `warmup` untimed ones."""
    for _ in range(warmup):
        call()
    t = np.empty(requests)
    for i in range(requests):
        t0 = time.perf_counter()
        call()
        t[i] = time.perf_counter() - t0
    return t


def round_trips(images: bool, requests: int) -> tuple[np.ndarray, np.ndarray, str]:
    """(bench client, openpi-client) round-trip seconds against `bench serve`; and the observation's layout."""
    from bench import api
    from bench.protocols import describe_spec

    suite_options = IMAGES if images else {}
    with serve("policy=scripted", *[f"{k}={v}" for k, v in suite_options.items()]) as port:
        plan = api.plan(
            api.RunConfig(
                suite="held_out_robots",
                policy="remote",
                robots=["Panda"],
                episodes=1,
                horizon=1,
                workers=1,
                out=tempfile.gettempdir(),
                run_id="wire-bench",
                suite_options=suite_options,
                policy_options={"port": port, "timeout_s": 120.0},
            )
        )
        worker = api.worker(plan)
        env, policy = worker.built(plan.jobs[0])
        obs = env.reset(plan.jobs[0].seed)
        layout = describe_spec(env.obs_spec)
        policy.reset(plan.jobs[0].seed)  # the server builds the cell's env and policy here (not timed)
        t = seconds_per_call(lambda: policy.act(obs), requests)
        policy.close()
        worker.close()
        from openpi_client.websocket_client_policy import WebsocketClientPolicy

        client = WebsocketClientPolicy("127.0.0.1", port)
        msg = {**obs, "task": "Lift"}
        o = seconds_per_call(lambda: client.infer(msg), requests)
        client._ws.close()
    return t, o, layout


def throughput(robots: list[str], episodes: int, horizon: int) -> tuple[float, float, float, float, bool, int]:
    """(in-process env-steps/s, remote env-steps/s, median per-episode ratio, mean round trip ms,
    records equal, episodes compared)."""
    from bench import api
    from bench.records import comparable

    def plan(policy: str, **popts):
        return api.plan(
            api.RunConfig(
                suite="held_out_robots",
                policy=policy,
                robots=robots,
                episodes=episodes,
                horizon=horizon,
                workers=1,
                out=tempfile.gettempdir(),
                run_id=f"tp-{policy}",
                policy_options=popts,
            )
        )

    local_plan = plan("scripted")
    local = api.worker(local_plan)
    with serve("policy=scripted") as port:
        remote_plan = plan("remote", port=port, timeout_s=120.0)
        remote = api.worker(remote_plan)
        cells = {}
        for job in local_plan.jobs:  # warm up: envs built on both sides (and on the server), not timed
            if job.cell.key not in cells:
                cells[job.cell.key] = True
                local.run(job)
                remote.run(job)
        t_local = t_remote = 0.0
        steps_local = steps_remote = 0
        same, n, ratios, rtt = True, 0, [], []
        strip = lambda r: {k: v for k, v in comparable(r).items() if k not in ("policy", "extras")}  # noqa: E731
        for i, job in enumerate(local_plan.jobs):
            timed = {}
            for side in ("local", "remote") if i % 2 == 0 else ("remote", "local"):  # alternate who goes first
                t0 = time.perf_counter()
                rec = (local if side == "local" else remote).run(job)
                timed[side] = (rec, time.perf_counter() - t0)
            (a, dt_local), (b, dt_remote) = timed["local"], timed["remote"]
            t_local, t_remote = t_local + dt_local, t_remote + dt_remote
            ratios.append(dt_local / dt_remote)  # the same episode both ways: robust to slow drifts in load
            rtt.append(b.extras["policy"]["rtt_ms"]["mean"])
            steps_local, steps_remote = steps_local + a.length, steps_remote + b.length
            same = same and a.error is None and b.error is None and strip(a) == strip(b)
            n += 1
        local.close()
        remote.close()
    return steps_local / t_local, steps_remote / t_remote, float(np.median(ratios)), float(np.mean(rtt)), same, n


def main(argv: list[str]) -> int:
    kv = script_keys(argv, __doc__, ("episodes", "horizon", "requests", "robots"))
    requests = int(kv.get("requests", 2000))
    robots = kv.get("robots", "[Panda,UR5e]").strip("[]").split(",")
    episodes, horizon = int(kv.get("episodes", 6)), int(kv.get("horizon", 150))
    os.environ.setdefault("MUJOCO_GL", "egl")  # the cameras render offscreen (software EGL on CPU machines)
    print(f"round trip over 127.0.0.1, bench serve in its own process, {requests} requests each (median, p90):")
    for images, label, target in ((False, "state", 1.0), (True, "state + two 224x224 images", 5.0)):
        t, o, layout = round_trips(images, requests)
        med = np.median(t) * 1000
        print(
            f"  {label:<27} policy=remote {med:6.3f} ms, p90 {np.quantile(t, 0.9) * 1000:6.3f} ms   "
            f"(openpi-client {np.median(o) * 1000:6.3f} ms)   target <= {target:g} ms: "
            f"{'met' if med <= target else 'NOT met'}   [{layout}]"
        )
    local, remote, paired, rtt, same, n = throughput(robots, episodes, horizon)
    print(f"throughput, held_out_robots {'/'.join(robots)}, scripted, {n} episodes x <= {horizon} steps, steady state:")
    ratio = remote / local
    print(
        f"  in process {local:7.1f} env-steps/s, policy=remote vs bench serve {remote:7.1f} env-steps/s: "
        f"remote / in-process = {ratio:.3f} (target >= 0.9: {'met' if ratio >= 0.9 else 'NOT met'})"
    )
    print(
        f"  median over episodes of (in-process time / remote time) for the same episode: {paired:.3f}; "
        f"mean round trip during the runs {rtt:.3f} ms"
    )
    print(
        f"  records equal to in-process (policy name and latency extras aside): {'yes' if same else 'NO'} "
        f"({n} episodes)"
    )
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
