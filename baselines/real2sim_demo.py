"""Does closing the loop make the simulator a better predictor of how policies do on the real robot?

    python -m baselines.real2sim_demo [out=results/real2sim] [work=/tmp/real2sim] [episodes=20] [seed=1]
                                      [log_episodes=8] [workers=2]

1. The "real" robot: held_out_robots' Panda with effects the nominal model lacks, several at once
   and never declared to the calibration (`REAL`): every arm joint damped 8x, dry friction of
   0.8 N·m on joints 2, 4 and 6, the joint 2 and 4 drives 20% weak, 0.5 kg more on link 7. It is
   written as model edits (`real_robot.json`) and run through the same `calibration=` machinery
   a calibration uses, so the real robot is a MuJoCo model the harness can step.
2. Logs from it: a noisy expert (noise 0.3: the noise excites the arm), `log_episodes` episodes
   with `record=` (seeds of run seed 100, not the evaluation's).
3. The calibration: `bench calibrate suite=held_out_robots robot=Panda logs=...` on those logs.
4. A population of 9 policies (the scripted expert; noisy, timid and weak-grip variants of it,
   `baselines.expert_variants`; the behaviour-cloning checkpoint; random), each evaluated
   `episodes` times on the real robot, the nominal simulator and the calibrated simulator (seed
   `seed`: the same initial states everywhere).
5. Sim-real agreement of the nominal and the calibrated simulator with the real robot: MMRV and
   Pearson with bootstrap intervals (`bench.scoring.agreement`), and the paired change (same real resample).

Everything is resumable (runs are resumed by run_id); the committed outputs are in `out`.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

SUITE, ROBOT = "held_out_robots", "Panda"
REAL: dict[str, Any] = {
    "damping_scale": 8.0,
    "friction": 0.8,
    "friction_joints": ("robot0_joint2", "robot0_joint4", "robot0_joint6"),
    "gain": 0.8,
    "gain_motors": ("robot0_torq_j2", "robot0_torq_j4"),
    "payload": 0.5,
    "payload_body": "robot0_link7",
}
VARIANT = "baselines.expert_variants:ExpertVariant"
POLICIES: dict[str, tuple[str, dict[str, Any]]] = {
    "expert": ("scripted", {}),
    "expert-noise0.1": (VARIANT, {"noise": 0.1}),
    "expert-noise0.3": (VARIANT, {"noise": 0.3}),
    "expert-noise0.6": (VARIANT, {"noise": 0.6}),
    "expert-timid0.5": (VARIANT, {"scale": 0.5}),
    "expert-timid0.75": (VARIANT, {"scale": 0.75}),
    "expert-weakgrip0.3": (VARIANT, {"grip": 0.3}),
    "bc": ("bc", {}),
    "random": ("random", {}),
}
SIMS = ("real", "nominal", "calibrated")


def real_robot(path: Path) -> Path:
    """Write the real robot's model edits (the apply section of a calibration file) for the nominal Panda."""
    from bench import api
    from bench.api.calibration import model_hash, torque_joints
    from bench.api.data import write_atomic

    suite = api.load_suite(SUITE)
    env = suite.make_env(next(c for c in suite.all_cells() if c.robot == ROBOT), suite.default_horizon)
    try:
        m = env.mujoco.model
        joints = torque_joints(m)
        names = [m.joint(j).name for j in joints]
        edits = []
        for j, n in zip(joints, names):
            d = int(m.jnt_dofadr[j])
            edits.append(
                {
                    "field": "dof_damping",
                    "element": n,
                    "nominal": float(m.dof_damping[d]),
                    "value": float(m.dof_damping[d] * REAL["damping_scale"]),
                }
            )
        for n in REAL["friction_joints"]:
            d = int(m.jnt_dofadr[m.joint(n).id])
            edits.append(
                {
                    "field": "dof_frictionloss",
                    "element": n,
                    "nominal": float(m.dof_frictionloss[d]),
                    "value": float(REAL["friction"]),
                }
            )
        for a in REAL["gain_motors"]:
            g = float(m.actuator_gainprm[m.actuator(a).id, 0])
            edits.append({"field": "actuator_gainprm", "element": a, "nominal": g, "value": g * REAL["gain"]})
        b = m.body(REAL["payload_body"]).id
        edits.append(
            {
                "field": "body_mass",
                "element": REAL["payload_body"],
                "nominal": float(m.body_mass[b]),
                "value": float(m.body_mass[b] + REAL["payload"]),
            }
        )
        doc = {
            "schema": "bench.calibration/1",
            "truth": "the hidden 'real' robot of baselines/real2sim_demo.py",
            "real": {k: list(v) if isinstance(v, tuple) else v for k, v in REAL.items()},
            "suite": {"name": suite.name, "version": suite.version, "robot": ROBOT},
            "apply": {"robot": ROBOT, "joints": names, "model_hash": model_hash(m, names), "edits": edits},
        }
    finally:
        env.close()
    write_atomic(path, doc)
    return path


def run_policy(
    work: Path,
    run_id: str,
    policy: str,
    options: dict,
    episodes: int,
    seed: int,
    workers: int,
    calibration: str | None = None,
    record: str | None = None,
) -> dict:
    from bench import api

    cfg = api.RunConfig(
        suite=SUITE,
        policy=policy,
        policy_options=options,
        robots=[ROBOT],
        episodes=episodes,
        seed=seed,
        workers=workers,
        out=str(work / "runs"),
        run_id=run_id,
        calibration=calibration,
        record=record,
    )
    t0 = time.time()
    result = api.run(cfg)
    succ = sum(bool(r.success_once) for r in result.records if r.error is None)
    trials = sum(r.error is None for r in result.records)
    print(f"  {run_id}: {succ}/{trials} lifted ({time.time() - t0:.0f} s)", flush=True)
    return {"trials": trials, "successes": succ, "errors": len(result.records) - trials, "rate": succ / trials}


def paired(nominal: dict, calibrated: dict, real: dict, n_boot: int = 2000, seed: int = 0) -> dict:
    """Bootstrap of the change in MMRV and Pearson from the nominal to the calibrated simulator: each
    replicate redraws every policy's trials in all three tables, so the real side is shared."""
    from bench.api.stats import mmrv

    names = list(real)
    rng = np.random.default_rng(seed)

    def draw(t: dict) -> np.ndarray:
        n = np.array([t[p]["trials"] for p in names])
        p = np.array([t[p]["successes"] / t[p]["trials"] for p in names])
        return rng.binomial(n, p) / n

    def pearson(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.corrcoef(a, b)[0, 1]) if a.std() > 0 and b.std() > 0 else float("nan")

    d_mmrv, d_pearson = [], []
    for _ in range(n_boot):
        r, s0, s1 = draw(real), draw(nominal), draw(calibrated)
        d_mmrv.append(mmrv(sim=s1, real=r) - mmrv(sim=s0, real=r))
        d_pearson.append(pearson(s1, r) - pearson(s0, r))
    out = {}
    for name, vals in (("mmrv_change", np.array(d_mmrv)), ("pearson_change", np.array(d_pearson))):
        ok = vals[np.isfinite(vals)]
        out[name] = {
            "ci": [float(q) for q in np.quantile(ok, [0.025, 0.975])] if ok.size else None,
            "share_improved": float(np.mean(ok < 0 if name == "mmrv_change" else ok > 0)) if ok.size else None,
            "n_boot_defined": int(ok.size),
        }
    return out


@dataclass(frozen=True)
class DemoConfig:
    """Keys of the demonstration (key=value)."""

    out: str = "results/real2sim"  # where the README's inputs go (real_robot.json, calibration/, agreement.json)
    work: str = "/tmp/real2sim"  # runs and logs (reused on a rerun)
    episodes: int = 20  # episodes per policy on each of real / nominal / calibrated
    seed: int = 1  # run seed of the evaluations (the logs use 100)
    log_episodes: int = 8  # episodes logged on the "real" robot
    workers: int = 2  # workers per run


def main(argv: list[str]) -> int:
    from bench.api.calibration import calibrate_suite, write_report
    from bench.api.data import write_atomic
    from bench.api.scripts import build_from_argv
    from bench.api.stats import Outcome, agreement

    cfg: DemoConfig = build_from_argv(DemoConfig, argv, "python -m baselines.real2sim_demo")
    out, work = Path(cfg.out), Path(cfg.work)
    episodes, seed, log_eps, workers = cfg.episodes, cfg.seed, cfg.log_episodes, cfg.workers
    out.mkdir(parents=True, exist_ok=True)
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    real = real_robot(out / "real_robot.json")
    print(f"1. real robot: {real}", flush=True)
    logs = work / "logs"
    if not logs.exists():
        print("2. logs from the real robot", flush=True)
        policy, options = POLICIES["expert-noise0.3"]
        run_policy(work, "logs", policy, options, log_eps, 100, workers, str(real), str(logs))
    cal_dir = out / "calibration"
    if not (cal_dir / "calibration.json").exists():
        print("3. calibration", flush=True)
        cal, extra = calibrate_suite(
            SUITE, ROBOT, logs, seed=0, threads=1, residual=True, log=lambda msg: print("   ", msg, flush=True)
        )
        write_report(cal, cal_dir, extra)
    print("4. policies on the real robot, the nominal and the calibrated simulator", flush=True)
    calibrations = {"real": str(real), "nominal": None, "calibrated": str(cal_dir / "calibration.json")}
    table: dict[str, dict[str, dict]] = {s: {} for s in SIMS}
    for name, (policy, options) in POLICIES.items():
        for sim in SIMS:
            table[sim][name] = run_policy(
                work, f"{sim}-{name}", policy, options, episodes, seed, workers, calibrations[sim]
            )
    outcomes = {s: {p: Outcome(v["trials"], v["successes"]) for p, v in table[s].items()} for s in SIMS}
    report = {
        "setup": {
            "suite": SUITE,
            "robot": ROBOT,
            "episodes": episodes,
            "seed": seed,
            "log_episodes": log_eps,
            "real": {k: list(v) if isinstance(v, tuple) else v for k, v in REAL.items()},
            "policies": {k: {"policy": p, "options": o} for k, (p, o) in POLICIES.items()},
        },
        "outcomes": table,
        "agreement": {
            s: agreement(outcomes[s], outcomes["real"], sim_name=s, real_name="real") for s in ("nominal", "calibrated")
        },
        "change": paired(table["nominal"], table["calibrated"], table["real"]),
        "wall_s": round(time.time() - t0, 1),
    }
    write_atomic(out / "agreement.json", report)
    for s in ("nominal", "calibrated"):
        st = report["agreement"][s]["statistics"]
        print(
            f"{s:10s} vs real: MMRV {st['mmrv']['value']} {st['mmrv']['ci']}, Pearson {st['pearson']['value']} "
            f"{st['pearson']['ci']}"
        )
    print(f"change: {json.dumps(report['change'])}")
    return 0


if __name__ == "__main__":
    from bench.api.scripts import guarded  # bad input: one line, exit 2; never a traceback

    raise SystemExit(guarded(lambda: main(sys.argv[1:])))
