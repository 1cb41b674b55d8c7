"""How long calibrating a real 7-joint arm takes on one core: the Panda log of Gaz et al. (issue 25).

    python benchmarks/bench_arm_calibrate.py [repeats=3] [work=/tmp/bench_arm]

Imports the log once, then runs `bench calibrate spec=bench/calibrate/models/panda_gaz.yaml` in a fresh
process pinned to one CPU (`taskset -c 0`, numpy's BLAS at one thread) `repeats` times and prints the
wall and CPU seconds of each (the whole command: start-up, model build, data, fit, trace, bootstrap,
forward check, report), the machine's load before and after, and the calibration's own stage times.
Target: under 60 s.
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


def main() -> int:
    args = dict(a.split("=", 1) for a in sys.argv[1:])
    repeats, work = int(args.get("repeats", 3)), Path(args.get("work", "/tmp/bench_arm"))
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
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    pin = ["taskset", "-c", "0"] if shutil.which("taskset") else []
    print(f"load before: {os.getloadavg()}; pinned to one CPU: {bool(pin)}")
    rows = []
    for i in range(repeats):
        out = work / f"cal{i}"
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(
            [*pin, bench, "calibrate", f"spec={SPEC}", f"logs={work / 'logs'}", f"out={out}", "quiet=true"],
            check=True,
            capture_output=True,
            env=env,
        )
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        doc = json.loads((out / "calibration.json").read_text())
        rows.append((wall, cpu, doc))
        stages = ", ".join(f"{k} {v:.1f}" for k, v in doc["timing"].items())
        print(f"run {i + 1}: wall {wall:.1f} s, CPU {cpu:.1f} s (stages, s: {stages})")
    walls = sorted(r[0] for r in rows)
    tq = rows[0][2]["errors"]["torque"]
    print(f"load after: {os.getloadavg()}")
    print(
        f"Panda log, 7 joints, one core: wall min {walls[0]:.1f} s, median {walls[len(walls) // 2]:.1f} s "
        f"(target < 60 s: {'met' if walls[len(walls) // 2] < 60 else 'MISSED'}); held-out torque NRMSE "
        f"{tq['nominal']['nrmse']:.3g} -> {tq['final']['nrmse']:.3g}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
