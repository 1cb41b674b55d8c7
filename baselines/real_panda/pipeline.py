"""The steps of `python -m baselines.real_panda` (see the package's docstring): calibrate, compare, run, write."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

import baselines.real_panda as real_panda  # the package: its docstring is the --help text
from baselines import bc
from baselines.real_panda.args import JOINT_COLS, POLICIES, REFERENCE, SPEC, SWEEP_AXES, Args
from baselines.real_panda.friction import friction_table
from baselines.real_panda.readme import readme
from bench import api
from bench.api.calibration import calibrate_arm, load_arm_spec, score_reference, write_arm_report
from bench.api.data import outputs, portable, write_atomic
from bench.api.datasets import import_csv, read_dataset, write_dataset
from bench.api.scripts import build_from_argv, command_help, guarded
from bench.api.stats import Outcome, agreement, paired_gap


def train_small_bc(a: Args, work: Path) -> Path:
    """A second, weaker behaviour-cloning policy: 8 scripted demonstrations per seen arm, a small MLP."""
    demos = work / "demos"
    for old in (demos, work / "runs" / "demos-small"):
        if old.exists():
            shutil.rmtree(old)
    api.run(
        api.RunConfig(
            suite="held_out_robots",
            policy="scripted",
            splits=["seen"],
            episodes=8,
            seed=100,
            workers=a.workers,
            out=str(work / "runs"),
            run_id="demos-small",
            record=str(demos),
        ),
        progress=True,
    )
    path, _ = bc.train(
        bc.Args(
            data=[str(demos)],
            out=str(work / "bc_small" / "policy.safetensors"),
            hidden=[64, 64],
            overwrite=True,
            seed=0,
        )
    )
    return path


def drop_stale(run_dir: Path, cal_dir: Path) -> None:
    """A calibrated run recorded with an earlier fit is another robot: start it again (bench refuses to mix)."""
    meta = run_dir / "run.json"
    if not meta.is_file():
        return
    sha = hashlib.sha256((cal_dir / "calibration.json").read_bytes()).hexdigest()
    if json.loads(meta.read_text()).get("provenance", {}).get("calibration", {}).get("sha256") != sha:
        print(f"{run_dir.name}: recorded with an earlier calibration; running it again")
        shutil.rmtree(run_dir)


def run_population(a: Args, work: Path, cal_dir: Path, small_bc: Path) -> dict[str, Any]:
    rows: dict[str, Any] = {}
    for name, policy, options in POLICIES:
        if name == "bc-small":
            options = {"checkpoint": str(small_bc)}
        per: dict[str, Any] = {}
        conditions: tuple[tuple[str, dict[str, Any]], ...] = (
            ("nominal", {}),
            ("calibrated", {"calibration": str(cal_dir)}),
        )
        for cond, extra in conditions:
            if cond == "calibrated":
                drop_stale(work / "runs" / f"{name}-{cond}", cal_dir)
            cfg = api.RunConfig(
                suite="held_out_robots",
                policy=policy,
                robots=["Panda"],
                episodes=a.episodes,
                seed=a.seed,
                workers=a.workers,
                out=str(work / "runs"),
                run_id=f"{name}-{cond}",
                policy_options=options,
                **extra,
            )
            res = api.run(cfg, progress=True)
            recs = sorted((r for r in res.records if r.error is None), key=lambda r: r.episode)
            per[cond] = {
                "successes": int(sum(r.success_once for r in recs)),
                "n": len(recs),
                "by_episode": {r.episode: int(r.success_once) for r in recs},
            }
        both = sorted(set(per["nominal"]["by_episode"]) & set(per["calibrated"]["by_episode"]))
        nom = np.array([per["nominal"]["by_episode"][e] for e in both], float)
        calv = np.array([per["calibrated"]["by_episode"][e] for e in both], float)
        gap = paired_gap(calv, nom, np.random.default_rng(a.seed)).to_dict()
        rows[name] = {
            "policy": policy,
            "options": options,
            "nominal": {k: per["nominal"][k] for k in ("successes", "n")},
            "calibrated": {k: per["calibrated"][k] for k in ("successes", "n")},
            "change_calibrated_minus_nominal": gap,
            "pairs": len(both),
        }
    return rows


def rank_change(rows: dict[str, Any], seed: int) -> dict[str, Any]:
    nominal = {k: Outcome(trials=v["nominal"]["n"], successes=v["nominal"]["successes"]) for k, v in rows.items()}
    calibrated = {
        k: Outcome(trials=v["calibrated"]["n"], successes=v["calibrated"]["successes"]) for k, v in rows.items()
    }
    agree = agreement(sim=nominal, real=calibrated, seed=seed)
    order = lambda side: sorted(rows, key=lambda k: -rows[k][side]["successes"] / max(rows[k][side]["n"], 1))  # noqa: E731
    return {
        "agreement_nominal_vs_calibrated": agree,
        "order_nominal": order("nominal"),
        "order_calibrated": order("calibrated"),
    }


def run_sweep(a: Args, work: Path, cal_dir: Path) -> dict[str, Any]:
    perturb = {axis: f"from({cal_dir})" for axis in SWEEP_AXES}
    old = work / "runs" / "sweep-from-calibration"
    if old.exists():  # condition names carry the calibration's sha256: never mix two calibrations' draws
        shutil.rmtree(old)
    cfg = api.RunConfig(
        suite="held_out_robots",
        policy="scripted",
        robots=["Panda"],
        episodes=a.episodes,
        seed=a.seed,
        workers=a.workers,
        out=str(work / "runs"),
        run_id="sweep-from-calibration",
        perturb=perturb,
    )
    res = api.run(cfg, progress=True)
    assert res.summary is not None
    return {"perturb": perturb, "sensitivity": res.summary.get("sensitivity")}


def main_args(a: Args) -> int:
    if not a.out or not a.work:
        raise api.ConfigError("out= and work= are required (python -m baselines.real_panda --help)")
    log = Path(a.log).expanduser()
    if not log.is_file():
        raise api.DataError(f"log={str(log)!r}: the Panda CSV is missing (../shared/data/real/panda_gaz)")
    # the work folder is resumed (its runs are kept) and parts of it are rebuilt: it must not hold, or lie in, the
    # log, and the result (swapped in whole) must neither be it, hold it, nor lie inside it
    work = outputs.check("work", a.work, {"log": str(log)}, resume=lambda p: True)
    out = outputs.check("out", a.out, {"log": str(log), "work": str(work)}, overwrite=a.overwrite)
    t0 = time.perf_counter()
    ds = import_csv(
        log,
        time="time_s",
        resample=1000.0,
        robot_type="panda",
        state=JOINT_COLS["state"],
        velocity=JOINT_COLS["velocity"],
        effort=JOINT_COLS["effort"],
    )
    logs = work / "logs"
    if logs.exists():
        shutil.rmtree(logs)
    write_dataset(logs, ds)
    spec = load_arm_spec(SPEC)
    ds = read_dataset(logs)
    load0, t1, c1 = os.getloadavg()[0], time.perf_counter(), time.process_time()
    cal = calibrate_arm(spec, [e.data for e in ds.episodes], float(ds.fps), seed=0, log=print)
    t_cal = {"wall": time.perf_counter() - t1, "cpu": time.process_time() - c1, "load": (load0, os.getloadavg()[0])}
    staging = work / "calibration"
    if staging.exists():
        shutil.rmtree(staging)
    cal_json = write_arm_report(cal, staging)
    doc = json.loads(cal_json.read_text())
    friction = friction_table(doc, cal.log.dq[cal.log.hold])
    reference = (
        score_reference(cal, json.loads(REFERENCE.read_text()))
        if REFERENCE.is_file()
        else {"why": f"{portable(REFERENCE)} is missing (python benchmarks/gaz_reference.py gaz=CLONE makes it)"}
    )
    friction["gaz_model_heldout"] = reference
    small_bc = train_small_bc(a, work)
    rows = run_population(a, work, staging, small_bc)
    ranks = rank_change(rows, a.seed)
    sweep = run_sweep(a, work, staging)

    # the result names the copies it holds (relative to the checkout when it lies there), never the work folder
    moves = {str(staging): portable(out / "calibration"), str(small_bc.parent): portable(out / "bc_small")}
    rows, sweep = relocated(rows, moves), relocated(sweep, moves)

    def write(tmp: Path) -> None:
        shutil.copytree(staging, tmp / "calibration")
        shutil.copytree(small_bc.parent, tmp / "bc_small")
        write_atomic(tmp / "population.json", {"policies": rows, **ranks, "episodes": a.episodes, "seed": a.seed})
        write_atomic(tmp / "friction.json", friction)
        write_atomic(tmp / "sweep.json", sweep)
        text = readme(a, doc, friction, rows, ranks, sweep, t_cal, time.perf_counter() - t0)
        (tmp / "README.md").write_text(text)

    outputs.replace_dir(out, write)
    print(f"wrote {out}: calibration in {t_cal['wall']:.1f} s, {len(rows)} policies x 2 robots x {a.episodes} episodes")
    return 0


def relocated(node: Any, moves: dict[str, Any]) -> Any:
    """`node` with every string that starts with a key of `moves` starting with its value instead."""
    if isinstance(node, dict):
        return {k: relocated(v, moves) for k, v in node.items()}
    if isinstance(node, list):
        return [relocated(v, moves) for v in node]
    if isinstance(node, str):
        for old, new in moves.items():
            node = node.replace(old, str(new))
    return node


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if any(x in ("-h", "--help") for x in args):
        print(
            command_help(
                "usage: python -m baselines.real_panda out=DIR work=DIR [episodes=20] [seed=1]",
                (real_panda.__doc__ or "").split("\n\n")[0],
                Args,
            ),
            end="",
        )
        return 0
    return guarded(lambda: main_args(build_from_argv(Args, args, "python -m baselines.real_panda")))
