"""Wall and CPU time of the whole Real2Sim loop on one core, before and after, measured in one run.

    python benchmarks/bench_calibrate.py [case=all|emps|arm] [effects=[coulomb_friction,...]|all]
                                         [before=REV|none] [repeats=1]

Both sides calibrate the same logs, each in a fresh subprocess pinned to one CPU (sched_setaffinity,
one BLAS thread, one rollout thread), interleaved case by case so that load from other processes
hits both alike:

  - before: the code of git revision REV (default 5fddacd, the code issue 19 measured: 6-36 s per
    3-joint case, ~18 s on EMPS), extracted with `git archive` into a temporary folder;
  - after:  this checkout.

Timed is `bench.calibrate.trace.calibrate_episodes` alone (`run` in older revisions): declared fit, trace
rounds, refits, held-out errors; reading the logs and importing happen before the clock starts. Cases:

  - emps: the EMPS estimation run (24,841 frames at 1 kHz, last 30% held out), imported from
    ../shared/data/real/emps/DATA_EMPS.mat; target < 5 s.
  - arm: 8 episodes x 6 s at 100 Hz of the 3-joint arm of `bench calibrate generate` with one hidden
    effect, for each effect in `effects` (default: all of the library and none); target < 10 s.
    The logs and declared model come from this checkout's generator; the before code searches its
    own library (without the spring's rest position and the position-play backlash families).

Each line gives wall and CPU seconds of both sides, their ratio, what each added and the held-out
free-run NRMSE it reached; a summary gives the slowest case and the median ratio. The targets are
judged on CPU seconds: each side runs on one core, and on a shared machine the wall clock also
counts the time that core spent on other processes (wall is printed beside it).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
BEFORE = "5fddacd"  # the code as issue 19 found it
TARGETS = {"emps": 5.0, "arm": 10.0}

# run in the subprocess: `python -c DRIVER TREE SPEC LOGS` -> one JSON line on stdout
DRIVER = r"""
import json, os, sys, time
os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[-1]})
sys.path.insert(0, sys.argv[1])
from bench.calibrate.spec import load_spec
try:
    from bench.calibrate.trace import calibrate_episodes
except ImportError:  # a revision from before the rename
    from bench.calibrate.trace import run as calibrate_episodes
from bench.logs import read_dataset
assert sys.modules["bench"].__file__.startswith(sys.argv[1]), sys.modules["bench"].__file__
spec = load_spec(sys.argv[2])
ds = read_dataset(sys.argv[3])
episodes = [ep.data for ep in ds.episodes]
w0, c0 = time.perf_counter(), time.process_time()
cal = calibrate_episodes(spec, episodes, float(ds.fps), seed=0, threads=1)
wall, cpu = time.perf_counter() - w0, time.process_time() - c0
e = cal.errors
print(json.dumps({"wall": wall, "cpu": cpu, "added": [a["name"] + "@" + a["target"] for a in cal.added],
                  "declared": e["declared"]["free_run_nrmse"], "final": e["final"]["free_run_nrmse"],
                  "final_rmse": e["final"]["free_run_rmse"], "steps": cal.wall.get("sim_steps")}))
"""


def extract(rev: str, into: Path) -> Path:
    """The `bench` package of git revision `rev`, unpacked under `into`."""
    archive = into / "before.tar"
    with open(archive, "wb") as f:
        subprocess.run(["git", "-C", str(REPO), "archive", rev, "bench"], stdout=f, check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(into / "tree", filter="data")
    return into / "tree"


def measure(tree: Path, spec: Path, logs: Path) -> dict:
    env = {
        **os.environ,
        "OMP_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "PYTHONPATH": str(tree),
    }
    out = subprocess.run(
        [sys.executable, "-c", DRIVER, str(tree), str(spec), str(logs)],
        env=env,
        capture_output=True,
        text=True,
        cwd=tree,
    )
    if out.returncode != 0:
        raise RuntimeError(f"calibration in {tree} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def fmt(r: dict) -> str:
    added = ", ".join(r["added"]) or "nothing"
    return f"{r['wall']:6.2f} s wall {r['cpu']:6.2f} s cpu  [{added}; free-run NRMSE {r['final']:.4g}]"


def cases(kind: str, effects: list[str], tmp: Path) -> list[tuple[str, str, Path, Path]]:
    """(label, kind, spec, logs) of each case, written under `tmp`."""
    out = []
    if kind in ("all", "emps"):
        mat = SHARED / "data/real/emps/DATA_EMPS.mat"
        if mat.is_file():
            from bench.calibrate.generate import MODELS
            from bench.logs import import_mat, write_dataset

            ds = import_mat(mat, {"observation.state": ["qm"], "action": ["vir"]})
            write_dataset(tmp / "emps", ds)
            out.append(("emps", "emps", MODELS / "emps.yaml", tmp / "emps"))
        else:
            print(f"emps: skipped, {mat} not found (../shared is only beside the checkout)")
    if kind in ("all", "arm"):
        from bench.calibrate.generate import write_case

        for effect in effects:
            case = write_case(
                tmp / f"arm-{effect}", None if effect == "none" else effect, episodes=8, duration=6.0, fps=100.0, seed=0
            )
            out.append((f"arm {effect}", "arm", case / "spec.yaml", case / "logs"))
    return out


@dataclass(frozen=True)
class Args:
    """Keys of this benchmark (key=value)."""

    case: str = "all"  # all | emps | arm
    effects: Any = "all"  # arm cases: all, one effect name, or a list [a,b]
    before: str = BEFORE  # the git revision timed as "before" (none = only this checkout)
    repeats: int = 1  # best of this many timings


def main(argv: list[str]) -> int:
    from bench.calibrate.effects import EFFECTS
    from bench.core.config import build_from_argv

    args: Args = build_from_argv(Args, argv, "python benchmarks/bench_calibrate.py")
    kind = args.case
    if kind not in ("all", "emps", "arm"):
        print(f"error: case is {kind!r}; valid: all, emps, arm", file=sys.stderr)
        return 2
    effects = args.effects
    effects = [*EFFECTS, "none"] if effects == "all" else list(effects) if not isinstance(effects, str) else [effects]
    before, repeats = args.before, args.repeats
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        trees = {"after": REPO}
        if before != "none":
            trees = {"before": extract(before, tmp), **trees}
        todo = cases(kind, effects, tmp)
        print(
            f"one core each (rollout threads 1, BLAS threads 1); before = {before}, after = this checkout; "
            f"best of {repeats}"
        )
        rows = []
        for label, k, spec, logs in todo:
            best: dict[str, dict] = {}
            for _ in range(repeats):
                for side, tree in trees.items():
                    r = measure(tree, spec, logs)
                    if side not in best or r["wall"] < best[side]["wall"]:
                        best[side] = r
            rows.append((label, k, best))
            verdict = "ok" if best["after"]["cpu"] < TARGETS[k] else "MISSED"
            print(f"{label}  (target < {TARGETS[k]:g} s on one core: {verdict})")
            for side, r in best.items():
                print(f"  {side:6s} {fmt(r)}")
            if "before" in best:
                print(
                    f"  speed-up x{best['before']['wall'] / best['after']['wall']:.2f} wall, "
                    f"x{best['before']['cpu'] / best['after']['cpu']:.2f} cpu"
                )
    for k in ("emps", "arm"):
        mine = [(label, b) for label, kk, b in rows if kk == k]
        if not mine:
            continue
        worst = max(mine, key=lambda lb: lb[1]["after"]["cpu"])
        line = f"{k}: slowest after {worst[1]['after']['cpu']:.2f} cpu-s ({worst[0]}; target < {TARGETS[k]:g} s)"
        if "before" in worst[1]:
            ratios = [b["before"]["cpu"] / b["after"]["cpu"] for _, b in mine]
            slowest = max(mine, key=lambda lb: lb[1]["before"]["cpu"])
            line += (
                f"; slowest before {slowest[1]['before']['cpu']:.2f} cpu-s ({slowest[0]}); median speed-up "
                f"x{statistics.median(ratios):.2f} (cpu) over {len(mine)} case(s)"
            )
        print(line)
    return 0


if __name__ == "__main__":
    from bench.core.guard import guarded  # bad keys: one line, exit 2, as bench's commands

    raise SystemExit(guarded(lambda: main(sys.argv[1:])))
