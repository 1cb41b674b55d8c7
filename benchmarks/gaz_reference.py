"""Gaz et al.'s own identified Panda model, evaluated on our processed samples of the never-repeated stretch.

    python benchmarks/gaz_reference.py gaz=PATH [out=results/references/gaz_panda.json] [overwrite=false]

PATH is a clone of github.com/marcocognetti/FrankaEmikaPandaDynModel (GPL-3.0) at commit COMMIT. Their
model is their C++ code (mass matrix, Coriolis matrix, gravity vector and friction, with their identified
parameters written into it): this script compiles it here, with a driver of ours that reads samples on
stdin, in a temporary folder (g++ and Eigen 3 needed: `apt-get install g++ libeigen3-dev`), and never
copies a line of it into the project. The samples are ours: the real Panda log of ../shared processed
exactly as `bench calibrate spec=bench/calibrate/models/panda_gaz.yaml` processes it (uniform clock,
20 Hz zero-phase low-pass, accelerations from the filtered velocities, 200 Hz), and the rows are the
calibration's held-out rows (the stretch the excitation never repeats). Written: the torque their model
predicts on those rows, with provenance (their commit and the sha256 of every file compiled, the
compiler, our spec and processing, a checksum of the samples), so that a test and `baselines.real_panda`
score their model with the same code as ours, on the same samples, without the GPL code at test time.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.api import ConfigError  # noqa: E402
from bench.api.calibration import load_arm_log, load_arm_spec  # noqa: E402  (the checkout's bench, run as a script)
from bench.api.data import outputs, write_text_atomic  # noqa: E402
from bench.logs import import_csv  # noqa: E402

REPO = "https://github.com/marcocognetti/FrankaEmikaPandaDynModel"
COMMIT = "24d85ce4e648e2e894c832bfeee9b16711eb1a1a"
SOURCES = (
    "include/franka_model.h",
    "src/MassMatrix.cpp",
    "src/CoriolisMatrix.cpp",
    "src/GravityVector.cpp",
    "src/FrictionTorque.cpp",
)
LOG = ROOT.parent / "shared" / "data" / "real" / "panda_gaz" / "trajectory_1.csv"
SPEC = ROOT / "bench" / "calibrate" / "models" / "panda_gaz.yaml"
DRIVER = """// reads q(7) dq(7) ddq(7) per line; prints M(q) ddq + C(q, dq) dq + g(q) + f(dq), their model, per line
#include <iomanip>
#include <iostream>
#include "franka_model.h"
int main() {
  Eigen::Vector7d q, dq, ddq;
  std::cout << std::setprecision(17);
  for (;;) {
    for (int i = 0; i < 7; i++) if (!(std::cin >> q[i])) return 0;
    for (int i = 0; i < 7; i++) std::cin >> dq[i];
    for (int i = 0; i < 7; i++) std::cin >> ddq[i];
    Eigen::Vector7d tau = MassMatrix(q) * ddq + CoriolisMatrix(q, dq) * dq + GravityVector(q) + Friction(dq);
    for (int i = 0; i < 7; i++) std::cout << tau[i] << (i < 6 ? ' ' : '\\n');
  }
}
"""


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def build(gaz: Path, work: Path) -> tuple[Path, dict[str, str], str]:
    """Their sources compiled with our driver: (the binary, sha256 per source file, the compiler's version)."""
    src = gaz / "cpp" / "panda_dyn_model_example"
    missing = [s for s in SOURCES if not (src / s).is_file()]
    if missing:
        raise SystemExit(f"gaz={gaz}: not a clone of {REPO} (missing cpp/panda_dyn_model_example/{missing[0]})")
    head = subprocess.run(["git", "-C", str(gaz), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    if head and head != COMMIT:
        print(f"note: the clone is at {head[:12]}, the table's provenance names it (written for {COMMIT[:12]})")
    eigen = next((p for p in ("/usr/include/eigen3", "/usr/local/include/eigen3") if Path(p, "Eigen").is_dir()), None)
    if eigen is None or shutil.which("g++") is None:
        raise SystemExit("needs g++ and Eigen 3 (apt-get install g++ libeigen3-dev)")
    (work / "driver.cpp").write_text(DRIVER)
    objs = []
    for s in [*SOURCES[1:], "driver.cpp"]:
        obj = work / (Path(s).stem + ".o")
        path = work / s if s == "driver.cpp" else src / s
        subprocess.run(
            ["g++", "-O1", f"-I{eigen}", f"-I{src / 'include'}", "-c", str(path), "-o", str(obj)], check=True
        )
        objs.append(str(obj))
    binary = work / "gaz_model"
    subprocess.run(["g++", *objs, "-o", str(binary)], check=True)
    version = subprocess.run(["g++", "--version"], capture_output=True, text=True).stdout.splitlines()[0]
    return binary, {s: _sha(src / s) for s in SOURCES}, version


def main() -> int:
    args = dict(a.split("=", 1) for a in sys.argv[1:])
    if "gaz" not in args:
        print(__doc__)
        return 2
    if not LOG.is_file():
        print(f"the Panda log is missing ({LOG}); nothing written", file=sys.stderr)
        return 1
    try:  # checked before anything is built: never over or inside an input, a bench table replaced only on request
        out = outputs.check(
            "out",
            args.get("out", ROOT / "results" / "references" / "gaz_panda.json"),
            {"gaz": args["gaz"], "log": str(LOG), "spec": str(SPEC)},
            kind="file",
            overwrite=args.get("overwrite", "false") == "true",
        )
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    spec = load_arm_spec(SPEC)
    cols = {
        "state": [f"q{i}" for i in range(1, 8)],
        "velocity": [f"dq{i}" for i in range(1, 8)],
        "effort": [f"tau{i}" for i in range(1, 8)],
    }
    ds = import_csv(LOG, time="time_s", resample=1000.0, **cols)
    data = load_arm_log(spec, [e.data for e in ds.episodes], float(ds.fps), seed=0)
    rows = np.flatnonzero(data.hold)
    with tempfile.TemporaryDirectory() as tmp:
        binary, shas, compiler = build(Path(args["gaz"]).expanduser(), Path(tmp))
        lines = "\n".join(" ".join(f"{v:.17g}" for v in r) for r in np.hstack([data.q, data.dq, data.ddq])[rows])
        res = subprocess.run([str(binary)], input=lines, capture_output=True, text=True, check=True)
    tau = np.array([[float(x) for x in ln.split()] for ln in res.stdout.strip().splitlines()])
    assert tau.shape == (len(rows), 7), tau.shape
    doc = {
        "schema": "bench.reference/1",
        "what": "Gaz et al.'s identified Panda model (RA-L 2019): predicted joint torque on the held-out rows of "
        "bench calibrate's processing of ../shared/data/real/panda_gaz/trajectory_1.csv",
        "provenance": {
            "repository": REPO,
            "commit": COMMIT,
            "license": "GPL-3.0 (their code was compiled and run here, not copied; only its outputs are stored)",
            "files_sha256": shas,
            "compiler": compiler,
            "model": "tau = M(q) ddq + C(q, dq) dq + g(q) + f(dq), their functions MassMatrix, CoriolisMatrix, "
            "GravityVector, Friction",
            "log_sha256": _sha(LOG),
            "spec": spec.to_json(),
            "made_by": "python benchmarks/gaz_reference.py gaz=PATH",
        },
        "samples": {
            "rate_hz": data.rate,
            "rows": len(rows),
            "t_first": float(data.t[rows[0]]),
            "t_last": float(data.t[rows[-1]]),
            "heldout": data.heldout.to_json(),
            "checksum_q_mean": data.q[rows].mean(axis=0).tolist(),  # that the samples are still ours
        },
        "t": np.round(data.t[rows], 6).tolist(),
        "tau": np.round(tau, 6).tolist(),
    }
    write_text_atomic(out, json.dumps(doc) + "\n")  # compact: two long arrays
    print(f"wrote {out}: {len(rows)} rows, t {doc['samples']['t_first']:.3f}-{doc['samples']['t_last']:.3f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
