"""Both calibration methods side by side: time, held-out error (with an interval) and effects found.

    python benchmarks/bench_calibrate_gradient.py [case=all|arm|emps|panda] [effects=[viscous_damping,...]]
        [panda_effects=[payload_mass,bias,...]]

For each case the same spec and logs are calibrated twice in this process, by `method=least_squares`
(finite-difference Jacobians on CPU MuJoCo) and by `method=gradient` (MJX gradients, L-BFGS-B), and
one line per method gives the wall time (the gradient line also its compile time, which JAX's disk
cache, `$BENCH_JAX_CACHE`, removes on a second run), the effects added, the held-out free-run NRMSE
and the held-out k-step error with a 95% bootstrap interval over held-out windows. The verdict says
whether the gradient fit's k-step error is within (or below) the least-squares interval and whether
both found the same effects. Cases:

  - arm: `bench calibrate generate` 3-joint arm cases (4 episodes x 3 s at 100 Hz) with one hidden effect
    each (default: viscous_damping, payload_mass, coulomb_friction), the whole effect library searched;
  - emps: the EMPS log (../shared/data/real/emps/DATA_EMPS.mat) with bench/calibrate/models/emps.yaml;
  - panda: the real Panda log (../shared/data/real/panda_gaz, GPL: read at run time, never copied),
    linearly resampled to 2 ms and driven by the measured joint torques on robosuite's Panda as a
    dynamics-only model built at run time (bench.sims.panda_dynamics); declared per-joint damping and
    armature and one mass scale over the links, 100-step windows, the last 30% of time held out, no
    effect search unless `panda_effects=[...]` names effect families to search (bench.calibrate.effects).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
PANDA_CSV = SHARED / "data/real/panda_gaz/trajectory_1.csv"
EMPS_MAT = SHARED / "data/real/emps/DATA_EMPS.mat"
ARM_EFFECTS = ("viscous_damping", "payload_mass", "coulomb_friction")
PANDA_DT = 0.002  # s: the Panda log resampled onto this grid (linear interpolation), one physics step per frame


@dataclass(frozen=True)
class Keys:
    """Keys of this benchmark."""

    case: str = "all"  # all | arm | emps | panda
    effects: Optional[list[str]] = (
        None  # arm cases' hidden effects (default: viscous_damping, payload_mass, coulomb_friction)
    )
    panda_effects: Optional[list[str]] = None  # effect families searched on the real Panda (default: none)


def arm_case(effect: str, tmp: Path) -> tuple[Path, Path]:
    """A generated 3-joint arm case: (spec, logs)."""
    from bench.calibrate.generate import write_case

    folder = tmp / f"arm_{effect}"
    write_case(folder, effect, episodes=4, duration=3.0, fps=100.0, seed=0)
    return folder / "spec.yaml", folder / "logs"


def emps_case(tmp: Path) -> tuple[Path, Path]:
    from bench.calibrate.generate import MODELS
    from bench.logs import import_mat, write_dataset

    write_dataset(tmp / "emps", import_mat(EMPS_MAT, {"observation.state": ["qm"], "action": ["vir"]}))
    return MODELS / "emps.yaml", tmp / "emps"


def panda_case(
    tmp: Path, seconds: float | None = None, horizon: float = 0.2, effects: list[str] | None = None
) -> tuple[Path, Path]:
    """The Panda log resampled to 2 ms (first `seconds` of it), its spec (windows of `horizon` s, the effect
    library `effects` searched, none by default) and the dynamics-only model, in `tmp`."""
    from bench.logs import import_csv, write_dataset
    from bench.sims import panda_dynamics

    raw = np.genfromtxt(PANDA_CSV, delimiter=",", names=True)
    t = raw["time_s"]
    end = t[-1] if seconds is None else min(t[-1], seconds)
    grid = np.arange(0.0, end, PANDA_DT)
    cols = [f"{p}{i}" for p in ("q", "dq", "tau") for i in range(1, 8)]
    table = np.column_stack([grid] + [np.interp(grid, t, raw[c]) for c in cols])
    csv = tmp / "panda_resampled.csv"
    np.savetxt(csv, table, delimiter=",", header=",".join(["time_s", *cols]), comments="", fmt="%.9g")
    ds = import_csv(csv, time="time_s", state=cols[:14], action=cols[14:])
    write_dataset(tmp / "panda_logs", ds)
    panda_dynamics.write(tmp, timestep=PANDA_DT)
    joints = list(panda_dynamics.JOINTS)
    links = [f"link{i}" for i in range(1, 8)]
    spec = tmp / "panda_spec.yaml"
    spec.write_text(
        "model: panda_dynamics.xml\nsubsteps: 1\n"
        "signals:\n"
        "  qpos: {column: observation.state, index: [0, 1, 2, 3, 4, 5, 6]}\n"
        "  qvel: {column: observation.state, index: [7, 8, 9, 10, 11, 12, 13]}\n"
        "  ctrl: {column: action, index: [0, 1, 2, 3, 4, 5, 6]}\n"
        "params:\n"
        f"  - {{name: damping, field: dof_damping, elements: [{', '.join(joints)}], bounds: [0, 5]}}\n"
        f"  - {{name: armature, field: dof_armature, elements: [{', '.join(joints)}], bounds: [0, 1]}}\n"
        f"  - {{name: link_mass, field: body_mass, elements: [{', '.join(links)}], bounds: [0.5, 2], scale: true}}\n"
        f"effects: {'[' + ', '.join(effects) + ']' if effects else 'none'}\nholdout: 0.3\nhorizon: {horizon}\n"
    )
    return spec, tmp / "panda_logs"


def kstep_interval(cal, seed: int = 0, n_boot: int = 2000) -> tuple[float, float, float]:
    """Held-out k-step error (mean squared normalised residual per window) and its 95% bootstrap interval."""
    grid = cal.residual["final"]  # (windows, k, channels), zero where masked
    per_window = (grid**2).reshape(len(grid), -1).mean(axis=1)
    rng = np.random.default_rng(seed)
    boots = per_window[rng.integers(0, len(per_window), size=(n_boot, len(per_window)))].mean(axis=1)
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return float(per_window.mean()), float(lo), float(hi)


def calibrate(spec: Path, logs: Path, method: str) -> dict:
    """One calibration by `method`: wall time, effects, held-out errors and the interval."""
    from bench.calibrate.gradient import GradientFitter
    from bench.calibrate.spec import load_spec
    from bench.calibrate.trace import calibrate_episodes
    from bench.logs import read_dataset

    s = load_spec(spec)
    ds = read_dataset(logs)
    kw = {}
    fitter = None
    if method == "gradient":
        fitter = GradientFitter()
        kw["fitter"] = fitter
    t0 = time.perf_counter()
    cal = calibrate_episodes(s, [ep.data for ep in ds.episodes], float(ds.fps), seed=0, threads=1, **kw)
    wall = time.perf_counter() - t0
    err, lo, hi = kstep_interval(cal)
    return {
        "wall": wall,
        "compile": fitter.stats.compile_s if fitter else 0.0,
        "fallbacks": fitter.stats.fallbacks if fitter else 0,
        "added": sorted(f"{a['name']}@{a['target']}" for a in cal.added),
        "free_run": cal.errors["final"]["free_run_nrmse"],
        "declared_free_run": cal.errors["declared"]["free_run_nrmse"],
        "kstep": err,
        "interval": (lo, hi),
        "x": cal.final_fit.x,
        "labels": cal.final_fit.labels,
    }


def compare(name: str, spec: Path, logs: Path) -> bool:
    ls = calibrate(spec, logs, "least_squares")
    gd = calibrate(spec, logs, "gradient")
    for label, r in (("least_squares", ls), ("gradient", gd)):
        extra = (
            f" (compile {r['compile']:.1f} s, {r['fallbacks']} fits by least squares)" if label == "gradient" else ""
        )
        print(
            f"{name:22s} {label:13s} {r['wall']:7.1f} s{extra}  effects: {', '.join(r['added']) or 'none'}; "
            f"held-out free-run NRMSE {r['declared_free_run']:.4g} -> {r['free_run']:.4g}; k-step error "
            f"{r['kstep']:.4g} [{r['interval'][0]:.4g}, {r['interval'][1]:.4g}]",
            flush=True,
        )
    within = gd["kstep"] <= ls["interval"][1]
    same = gd["added"] == ls["added"]
    print(
        f"{name:22s} verdict: gradient k-step error {'within/below' if within else 'ABOVE'} the least-squares "
        f"interval; effects {'the same' if same else 'DIFFER'}; time ratio gradient/least-squares "
        f"{gd['wall'] / ls['wall']:.2f} (without compile {(gd['wall'] - gd['compile']) / ls['wall']:.2f})",
        flush=True,
    )
    if name == "panda":
        for lab, a, b in zip(ls["labels"], ls["x"], gd["x"]):
            print(f"    {lab:22s} least squares {a:9.4g}   gradient {b:9.4g}")
    return within and same


def main(argv: list[str]) -> int:
    from bench.core.config import build_from_argv
    from bench.sims import mjx as mjx_backend

    cfg = build_from_argv(Keys, argv, "bench_calibrate_gradient")
    case, effects = cfg.case, cfg.effects
    mjx_backend.require()
    print(f"device: {mjx_backend.device()}; load {open('/proc/loadavg').read().split()[:3]}; {os.cpu_count()} CPUs")
    ok = True
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if case in ("all", "arm"):
            for eff in effects or ARM_EFFECTS:
                ok &= compare(f"arm {eff}", *arm_case(eff, tmp))
        if case in ("all", "emps"):
            if EMPS_MAT.exists():
                ok &= compare("emps", *emps_case(tmp))
            else:
                print(f"emps: skipped, {EMPS_MAT} not found")
        if case in ("all", "panda"):
            if PANDA_CSV.exists():
                ok &= compare("panda", *panda_case(tmp, effects=cfg.panda_effects))
            else:
                print(f"panda: skipped, {PANDA_CSV} not found")
    print(f"load at the end {open('/proc/loadavg').read().split()[:3]}")
    return 0 if ok else 1


if __name__ == "__main__":
    from bench.core.guard import guarded  # bad keys or a bad spec (panda_effects=[nosuch]): one line, exit 2

    raise SystemExit(guarded(lambda: main(sys.argv[1:])))
