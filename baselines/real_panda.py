"""A real Franka Panda's own log, calibrated, and what that does to the suite's predictions.

    python -m baselines.real_panda out=results/real_panda work=/tmp/real_panda episodes=20 seed=1 workers=2

1. Imports Gaz et al.'s excitation log (`../shared/data/real/panda_gaz`, irregular clock: resampled to
   1 kHz by linear interpolation) and calibrates robosuite's Panda, as held_out_robots builds it, by
   inverse dynamics (`bench/calibrate/models/panda_gaz.yaml`): OUT/calibration/.
2. Compares the calibrated model with the one the log's authors identified (Gaz et al., RA-L 2019), on
   the never-repeated stretch the calibration holds out: their predicted torque on the same samples
   (results/references/gaz_panda.json, made by benchmarks/gaz_reference.py from their own code) scored
   by the same code as ours; and their friction law, tau_f = A / (1 + exp(-a (dq + s))) - A / (1 + exp(-a s))
   per joint, against ours on the held-out velocities.
3. Runs a population of policies (scripted expert, noisy, timid and weak-grip experts, the committed
   behaviour-cloning checkpoint and a smaller one trained here on 8 demonstrations per seen arm, random) on the nominal and on the calibrated Panda, the same seeds on
   both, and reports per-policy success with paired intervals and the change in rank order.
4. Runs the scripted expert under `perturb.AXIS=from(calibration)` on damping, dry friction and the
   links' inertia: the measured robot within what the calibration knows about it.

Writes OUT/README.md (the tables), OUT/population.json and OUT/friction.json; the runs go to WORK.
The log has no task success: this measures how calibration moves predictions, not whether it
improves them.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from baselines import bc
from bench import api
from bench.api.calibration import calibrate_arm, load_arm_spec, score_reference, write_arm_report
from bench.api.data import outputs, portable, write_atomic
from bench.api.datasets import import_csv, read_dataset, write_dataset
from bench.api.scripts import build_from_argv, command_help, guarded
from bench.api.stats import Outcome, agreement, paired_gap

ROOT = Path(__file__).resolve().parents[1]
SPEC = ROOT / "bench" / "calibrate" / "models" / "panda_gaz.yaml"
LOG = ROOT.parent / "shared" / "data" / "real" / "panda_gaz" / "trajectory_1.csv"
JOINT_COLS = {
    "state": [f"q{i}" for i in range(1, 8)],
    "velocity": [f"dq{i}" for i in range(1, 8)],
    "effort": [f"tau{i}" for i in range(1, 8)],
}
# Gaz et al. (2019), friction parameters of the identified model, per joint: FI_1 (A), FI_2 (a), FI_3 (s)
# as published with the paper's code (marcocognetti/FrankaEmikaPandaDynModel, get_FrictionTorque.m)
GAZ = {
    "A": [0.54615, 0.87224, 0.64068, 1.2794, 0.83904, 0.30301, 0.56489],
    "a": [5.1181, 9.0657, 10.136, 5.5903, 8.3469, 17.133, 10.336],
    "s": [0.039533, 0.025882, -0.04607, 0.036194, 0.026226, -0.021047, 0.0035526],
}
POLICIES: list[tuple[str, str, dict[str, Any]]] = [
    ("expert", "scripted", {}),
    ("expert-noise0.3", "baselines.expert_variants:ExpertVariant", {"noise": 0.3}),
    ("expert-noise0.6", "baselines.expert_variants:ExpertVariant", {"noise": 0.6}),
    ("expert-timid0.5", "baselines.expert_variants:ExpertVariant", {"scale": 0.5}),
    ("expert-weakgrip0.3", "baselines.expert_variants:ExpertVariant", {"grip": 0.3}),
    ("bc", "bc", {}),  # the committed checkpoint: 40 demonstrations per seen arm
    ("bc-small", "checkpoint", {}),  # trained here: 8 demonstrations per seen arm, a 64x64 MLP (checkpoint set below)
    ("random", "random", {}),
]
SWEEP_AXES = ("damping", "frictionloss", "link_mass")
REFERENCE = ROOT / "results" / "references" / "gaz_panda.json"  # Gaz et al.'s model on the held-out samples


@dataclass(frozen=True)
class Args:
    """Keys of `python -m baselines.real_panda`."""

    out: Optional[str] = None  # folder for README.md, population.json, friction.json and calibration/ (required)
    work: Optional[str] = None  # folder for the imported log and the runs (required; never inside out)
    log: str = str(LOG)  # the Panda CSV (Gaz et al.'s trajectory 1)
    episodes: int = 20  # episodes per policy and condition
    seed: int = 1  # run seed: the same initial states on the nominal and the calibrated robot
    workers: int = 2  # worker processes per run
    overwrite: bool = False  # replace an out folder this script wrote


def gaz_friction(dq: np.ndarray) -> np.ndarray:
    """Gaz et al.'s friction torque (N·m) at joint velocities dq (N, 7)."""
    a, b, s = (np.asarray(GAZ[k]) for k in ("A", "a", "s"))
    return a / (1 + np.exp(-b * (dq + s))) - a / (1 + np.exp(-b * s))


def ours(params: list[dict], joints: list[str], dq: np.ndarray) -> np.ndarray:
    """The calibration's friction torque (Coulomb tanh(dq / 0.02), viscous, offset) at dq (N, 7)."""
    val = {p["name"]: p["value"] for p in params}
    out = np.zeros_like(dq)
    for j, jn in enumerate(joints):
        fc, fv, off = (val.get(f"{jn}.{k}", 0.0) for k in ("coulomb", "viscous", "offset"))
        out[:, j] = fc * np.tanh(dq[:, j] / 0.02) + fv * dq[:, j] + off
    return out


def friction_table(cal: dict, dq_hold: np.ndarray) -> dict[str, Any]:
    joints = cal["model"]["joints"]
    grid = np.array([-1.0, -0.5, -0.1, -0.02, 0.02, 0.1, 0.5, 1.0])
    g = np.repeat(grid[:, None], 7, axis=1)
    mine, theirs = ours(cal["parameters"], joints, g), gaz_friction(g)
    h_mine, h_theirs = ours(cal["parameters"], joints, dq_hold), gaz_friction(dq_hold)
    return {
        "velocities": grid.tolist(),
        "ours": mine.T.tolist(),
        "gaz": theirs.T.tolist(),
        "heldout_rms": {
            "ours": np.sqrt((h_mine**2).mean(0)).tolist(),
            "gaz": np.sqrt((h_theirs**2).mean(0)).tolist(),
            "difference": np.sqrt(((h_mine - h_theirs) ** 2).mean(0)).tolist(),
        },
        "note": "ours includes the constant offset the fit found (a torque-sensor offset); Gaz et al.'s model "
        "is zero at rest by construction",
    }


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


def _iv(e: dict) -> str:
    if e.get("value") is None:
        return "-"
    lo, hi = e.get("ci") or (None, None)
    return f"{e['value']:+.2f}" + (f" [{lo:+.2f}, {hi:+.2f}]" if lo is not None else "")


def readme(
    a: Args, doc: dict, fr: dict, rows: dict, ranks: dict, sweep: dict, t_cal: dict[str, Any], total: float
) -> str:
    tq = doc["errors"]["torque"]
    fw = doc["errors"].get("forward", {})
    trust, held = doc.get("trust", {}), doc.get("heldout", {})
    ref = fr.get("gaz_model_heldout", {})
    rep = tq["repeat"][tq["repeat"]["best"]]
    joints = [j.split("_")[-1] for j in tq["joints"]]
    win = ", ".join(f"{w['start_s']:.2f}-{w['stop_s']:.2f} s" for w in held.get("windows", []))
    lines = [
        "# A real Franka Panda's log in the loop: calibrated robot, moved predictions",
        "",
        "Reproduce: `python -m baselines.real_panda out=results/real_panda work=/tmp/real_panda "
        f"episodes={a.episodes} seed={a.seed} workers={a.workers}` (this invocation: {total / 60:.0f} min on 2 "
        f"cores; runs already recorded in WORK resumed where nominal or fitted by the same calibration file; the calibration alone: {t_cal['cpu']:.1f} s of CPU, "
        f"{t_cal['wall']:.1f} s of wall time on a machine at load {t_cal['load'][0]:.1f} -> {t_cal['load'][1]:.1f}: "
        "`benchmarks/bench_arm_calibrate.py` times it).",
        "",
        "Data: Gaz et al.'s excitation trajectory (`../shared/data/real/panda_gaz`, 21 s, irregular clock "
        "resampled to 1 kHz by linear interpolation, measured link-side joint torque with gravity). Declared "
        "model: robosuite's Panda as held_out_robots builds it (placeholder inertials, armature 5/i kg m^2, "
        "damping 0.1, friction loss 0.1). Method: inverse dynamics (`bench/calibrate/models/panda_gaz.yaml`, "
        'docs/calibration.md "Real arms").',
        "",
        f"Held out: {win} of the log, the stretch its excitation never repeats ({held.get('sentence', '')}). "
        "Everything below is scored there: data the fit has not seen in any period.",
        "",
        "## The calibration (calibration/report.md has every parameter)",
        "",
        "Held-out torque RMSE (N·m) on the same samples, scored by the same code:",
        "",
        "| model | " + " | ".join(joints) + " | mean NRMSE |",
        "|---|" + "---|" * (len(joints) + 1),
        "| declared (robosuite's Panda) | "
        + " | ".join(f"{v:.3g}" for v in tq["nominal"]["rmse"])
        + f" | {tq['nominal']['nrmse']:.3g} |",
        "| repeat baseline (memory of the fitted data) | "
        + " | ".join(f"{v:.3g}" for v in rep["rmse"])
        + f" | {rep['nrmse']:.3g} |",
        f"| calibrated ({trust.get('estimate', 'idim')}, carried into runs) | "
        + " | ".join(f"{v:.3g}" for v in tq["final"]["rmse"])
        + f" | {tq['final']['nrmse']:.3g} |",
    ]
    if "nrmse" in ref:
        lines.append(
            "| Gaz et al.'s identified model | "
            + " | ".join(f"{v:.3g}" for v in ref["rmse"])
            + f" | {ref['nrmse']:.3g} |"
        )
    else:
        lines.append(f"| Gaz et al.'s identified model | {ref.get('why', 'not available')} |" + " |" * len(joints))
    cl = fw.get("closed_loop", {})
    if cl.get("free_run"):
        labels = [k for k in ("nominal", "idim", "didim") if k in cl["free_run"]]
        lines += [
            "",
            "Held-out simulation (position NRMSE, mean over joints) of the model each run carries, built from its "
            f"model edits: closed loop ({fw['loop']['why']}), the link side driven by the logged torque:",
            "",
            "| closed loop | " + " | ".join(labels) + " |",
            "|---|" + "---|" * len(labels),
        ]
        for h, row in cl["k_step"].items():
            lines.append(f"| k-step {h} s | " + " | ".join(f"{row[k]['nrmse']:.3g}" for k in labels) + " |")
        lines.append("| free run | " + " | ".join(f"{cl['free_run'][k]['nrmse']:.3g}" for k in labels) + " |")
        lines += ["", f"Open loop: {fw['open_loop'].get('why', '')}."]
    verdict = trust.get("forward", {})
    lines += [
        "",
        f"Verdict: the calibrated model {'beats' if tq['beats_repeat'] else 'does NOT beat'} the repeat baseline on "
        f"torque, and it simulates the held-out data {'better' if verdict.get('simulates_better') else 'NOT better'} "
        f"than the declared model ({verdict.get('declared', float('nan')):.3g} -> {verdict.get('calibrated', float('nan')):.3g}, "
        f"closed-loop free run). Estimate carried: {trust.get('estimate')} ({trust.get('estimate_why', '')}).",
    ]
    idn = doc.get("identifiability") or {}
    if idn:
        lines += [
            "",
            f"What the log identifies: {idn['identified_directions']} of {idn['parameters']} parameter directions; "
            f"the other {idn['unidentified_directions']} are not identified, and a parameter with a share of them "
            "has an unbounded interval (calibration/report.md lists the combinations the data do identify).",
        ]
    added = ", ".join(f"{e['name']} at {e['target']}" for e in doc["effects_added"]) or "none"
    lines += ["", f"Effects added: {added}. Searched: " + "; ".join(doc["effects_searched"]) + "."]
    if doc["warnings"]:
        lines += ["", "Said by the calibration:", ""] + [f"- {w}" for w in doc["warnings"]]
    lines += [
        "",
        "## Friction: ours against Gaz et al.'s identified model (N·m)",
        "",
        "Their model: A / (1 + exp(-a (dq + s))) - A / (1 + exp(-a s)), parameters as published. Ours: "
        "Coulomb tanh(dq / 0.02) + viscous dq + offset (the offset is a constant of the torque signal).",
        "",
        "| joint | " + " | ".join(f"dq={v:g}" for v in fr["velocities"]) + " | held-out RMS ours / Gaz / diff |",
        "|---|" + "---|" * (len(fr["velocities"]) + 1),
    ]
    for j, jn in enumerate(joints):
        cells = " | ".join(f"{o:+.2f} / {g:+.2f}" for o, g in zip(fr["ours"][j], fr["gaz"][j]))
        h = fr["heldout_rms"]
        lines.append(f"| {jn} | {cells} | {h['ours'][j]:.2f} / {h['gaz'][j]:.2f} / {h['difference'][j]:.2f} |")
    lines += [
        "",
        f"## {len(rows)} policies on the nominal and the calibrated Panda (Lift, {a.episodes} episodes each, "
        f"run seed {a.seed}: the same initial states on both)",
        "",
        "| policy | nominal | calibrated | change (calibrated - nominal), paired, 95% |",
        "|---|---|---|---|",
    ]
    for name, r in rows.items():
        lines.append(
            f"| {name} | {r['nominal']['successes']}/{r['nominal']['n']} | "
            f"{r['calibrated']['successes']}/{r['calibrated']['n']} | {_iv(r['change_calibrated_minus_nominal'])} |"
        )
    ag = ranks["agreement_nominal_vs_calibrated"]
    stats = ag.get("statistics", ag)
    lines += [
        "",
        "Rank order, nominal: " + ", ".join(ranks["order_nominal"]) + ".",
        "Rank order, calibrated: " + ", ".join(ranks["order_calibrated"]) + ".",
        "Agreement of the two rankings (population.json has the intervals): "
        + ", ".join(f"{k} {_pt(v)}" for k, v in stats.items() if isinstance(v, dict))
        + ".",
        "",
        "## The measured robot within what the calibration knows: `perturb.AXIS=from(calibration)`",
        "",
        "Scripted expert, nominal vs each axis drawn per episode from the calibration's bootstrap (sweep.json):",
        "",
    ]
    lines += ["| condition | n | success | drop vs nominal (paired, 95%) |", "|---|---|---|---|"]
    for row in sweep.get("sensitivity") or []:
        if row.get("scope") != "all":
            continue
        so = row["success_once"]
        lines.append(
            f"| {row['condition']} | {row['n']} | {so['successes']}/{row['n']} | "
            f"{_iv(row['drop_vs_nominal']['success_once']) if row['axis'] else '-'} |"
        )
    lines += [
        "",
        "## What this shows and what it does not",
        "",
        _bc_sentence(rows, doc),
        "",
        "It shows how far robosuite's Panda is from a real one where a torque log can see it (the held-out torque "
        "error above, on data the fit has not seen in any period, beside memory and the log's authors' own model), "
        "which parameters the log identifies and which it cannot, whether the calibrated arm simulates the robot "
        "better (in closed loop, where the declared model's heavier placeholder links only looked better open loop), "
        "and how much the suite's predictions move when the suite runs the calibrated arm instead: per policy, and "
        "in the order it ranks policies. It does not show that the calibrated suite predicts real task success "
        "better: the log has no task and no success, no gripper and no object; the calibration moves the arm's "
        "link-side dynamics only (friction, damping and link inertia; the rotor inertia behind the torque sensor "
        "stays robosuite's), and the suite's controller (OSC) compensates much of them. A sim-real agreement "
        "study needs success measured on the real robot.",
        "",
    ]
    return "\n".join(lines)


def _bc_sentence(rows: dict, doc: dict) -> str:
    """Whether the behaviour-cloning policy's drop on the calibrated Panda survives this calibration."""
    r = rows.get("bc")
    if not r:
        return ""
    ch = r["change_calibrated_minus_nominal"]
    lo, hi = ch.get("ci") or (None, None)
    t = doc.get("trust", {})
    fw = t.get("forward", {})
    holds = hi is not None and hi < 0
    earned = bool(t.get("simulates_better")) and bool(t.get("torque_beats_repeat"))
    return (
        f"bc on the calibrated Panda: {r['nominal']['successes']}/{r['nominal']['n']} -> "
        f"{r['calibrated']['successes']}/{r['calibrated']['n']} ({_iv(ch)}): the drop "
        + ("survives" if holds else "does not survive")
        + " this calibration, "
        + (
            f"whose model beats memory on held-out torque and simulates the held-out stretch better than the "
            f"declared one (closed-loop free run {fw.get('declared', float('nan')):.3g} -> "
            f"{fw.get('calibrated', float('nan')):.3g})."
            if earned
            else "whose model did NOT earn its place (see the verdict above): read the change with that in mind."
        )
    )


def _pt(v: dict) -> str:
    if v.get("value") is None:
        return "n/a" + (f" ({v['reason']})" if v.get("reason") else "")
    lo, hi = v.get("ci") or (None, None)
    return f"{v['value']:.2f}" + (f" [{lo:.2f}, {hi:.2f}]" if lo is not None and hi is not None else "")


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if any(x in ("-h", "--help") for x in args):
        print(
            command_help(
                "usage: python -m baselines.real_panda out=DIR work=DIR [episodes=20] [seed=1]",
                (__doc__ or "").split("\n\n")[0],
                Args,
            ),
            end="",
        )
        return 0
    return guarded(lambda: main_args(build_from_argv(Args, args, "python -m baselines.real_panda")))


if __name__ == "__main__":
    raise SystemExit(main())
