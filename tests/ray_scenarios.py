"""Ray scenarios run inside a loopback-only namespace (tests/ray_sandbox.py); facts go to OUT/facts.json.

    python -m tests.ray_scenarios basics|faults|driver_kill OUT

Each scenario starts its own cluster on 127.0.0.1, drives `bench run` as a user would (a
subprocess per run), and writes what it saw; tests/test_ray_executor.py asserts on it.
Nothing here asserts, so a failing check reads as a normal pytest failure.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from tests.ray_sandbox import REPO, Cluster, free_port

TOY = "suite=tests.toy_suite:ToySuite"


def bench(
    out: Path, run_id: str, *args: str, env: dict[str, str] | None = None, timeout: float = 300, cwd: Path = REPO
) -> dict[str, Any]:
    t0 = time.time()
    res = subprocess.run(
        [sys.executable, "-m", "bench", "run", *args, f"out={out}", f"run_id={run_id}"],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, **(env or {})},
    )
    return {"rc": res.returncode, "stderr": res.stderr[-4000:], "seconds": round(time.time() - t0, 2)}


def session_processes(sid: int) -> list[str]:
    """`pid state ppid=PPID command` of every process in session `sid` (from /proc; `[name]` for one that exited)."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()  # state ppid pgrp session ...
            if int(fields[3]) != sid:
                continue
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")[:200]
            cmd = cmd or f"[{(entry / 'comm').read_text().strip()}]"  # an exited process keeps only its name
        except (OSError, IndexError, ValueError):
            continue
        out.append(f"{entry.name} {fields[0]} ppid={fields[1]} {cmd}")
    return out


def leftovers(out: Path, run_id: str, *args: str) -> dict[str, Any]:
    """`bench run` in a session of its own; the processes still in that session the moment it has exited.

    stderr goes to a file, not a pipe: waiting for a pipe's end would wait for every process holding it.
    """
    with open(out / f"{run_id}.stderr", "w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "bench", "run", *args, f"out={out}", f"run_id={run_id}"],
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=err,
            start_new_session=True,
        )
        rc = proc.wait(timeout=300)
    # an exited process handed to init (state Z, ppid 1) holds nothing and init reaps it when it gets to it
    # (this machine's init can take seconds under load); a live process, or a zombie whose parent lives, counts
    left = [p for p in session_processes(proc.pid) if " Z ppid=1 [" not in p]
    return {"rc": rc, "left": left, "stderr": (out / f"{run_id}.stderr").read_text()[-4000:]}


def records(out: Path, run_id: str) -> list[dict[str, Any]]:
    path = out / run_id / "episodes.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []


def start_bg(out: Path, run_id: str, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "bench", "run", *args, f"out={out}", f"run_id={run_id}"],
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=open(out / f"{run_id}.stderr", "w"),
        start_new_session=True,
    )


def wait_records(out: Path, run_id: str, n: int, proc: subprocess.Popen, timeout: float = 240) -> int:
    deadline = time.time() + timeout
    while time.time() < deadline and proc.poll() is None:
        k = len(records(out, run_id))
        if k >= n:
            return k
        time.sleep(0.05)
    return len(records(out, run_id))


def basics(out: Path) -> dict[str, Any]:
    facts: dict[str, Any] = {}
    # before any cluster exists: ray_address=auto and a closed port
    facts["auto_none"] = bench(out, "auto", TOY, "executor=ray", "ray_address=auto")
    facts["closed_port"] = bench(out, "closed", TOY, "executor=ray", f"ray_address=127.0.0.1:{free_port()}")
    port = free_port()  # something that is not Ray listening there (checked while the cluster starts)
    http = subprocess.Popen(
        [sys.executable, "-m", "http.server", str(port), "--bind", "127.0.0.1"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    time.sleep(1)
    not_ray = threading.Thread(
        target=lambda: facts.update(not_ray=bench(out, "notray", TOY, "executor=ray", f"ray_address=127.0.0.1:{port}"))
    )
    not_ray.start()
    with Cluster(head_cpus=2, log_dir=out) as cluster:
        not_ray.join()
        http.kill()
        ray = ["executor=ray", f"ray_address={cluster.address}"]
        facts["ray"] = bench(out, "ray", TOY, "episodes=4", "step_delay=0.01", "actors=2", *ray)
        facts["local"] = bench(out, "local", TOY, "episodes=4", "step_delay=0.01", "workers=2")
        facts["hang"] = bench(out, "hang", TOY, "episodes=2", "fault=hang", "timeout=0.5", "actors=2", *ray)
        facts["raise"] = bench(out, "raise", TOY, "episodes=2", "fault=raise", "actors=2", *ray)
        # record=: trajectories written on the actors' nodes travel back to the driver's dataset
        facts["rec_ray"] = bench(out / "rray", "rec", TOY, "episodes=2", "actors=2", f"record={out / 'ds_ray'}", *ray)
        facts["rec_local"] = bench(out / "rlocal", "rec", TOY, "episodes=2", "workers=2", f"record={out / 'ds_local'}")
        # a plugin the driver imports from its PYTHONPATH, which the cluster's nodes do not have
        plugins = out / "plugins"
        plugins.mkdir()
        shutil.copy(REPO / "tests" / "toy_suite.py", plugins / "toyplug.py")
        env = {"PYTHONPATH": str(plugins)}
        facts["plugin_installed"] = bench(
            out,
            "plug_installed",
            "suite=toyplug:ToySuite",
            "episodes=1",
            "actors=2",
            "ray_env=installed",
            *ray,
            env=env,
        )
        facts["plugin_code"] = bench(
            out, "plug_code", "suite=toyplug:ToySuite", "episodes=1", "actors=2", "ray_env=code", *ray, env=env
        )
        facts["mismatch"] = mismatch(out, cluster.address)
        facts["no_gpu"] = bench(out, "nogpu", TOY, "actor_gpus=1", *ray)
    facts["private"] = leftovers(out, "private", TOY, "episodes=1", "executor=ray", "ray_address=local", "actors=1")
    for run_id in ("ray", "local", "hang", "raise", "plug_code", "private"):
        facts[f"records_{run_id}"] = records(out, run_id)
        summary = out / run_id / "summary.json"
        facts[f"summary_{run_id}"] = json.loads(summary.read_text()) if summary.exists() else None
    return facts


def mismatch(out: Path, address: str) -> dict[str, Any]:
    """A cluster whose workers see another mujoco: a dist-info reporting 0.0.1 first on their path."""
    from bench import api
    from bench.core.errors import BenchError
    from bench.execution.ray_executor import RayExecutor

    fake = out / "fake_site" / "mujoco-0.0.1.dist-info"
    fake.mkdir(parents=True)
    (fake / "METADATA").write_text("Metadata-Version: 2.1\nName: mujoco\nVersion: 0.0.1\n")
    cfg = api.RunConfig(
        suite="tests.toy_suite:ToySuite",
        policy="scripted",
        episodes=1,
        out=str(out),
        run_id="mismatch",
        executor="ray",
        ray_address=address,
        actors=1,
    )
    executor = RayExecutor(address, actors=1, runtime_env={"env_vars": {"PYTHONPATH": str(fake.parent)}})
    try:
        api.run(cfg, executor=executor)
    except BenchError as exc:
        return {"error": str(exc), "written": sorted(p.name for p in (out / "mismatch").glob("*"))}
    return {"error": None}


def faults(out: Path) -> dict[str, Any]:
    """A worker process killed, then a whole node killed, mid-run; then the same run on local workers."""
    facts: dict[str, Any] = {}
    slow = [TOY, "episodes=8", "step_delay=0.04"]
    with Cluster(head_cpus=1, log_dir=out) as cluster:
        node2 = cluster.add_node(cpus=1)
        ray = ["executor=ray", f"ray_address={cluster.address}", "actors=2"]
        # 1. one actor's process killed: its in-flight episodes go to a replacement
        proc = start_bg(out, "worker_kill", *slow, *ray)
        wait_records(out, "worker_kill", 3, proc)
        victim = records(out, "worker_kill")[-1]["worker_pid"]
        os.kill(victim, signal.SIGKILL)
        facts["worker_kill"] = {
            "rc": proc.wait(300),
            "victim": victim,
            "stderr": (out / "worker_kill.stderr").read_text()[-3000:],
        }
        # 2. the second node killed (raylet, object store, its workers): its episodes finish on the head
        proc = start_bg(out, "node_kill", *slow, *ray)
        wait_records(out, "node_kill", 4, proc)
        pids_on_node2 = {r["worker_pid"] for r in records(out, "node_kill")}
        killed = cluster.kill_node(node2)
        facts["node_kill"] = {
            "rc": proc.wait(300),
            "killed": killed,
            "node2_ran": sorted(pids_on_node2 & set(killed)),
            "stderr": (out / "node_kill.stderr").read_text()[-3000:],
        }
    facts["local"] = bench(out, "local", *slow, "workers=2")
    for run_id in ("worker_kill", "node_kill", "local"):
        facts[f"records_{run_id}"] = records(out, run_id)
    return facts


def driver_kill(out: Path) -> dict[str, Any]:
    """kill -9 of the driver's process group mid-run; the same command again resumes it."""
    facts: dict[str, Any] = {}
    args = [TOY, "episodes=10", "step_delay=0.03"]
    with Cluster(head_cpus=2, log_dir=out) as cluster:
        ray = ["executor=ray", f"ray_address={cluster.address}", "actors=2"]
        proc = start_bg(out, "k", *args, *ray)
        facts["before_kill"] = wait_records(out, "k", 6, proc)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        facts["after_kill"] = len(records(out, "k"))
        facts["resume"] = bench(out, "k", *args, *ray)
    facts["local"] = bench(out, "whole", *args, "workers=2")
    facts["records_k"] = records(out, "k")
    facts["records_whole"] = records(out, "whole")
    return facts


SCENARIOS = {"basics": basics, "faults": faults, "driver_kill": driver_kill}

if __name__ == "__main__":
    name, out_dir = sys.argv[1], Path(sys.argv[2])
    out_dir.mkdir(parents=True, exist_ok=True)
    result = SCENARIOS[name](out_dir)
    (out_dir / "facts.json").write_text(json.dumps(result, indent=1))
