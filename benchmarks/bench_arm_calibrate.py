"""How long calibrating a real 7-joint arm takes: the Panda log of Gaz et al., as a user runs the command.

    python benchmarks/bench_arm_calibrate.py [repeats=3] [load=2] [work=/tmp/bench_arm]

Imports the log once, then runs `bench calibrate spec=bench/calibrate/models/panda_gaz.yaml` with its
defaults (the whole command: start-up, model build, data, held-out choice, fit, trace, DIDIM, forward
checks, bootstrap, report) `repeats` times in each of three settings, interleaved:

- `user, quiet`: the command as a user types it (no pinning, no thread variables);
- `user, loaded`: the same beside `load` busy processes (`python -c "while True: pass"`), the machine
  a new user tried it on (2 cores at load 3);
- `one core`: pinned to one CPU (`taskset -c 0`).

and prints each run's wall and CPU seconds and the machine's load. CPU close to wall means one thread
(the command holds numpy's and scipy's BLAS to one: `bench.core.threads`). Target: under 60 s.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOG = ROOT.parent / "shared" / "data" / "real" / "panda_gaz" / "trajectory_1.csv"
SPEC = ROOT / "bench" / "calibrate" / "models" / "panda_gaz.yaml"
COLS = "state=[q1,q2,q3,q4,q5,q6,q7] velocity=[dq1,dq2,dq3,dq4,dq5,dq6,dq7] effort=[tau1,tau2,tau3,tau4,tau5,tau6,tau7]"


def _run(bench: str, work: Path, name: str, pin: list[str]) -> tuple[float, float, dict]:
    out = work / name
    shutil.rmtree(out, ignore_errors=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(
        [*pin, bench, "calibrate", f"spec={SPEC}", f"logs={work / 'logs'}", f"out={out}", "quiet=true"],
        check=True,
        capture_output=True,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, json.loads((out / "calibration.json").read_text())


def main() -> int:
    args = dict(a.split("=", 1) for a in sys.argv[1:])
    repeats, load = int(args.get("repeats", 3)), int(args.get("load", 2))
    work = Path(args.get("work", "/tmp/bench_arm"))
    if not LOG.is_file():
        print(f"the Panda log is missing ({LOG}); nothing measured", file=sys.stderr)
        return 1
    bench = str(Path(sys.executable).with_name("bench"))
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    subprocess.run(
        [bench, "logs", "import", str(LOG), f"out={work / 'logs'}", "time=time_s", *COLS.split(), "resample=1000"],
        check=True,
        capture_output=True,
    )
    pin = ["taskset", "-c", "0"] if shutil.which("taskset") else []
    settings = [("user, quiet", [], 0), ("user, loaded", [], load), ("one core", pin, 0)]
    results: dict[str, list[tuple[float, float, float, float]]] = {s[0]: [] for s in settings}
    doc: dict = {}
    for i in range(repeats):
        for name, prefix, busy in settings:
            hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
            try:
                time.sleep(1.0 if busy else 0.0)
                l0 = os.getloadavg()[0]
                wall, cpu, doc = _run(bench, work, f"cal{i}", prefix)  # the command's own CPU (its wait alone)
                l1 = os.getloadavg()[0]
            finally:
                for h in hogs:  # reaped now, so that no busy process's CPU is counted as a later run's
                    h.kill()
                    h.wait()
            results[name].append((wall, cpu, l0, l1))
            print(f"run {i + 1}, {name}: wall {wall:.1f} s, CPU {cpu:.1f} s, load {l0:.1f} -> {l1:.1f}")
    stages = ", ".join(f"{k} {v:.1f}" for k, v in doc.get("timing", {}).items())
    print(f"stages of the last run (s): {stages}")
    for name, rows in results.items():
        walls = sorted(r[0] for r in rows)
        cpus = sorted(r[1] for r in rows)
        med = walls[len(walls) // 2]
        print(
            f"{name}: wall median {med:.1f} s (min {walls[0]:.1f}, max {walls[-1]:.1f}), CPU median "
            f"{cpus[len(cpus) // 2]:.1f} s; target < 60 s: {'met' if med < 60 else 'MISSED'}"
        )
    tq = doc["errors"]["torque"]
    print(f"held-out torque NRMSE {tq['nominal']['nrmse']:.3g} -> {tq['final']['nrmse']:.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
