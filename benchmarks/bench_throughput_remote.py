"""The remote and batching parts of benchmarks/bench_throughput.py (run that script; see its docstring).

remote  held_out_robots, robots=[Panda,UR5e], a generated torch MLP policy answering chunks of 10 actions
        (hidden [512, 512], random weights made here with a fixed seed, not downloaded). End to end:
        whole `bench run` commands (process start, imports, plan, env builds, episodes, summary), each
        timed from start to exit, in-process (`policy=checkpoint`) against `policy=remote` talking to a
        `bench serve` started once before (a service; it builds the cells' envs ahead when a run
        announces them: `prepare`). The commands alternate (A B B A ...) so load drifts hit both alike.
          chunked   replan_every=5: in process, and remote with overlap=true
          per step  replan_every=1 (a round trip at every step): in process, remote with overlap=true,
                    and remote without overlap (records equal to in process: checked)
batch   `bench serve batch=8` with a wider MLP (hidden [4096, 4096, 4096], one action per answer): env
        worker processes 1, 2, 4, 8 all talking to that one server, against the same number of workers each
        holding its own copy of the policy (`policy=checkpoint`, one torch thread each). Each worker builds
        its env and policy as a bench worker does (`bench.api.worker`), all start stepping together
        (a barrier: start-up left out on both sides) and step for `batch_seconds`, asking the policy at
        every step; throughput = all their env steps / that time.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_remote import serve  # the same folder (run as a script or from bench_throughput): one server launcher

REPO = Path(__file__).resolve().parents[1]


def load() -> str:
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def make_checkpoint(folder: Path, hidden: list[int], chunk: int, name: str) -> Path:
    """A random-weight MLP policy for held_out_robots' 18-number observation and 7-D action."""
    import torch

    from baselines.architectures import build
    from baselines.checkpoint import save_checkpoint
    from bench.sims.robosuite import ACTION_NAMES
    from suites.lift import OBS_FIELDS

    torch.manual_seed(0)
    model = build("mlp", 18, 7 * chunk, {"hidden": hidden, "out_activation": "tanh"})
    spec = {
        "architecture": "mlp",
        "kwargs": {"hidden": hidden, "out_activation": "tanh"},
        "obs_names": [[n, w] for n, w in OBS_FIELDS],
        "action_names": list(ACTION_NAMES),
        "chunk": chunk,
        "meta": {"made_by": "benchmarks/bench_throughput_remote.py", "weights": "random, torch.manual_seed(0)"},
    }
    return save_checkpoint(folder / f"{name}.safetensors", model, spec)


def _bench_run(out: Path, run_id: str, *keys: str) -> float:
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "bench", "run", "suite=held_out_robots", f"out={out}", f"run_id={run_id}", *keys],
        cwd=REPO,
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    return time.perf_counter() - t0


def _records(path: Path) -> list[dict]:
    drop = ("wall_s", "finished_at", "worker_pid", "run_id", "policy", "extras")
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return sorted(({k: v for k, v in r.items() if k not in drop} for r in rows), key=lambda r: r["job_id"])


def part_remote(kv: dict[str, str]) -> None:
    episodes = int(kv.get("remote_episodes", 3))
    repeats = int(kv.get("repeats", 2))
    common = ["robots=[Panda,UR5e]", f"episodes={episodes}", "horizon=250", "workers=1", "seed=0"]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        ckpt = make_checkpoint(folder, [512, 512], 10, "chunked")
        with serve("policy=checkpoint", f"checkpoint={ckpt}") as port:
            remote = ["policy=remote", f"port={port}", "timeout_s=120"]
            local = ["policy=checkpoint", f"checkpoint={ckpt}"]
            cases = {
                "chunked (replan_every=5)": (
                    [*local, "replan_every=5"],
                    [*remote, "replan_every=5", "overlap=true"],
                ),
                "per step (replan_every=1), overlap": (
                    [*local, "replan_every=1"],
                    [*remote, "replan_every=1", "overlap=true"],
                ),
                "per step (replan_every=1), no overlap": (
                    [*local, "replan_every=1"],
                    [*remote, "replan_every=1"],
                ),
            }
            n = 0
            for name, (a_keys, b_keys) in cases.items():
                secs = {"in process": 0.0, "remote": 0.0}
                print(f"  {name}: load before {load()}")
                same = None
                for rep in range(repeats):
                    order = (("in process", a_keys), ("remote", b_keys))
                    for side, keys in order if rep % 2 == 0 else order[::-1]:
                        n += 1
                        secs[side] += _bench_run(folder, f"r{n}", *common, *keys)
                        if side == "in process":
                            local_dir = folder / f"r{n}"
                        else:
                            remote_dir = folder / f"r{n}"
                    if "no overlap" in name:
                        same = _records(local_dir / "episodes.jsonl") == _records(remote_dir / "episodes.jsonl")
                ratio = secs["in process"] / secs["remote"]
                extra = f"; records equal to in process: {same}" if same is not None else ""
                print(
                    f"    end to end, {repeats} x {2 * episodes} episodes each way: in process "
                    f"{secs['in process'] / repeats:.1f} s, remote {secs['remote'] / repeats:.1f} s per run: "
                    f"remote / in process = {ratio:.3f}{extra}   [load after {load()}]"
                )


def _worker(policy_keys: dict, horizon: int, seconds: float, barrier, results, index: int) -> None:
    """One env worker: build its env and policy as a bench worker does, wait for the others, then step
    `seconds` (the policy asked at every step) and report its env steps."""
    import torch

    from bench import api

    torch.set_num_threads(1)
    plan = api.plan(
        api.RunConfig(
            suite="held_out_robots",
            policy=policy_keys["policy"],
            robots=["Panda"],
            episodes=1,
            horizon=horizon,
            seed=index,
            out=tempfile.gettempdir(),
            run_id=f"batch-bench-{os.getpid()}",
            policy_options={k: v for k, v in policy_keys.items() if k != "policy"},
        )
    )
    worker = api.worker(plan)
    job = plan.jobs[0]
    env, policy = worker.built(job)
    obs = env.reset(job.seed)
    policy.reset(job.seed)
    barrier.wait()
    steps, t = 0, 0
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        action = np.asarray(policy.act(obs))
        obs = env.step(action[0] if action.ndim == 2 else action)[0]
        steps, t = steps + 1, t + 1
        if t >= horizon:
            obs, t = env.reset(job.seed), 0
            policy.reset(job.seed)
    results[index] = steps
    worker.close()


def _concurrent(workers: int, policy_keys: dict, horizon: int, seconds: float) -> float:
    """Env-steps/s of `workers` processes stepping at the same time (start-up excluded: they start together)."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    barrier = ctx.Barrier(workers + 1)
    results = ctx.Manager().dict()
    procs = [
        ctx.Process(target=_worker, args=(policy_keys, horizon, seconds, barrier, results, i)) for i in range(workers)
    ]
    for proc in procs:
        proc.start()
    barrier.wait()
    t0 = time.perf_counter()
    for proc in procs:
        proc.join()
    if len(results) != workers:
        raise RuntimeError(f"{workers - len(results)} worker(s) failed")
    return sum(results.values()) / max(seconds, time.perf_counter() - t0)


def part_batch(kv: dict[str, str]) -> None:
    seconds = float(kv.get("batch_seconds", 6))
    horizon = int(kv.get("batch_horizon", 100))
    counts = [int(x) for x in kv.get("batch_workers", "[1,2,4,8]").strip("[]").split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        ckpt = make_checkpoint(folder, [4096, 4096, 4096], 1, "wide")
        _forward_cost(ckpt)
        with serve("policy=checkpoint", f"checkpoint={ckpt}", "batch=8", "batch_wait_ms=2") as port:
            for w in counts:
                own = _concurrent(w, {"policy": "checkpoint", "checkpoint": str(ckpt)}, horizon, seconds)
                shared = _concurrent(w, {"policy": "remote", "port": port, "timeout_s": 120.0}, horizon, seconds)
                print(
                    f"  {w} worker(s), {seconds:g} s each way: each with its own policy copy {own:.1f} env-steps/s, "
                    f"all sharing one batch=8 server {shared:.1f}: shared / own = {shared / own:.2f}   [load {load()}]"
                )


def _forward_cost(ckpt: Path) -> None:
    """One forward pass of the wide policy, batch 1 and batch 8, one torch thread (what a worker uses)."""
    import torch

    from baselines.checkpoint import load_policy

    torch.set_num_threads(1)
    policy = load_policy(ckpt)
    obs = [{"state": np.zeros(18, np.float32)}] * 8
    for n in (1, 8):
        policy.act_batch(obs[:n])
        t0 = time.perf_counter()
        for _ in range(20):
            policy.act_batch(obs[:n])
        ms = (time.perf_counter() - t0) / 20 * 1e3
        print(
            f"  wide MLP (3 x 4096, {os.path.getsize(ckpt) / 2**20:.0f} MiB): batch {n}: {ms:.2f} ms per forward pass"
        )


PARTS = {"remote": part_remote, "batch": part_batch}
