"""Remote policies: round-trip latency over localhost and harness throughput, remote vs in process, in one run.

    python benchmarks/bench_remote.py [requests=2000] [robots=[Panda,UR5e]] [episodes=6] [horizon=150]

1. Round trip: `bench serve` runs in its own process on 127.0.0.1; the `policy=remote` client (the same
   `RemotePolicy.act` a run calls: obs_map, msgpack-numpy, validation of the (T, A) answer, latency
   bookkeeping) sends `requests` observations of two sizes and the median is reported:
     state   an 18-float32 state (held_out_robots' observation) + the task string
     images  the same plus two 224x224x3 uint8 cameras (LIBERO/DROID-sized)
   The observations are seeded random numbers of exactly those shapes from `WireSuite` below (no robosuite
   suite renders cameras yet); the served policy answers a 10x7 float32 chunk computed from the state,
   as openpi's LIBERO policies do. openpi-client's own `WebsocketClientPolicy` against the same server is
   printed for reference (the floor: no validation, no bookkeeping).
2. Throughput: held_out_robots with the scripted expert, in process vs `policy=remote` against
   `bench serve policy=scripted` in another process (state observations), same seeds; envs built and
   warmed on both sides first (steady state), episodes alternate in-process / remote so drifts in
   machine speed hit both alike. The remote records must equal the in-process ones (policy name and
   latency extras aside); the script says so.

Targets (issue 16): round-trip median <= 1 ms (state), <= 5 ms (two images); remote >= 0.9x in-process.
"""
from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.protocols import STATE, ActionSpec, Feature
from bench.suite import Cell, SuiteBase

REPO = Path(__file__).resolve().parents[1]
WIRE = "benchmarks.bench_remote:WireSuite"


@dataclass(frozen=True)
class WireOptions:
    """Keys of the wire-benchmark suite."""

    cameras: int = 0   # 224x224 cameras in the observation (0 or 2)


class WireEnv:
    """Observations of a given size (seeded random numbers); stepping is not what is measured here."""

    backend, fps, horizon = "wire-1", 20.0, 1
    mujoco = inputs = model_axes = None
    action_spec = ActionSpec.box(["dx", "dy", "dz", "droll", "dpitch", "dyaw", "gripper"], -1.0, 1.0)

    def __init__(self, cameras: int):
        self.obs_spec = {STATE: Feature.state([("state", 18)]),
                         **{f"rgb.cam{i}": Feature.rgb(224, 224) for i in range(cameras)}}

    def reset(self, seed: int) -> dict:
        rng = np.random.default_rng(seed)
        return {k: (rng.random(f.shape, np.float32) if f.dtype == "float32" else
                    rng.integers(0, 256, f.shape, dtype=np.uint8)) for k, f in self.obs_spec.items()}

    def step(self, action):
        raise RuntimeError("WireEnv measures the wire only")

    def success(self) -> bool:
        return False

    def init_state(self) -> np.ndarray:
        return np.zeros(1)

    def close(self) -> None:
        pass


class ChunkPolicy:
    """A 10x7 chunk from the state (and a touch of each image, so they are read)."""

    def reset(self, seed: int) -> None:
        pass

    def act(self, obs: dict) -> np.ndarray:
        base = np.resize(obs[STATE][:7], 7).astype(np.float32)
        bias = sum(float(v[0, 0, 0]) for k, v in obs.items() if k.startswith("rgb.")) / 255.0
        return np.tile(base + bias, (10, 1))


class WireSuite(SuiteBase):
    """One cell with a state (and optional cameras): the observation sizes of the round-trip benchmark."""

    name = "wire"
    version = "1"
    Options = WireOptions
    reference_policy = default_policy = "scripted"
    default_horizon = 1
    manifest = {"robots": {"seen": ["any"], "unseen": []}}
    capabilities = frozenset({"expert"})

    def all_cells(self) -> list[Cell]:
        return [Cell(self.name, "wire", "any", "localhost", "seen")]

    def obs_spec(self, cell: Cell):
        return WireEnv(self.options.cameras).obs_spec

    def make_env(self, cell: Cell, horizon: int) -> WireEnv:
        return WireEnv(self.options.cameras)

    def make_expert(self, cell: Cell, env) -> ChunkPolicy:
        return ChunkPolicy()


@contextlib.contextmanager
def serve(*keys: str):
    """`bench serve` in its own process on 127.0.0.1 (port chosen by the OS); yields the port."""
    proc = subprocess.Popen([sys.executable, "-m", "bench", "serve", "port=0", *keys], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        line = proc.stdout.readline()
        if "ws://127.0.0.1:" not in line:
            raise RuntimeError(f"bench serve did not start: {line!r}")
        yield int(line.split("ws://127.0.0.1:")[1].split(" ")[0])
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def round_trips(cameras: int, requests: int) -> tuple[np.ndarray, np.ndarray]:
    """(bench client, openpi-client) round-trip seconds against `bench serve` of the wire suite."""
    from bench import api

    with serve("policy=scripted", f"suite={WIRE}", f"cameras={cameras}") as port:
        plan = api.plan(api.RunConfig(suite=WIRE, policy="remote", episodes=1, horizon=1, workers=1,
                                      out=tempfile.gettempdir(), run_id="wire-bench",
                                      suite_options={"cameras": cameras}, policy_options={"port": port}))
        worker = api.worker(plan)
        env, policy = worker.built(plan.jobs[0])
        obs = env.reset(0)
        policy.reset(0)
        for _ in range(50):
            policy.act(obs)
        t = np.empty(requests)
        for i in range(requests):
            t0 = time.perf_counter()
            policy.act(obs)
            t[i] = time.perf_counter() - t0
        policy.close()
        worker.close()
        from openpi_client.websocket_client_policy import WebsocketClientPolicy

        client = WebsocketClientPolicy("127.0.0.1", port)
        msg = {**obs, "task": "wire"}
        for _ in range(50):
            client.infer(msg)
        o = np.empty(requests)
        for i in range(requests):
            t0 = time.perf_counter()
            client.infer(msg)
            o[i] = time.perf_counter() - t0
        client._ws.close()
    return t, o


def throughput(robots: list[str], episodes: int, horizon: int) -> tuple[float, float, float, float, bool, int]:
    """(in-process env-steps/s, remote env-steps/s, median per-episode ratio, mean round trip ms,
    records equal, episodes compared)."""
    from bench import api
    from bench.records import comparable

    def plan(policy: str, **popts):
        return api.plan(api.RunConfig(suite="held_out_robots", policy=policy, robots=robots, episodes=episodes,
                                      horizon=horizon, workers=1, out=tempfile.gettempdir(), run_id=f"tp-{policy}",
                                      policy_options=popts))

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
        for job in local_plan.jobs:
            t0 = time.perf_counter()
            a = local.run(job)
            dt_local = time.perf_counter() - t0
            t0 = time.perf_counter()
            b = remote.run(job)
            dt_remote = time.perf_counter() - t0
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
    kv = dict(a.split("=", 1) for a in argv)
    requests = int(kv.get("requests", 2000))
    robots = kv.get("robots", "[Panda,UR5e]").strip("[]").split(",")
    episodes, horizon = int(kv.get("episodes", 6)), int(kv.get("horizon", 150))
    os.environ.setdefault("MUJOCO_GL", "disable")
    print(f"round trip over 127.0.0.1, bench serve in its own process, {requests} requests each (median, p90):")
    for cameras, label, target in ((0, "state (18 float32)", 1.0), (2, "state + two 224x224x3 uint8 images", 5.0)):
        t, o = round_trips(cameras, requests)
        med = np.median(t) * 1000
        print(f"  {label:<36} policy=remote {med:6.3f} ms, p90 {np.quantile(t, 0.9) * 1000:6.3f} ms   "
              f"(openpi-client {np.median(o) * 1000:6.3f} ms)   target <= {target:g} ms: "
              f"{'met' if med <= target else 'NOT met'}")
    local, remote, paired, rtt, same, n = throughput(robots, episodes, horizon)
    print(f"throughput, held_out_robots {'/'.join(robots)}, scripted, {n} episodes x <= {horizon} steps, steady state:")
    ratio = remote / local
    print(f"  in process {local:7.1f} env-steps/s, policy=remote vs bench serve {remote:7.1f} env-steps/s: "
          f"remote / in-process = {ratio:.3f} (target >= 0.9: {'met' if ratio >= 0.9 else 'NOT met'})")
    print(f"  median over episodes of (in-process time / remote time) for the same episode: {paired:.3f}; "
          f"mean round trip during the runs {rtt:.3f} ms")
    print(f"  records equal to in-process (policy name and latency extras aside): {'yes' if same else 'NO'} "
          f"({n} episodes)")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
