"""Servo calibration on BAM's real bench logs: the time of one calibration on one core, and (folds=true) every
trajectory held out in turn, with the held-out errors per run, the physics recovered and BAM's published parameters
side by side, how many known values (m·g·l, each kp, each kp ratio) lie inside their intervals, and the verdict per
held-out run (which of the free-run, k-step and torque-off errors the calibration did not improve).

    python benchmarks/bench_servo.py [servo=xl330|sts3250] [folds=false]

Needs ../shared/data/real/servo_bam. Prints the machine's load with the time: the wall clock counts the pinned
core's other work, CPU seconds do not.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from bench.api.scripts import script_keys
from bench.calibrate.servo import calibrate_servo, parse_servo_spec, read_runs
from bench.calibrate.servo.verdict import verdict_lines, verdicts

ROOT = Path(__file__).resolve().parents[1]
BAM = ROOT.parent / "shared" / "data" / "real" / "servo_bam"
BAM_MODEL = {"xl330": ("xl330", ["m1", "m3", "m4", "m6"]), "sts3250": ("feetech_sts3215_7_4V", ["m1"])}


def _bam(servo: str) -> None:
    folder, models = BAM_MODEL[servo]
    print(f"\nBAM's published {folder} models (fitted by BAM with the bench's mass and length known):")
    print("model  kt/R N·m/V  kt²/R+viscous  armature  friction_base  load_friction_base  friction_stribeck")
    for m in models:
        p = json.loads((BAM / "params" / folder / f"{m}.json").read_text())
        print(
            f"{m:5s}  {p['kt'] / p['R']:.4f}      {p['kt'] ** 2 / p['R'] + p['friction_viscous']:.4f}         "
            f"{p['armature']:.5f}   {p['friction_base']:.4f}         {p.get('load_friction_base', p.get('load_friction_motor', 0)):.4f}"
            f"              {p.get('friction_stribeck', 0):.4f}"
        )


def main(argv: list[str]) -> int:
    args = script_keys(argv, __doc__, ("folds", "servo"))
    servo = args.get("servo", "xl330")
    spec = parse_servo_spec(
        yaml.safe_load((ROOT / "bench" / "calibrate" / "models" / f"servo_{servo}.yaml").read_text())
    )
    if not (BAM / servo).is_dir():
        print(f"needs {BAM / servo}", file=sys.stderr)
        return 2
    os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    runs = read_runs(BAM / servo, spec.columns, units=spec.units, load_scale=spec.load_scale, fps=spec.rate)
    trajectories = sorted({r.trajectory for r in runs}) if args.get("folds") == "true" else ["lift_and_drop"]
    totals, counted = [0, 0], [0, 0]
    for traj in trajectories:
        s = dataclasses.replace(spec, holdout={"trajectory": traj})
        load0 = os.getloadavg()[0]
        w0, c0 = time.perf_counter(), time.process_time()
        cal = calibrate_servo(s, runs)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        added = ", ".join(a["name"] for a in cal.added) or "none"
        print(
            f"\n{servo}, held out: {traj} ({len(cal.heldout)} runs): {wall:.2f} s wall, {cpu:.2f} s CPU on one core "
            f"(load {load0:.1f}); effects added: {added}"
        )
        print("run  setting  free-run RMSE rad declared -> final   k-step RMSE   torque off RMSE   verdict")
        per_run = verdicts(cal.errors, cal.heldout)["per_run"]
        for n in cal.heldout:
            b, a = cal.errors["declared"][n], cal.errors["final"][n]
            ff = f"{b['free_fall_rmse']:.4f} -> {a['free_fall_rmse']:.4f}" if b["free_fall_rmse"] is not None else "-"
            print(
                f"{n}  {b['label']}  {b['free_run_rmse']:.4f} -> {a['free_run_rmse']:.4f}   "
                f"{b['k_step_rmse']:.4f} -> {a['k_step_rmse']:.4f}   {ff}   {per_run[n]['verdict']}"
            )
        labels = {n: f"{e['trajectory']}, {e['label']}" for n, e in cal.errors["declared"].items()}
        print("\n".join(verdict_lines(cal.errors, cal.heldout, labels)))
        counted[0] += sum(v["verdict"] == "better" for v in per_run.values())
        counted[1] += len(per_run)
        g = cal.physics["gravity_torque"]
        lo, hi = g["interval_with_torque_scale"] or (-np.inf, np.inf)
        print(
            f"m·g·l: {g['fitted']:.4f} N·m {np.round(g['interval_data'] or [-np.inf, np.inf], 4).tolist()} (data: Jacobian + jackknife) "
            f"[{lo:.4f}, {hi:.4f}] (with kt/R sd; width {(hi - lo) / g['fitted']:.0%} of the value); known "
            f"{g['known_mgl']:.4f} ({g['relative_error']:+.1%}) {'inside' if g['inside'] else 'OUTSIDE'}"
        )
        for lab, k in cal.physics["gains"].items():
            lo, hi = k["interval"] or (-np.inf, np.inf)
            ratio = ""
            if k["ratio_interval"]:
                rlo, rhi = k["ratio_interval"]
                ratio = (
                    f"; ratio [{rlo:.3f}, {rhi:.3f}] (known {k['known_ratio']:g}, error {(k['ratio_error'] or 0):+.1%}) "
                    f"{'inside' if k['ratio_inside'] else 'OUTSIDE'}"
                )
            print(
                f"{lab}: fitted {k['fitted']:.1f} [{lo:.1f}, {hi:.1f}] (width {(hi - lo) / k['fitted']:.1%}) "
                f"{'inside' if k['inside'] else 'OUTSIDE'}{ratio}"
            )
        ins = cal.physics["truths_inside"]
        totals[0] += ins["inside"]
        totals[1] += ins["checked"]
        print(f"known values inside their intervals: {ins['inside']} of {ins['checked']}")
        params = cal.parameters(cal.final)
        kt = params["kt"]["value"]
        print(
            "final parameters: "
            + ", ".join(
                f"{n} {v['value']:.4g}"
                + (f" [{v['interval'][0]:.4g}, {v['interval'][1]:.4g}]" if v["interval"] else "")
                for n, v in params.items()
                if not n.startswith("kp[")
            )
        )
        print(
            f"kt²/R + viscous = {spec.kt_over_r * kt + params.get('viscous', {'value': 0.0})['value']:.4f} N·m·s/rad; "
            f"implied armature (inertia - m l², check only) {cal.physics.get('inertia', {}).get('implied_armature', float('nan')):.5f}"
        )
    print(f"\nall folds: {totals[0]} of {totals[1]} known values inside their 95% intervals")
    print(f"all folds: {counted[0]} of {counted[1]} held-out runs predicted better on every metric")
    _bam(servo)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
