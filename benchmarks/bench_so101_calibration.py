"""An arm's six servos (the SO-101's, or with arm=koch the Koch's) calibrated from a LeRobot dataset recorded in
simulation with hidden servo parameters: truth vs fitted, held-out position error before (the model's declared
servos) and after, and the time.

    python benchmarks/bench_so101_calibration.py [arm=so101|koch] [episodes=8] [seed=0] [units=rad|deg|normalized]
        [latency=0] [out=DIR]

It writes HIDDEN/calibration.json (known per-joint kp, damping and Coulomb friction; the armature stays the
MJCF's, which positions cannot separate from the stiffness where the rotor dominates), records
`bench run suite=ARM calibration=HIDDEN record=DIR policy=baselines.ARM_scripted:excitation` (a task's scripted
policy moves each joint once, slowly: too little to identify a servo), rewrites the dataset
in the chosen units (lerobot's normalised units with a calibration-ranges file), and calibrates it in this
process, pinned to one core where the OS allows: the wall and CPU seconds of the calibration alone are printed.
`latency=L` records with `perturb.latency=[L]` (a hidden transport delay: the goals act L frames late) and keeps
only those episodes; the delay the calibration finds is printed.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.api.scripts import script_keys
from bench.calibrate.servo.arm import calibrate_arm_servos, load_arm, parse_servo_arm_spec, servo_document, servos_from
from bench.calibrate.servo.arm.data import in_units
from bench.calibrate.servo.arm.spec import ARMS, UNITS, read_ranges
from bench.logs import read_dataset, write_dataset

# the hidden servos: per joint kp (firmware units), damping (N·m·s/rad) and Coulomb friction (N·m)
HIDDEN_SO101 = {
    "shoulder_pan": {"kp": 12, "damping": 0.9, "coulomb": 0.12},
    "shoulder_lift": {"kp": 22, "damping": 0.5, "coulomb": 0.08},
    "elbow_flex": {"kp": 14, "damping": 0.8, "coulomb": 0.10},
    "wrist_flex": {"kp": 18, "damping": 0.4, "coulomb": 0.03},
    "wrist_roll": {"kp": 10, "damping": 0.7, "coulomb": 0.06},
    "gripper": {"kp": 20, "damping": 0.5, "coulomb": 0.05},
}
HIDDEN = HIDDEN_SO101
# the Koch's (Dynamixel Position P Gain; declared 800, 1500 on the elbow; damping 0.041, Coulomb 0.0128)
HIDDEN_KOCH = {
    "shoulder_pan": {"kp": 600, "damping": 0.06, "coulomb": 0.020},
    "shoulder_lift": {"kp": 1100, "damping": 0.03, "coulomb": 0.015},
    "elbow_flex": {"kp": 1300, "damping": 0.05, "coulomb": 0.010},
    "wrist_flex": {"kp": 700, "damping": 0.03, "coulomb": 0.008},
    "wrist_roll": {"kp": 500, "damping": 0.05, "coulomb": 0.012},
    "gripper": {"kp": 900, "damping": 0.04, "coulomb": 0.010},
}
HIDDEN_OF = {"so101": HIDDEN_SO101, "koch": HIDDEN_KOCH}


def ranges_for(arm) -> dict:
    """A lerobot calibration file for the arm: each motor's range symmetric about the MJCF's zero (raw ticks)."""
    out = {}
    for i, (joint, (lo, hi)) in enumerate(zip(arm.joints, arm.limits)):
        half = max(-lo, hi) * 4095 / (2 * math.pi) + 5
        out[joint] = {
            "id": i + 1,
            "drive_mode": int(joint == "elbow_flex"),
            "homing_offset": 0,
            "range_min": int(round(2047 - half)),
            "range_max": int(round(2047 + half)),
        }
    return out


def record(folder: Path, episodes: int, seed: int, latency: int = 0, name: str = "so101") -> tuple[Path, object]:
    """HIDDEN/calibration.json and the recording under it (with `latency` > 0: its episodes of that delay only);
    returns (dataset folder, the hidden servos)."""
    arm = load_arm(ARMS[name].suite)
    per_kp = ARMS[name].torque_per_kp
    hidden = servos_from(arm, HIDDEN_OF[name], per_kp, "HIDDEN")
    (folder / "hidden").mkdir(parents=True, exist_ok=True)
    (folder / "hidden" / "calibration.json").write_text(json.dumps(servo_document(arm, hidden, per_kp)))
    cmd = [
        sys.executable, "-c", "import sys; from bench.cli import main; sys.exit(main())", "run", f"suite={ARMS[name].suite}", "envs=[nominal]", f"episodes={episodes}",
        f"seed={seed}", "workers=1", f"policy=baselines.{name}_scripted:excitation",
        f"calibration={folder / 'hidden' / 'calibration.json'}", f"record={folder / 'rad'}",
        f"out={folder / 'runs'}", "run_id=hidden",
    ] + ([f"perturb.latency=[{latency}]"] if latency else [])  # fmt: skip
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    if not latency:
        return folder / "rad", hidden
    ds = read_dataset(folder / "rad")
    late = [e for e in ds.episodes if e.meta.get("condition") == f"latency={latency}"]
    write_dataset(folder / "rad_late", dataclasses.replace(ds, episodes=late))
    return folder / "rad_late", hidden


def main(argv: list[str]) -> int:
    args = script_keys(argv, __doc__, ("arm", "episodes", "out", "seed", "units", "latency"))
    bad = {"episodes": "a whole number >= 2 (one episode is held out)", "seed": "a whole number",
           "latency": "a whole number of frames >= 0", "units": " | ".join(UNITS), "arm": " | ".join(ARMS)}  # fmt: skip
    name = args.get("arm", "so101")
    if name not in ARMS:
        print(f"error: arm={name!r}: must be {bad['arm']}", file=sys.stderr)
        return 2
    try:
        episodes, seed, latency = (int(args.get(k, d)) for k, d in (("episodes", "8"), ("seed", "0"), ("latency", "0")))
        units = args.get("units", "rad")
        wrong = [
            k for k, ok in (("episodes", episodes >= 2), ("latency", latency >= 0), ("units", units in UNITS)) if not ok
        ]
    except ValueError:
        wrong = [k for k in ("episodes", "seed", "latency") if not args.get(k, "0").lstrip("-").isdigit()]
    if wrong:
        print(f"error: {wrong[0]}={args.get(wrong[0])!r}: must be {bad[wrong[0]]}", file=sys.stderr)
        return 2
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    raw = {"method": "servo_arm", "arm": name, "units": units}
    if units == "normalized" and not ARMS[name].mid_range_zero:  # refused before anything is recorded
        print(f"error: units=normalized: arm {name}'s model has no mid-range zero; use rad or deg", file=sys.stderr)
        return 2
    folder = Path(args.get("out") or tempfile.mkdtemp(prefix=f"{name}_servos_"))
    t0 = time.perf_counter()
    logs, hidden = record(folder, episodes, seed, latency, name)
    print(f"recorded {episodes} episodes of the hidden servos in {time.perf_counter() - t0:.1f} s: {logs}")
    if units != "rad":
        arm = load_arm(ARMS[name].suite)
        if units == "normalized":
            (folder / "so101_follower.json").write_text(json.dumps(ranges_for(arm), indent=1))
            raw["ranges"] = str(folder / "so101_follower.json")
        ranges = read_ranges(folder / "so101_follower.json") if units == "normalized" else None
        write_dataset(folder / units, in_units(read_dataset(logs), arm.joints, units, ranges))
        logs = folder / units
    spec = parse_servo_arm_spec(raw, folder / "spec.yaml")
    wall, cpu = time.perf_counter(), time.process_time()
    cal = calibrate_arm_servos(spec, logs, seed=seed)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    lo, hi = cal.interval()
    n = len(cal.arm.joints)
    print(f"\n{'joint':14s} {'kind':10s} {'declared':>9s} {'truth':>9s} {'fitted':>9s}  95% interval        error")
    inside = total = 0
    for k, kind in enumerate(("stiffness", "damping", "coulomb")):
        for j, joint in enumerate(cal.arm.joints):
            d, t, f = (getattr(s, kind)[j] for s in (cal.declared, hidden, cal.servos))
            a, b = lo[k * n + j], hi[k * n + j]
            inside += a <= t <= b
            total += 1
            print(
                f"{joint:14s} {kind:10s} {d:9.4g} {t:9.4g} {f:9.4g}  "
                + f"[{a:.4g}, {b:.4g}]".ljust(20)
                + f"{(f - t) / t:+.1%}"
            )
    fr, wi = cal.errors["free_run"], cal.errors["window"]
    print(f"\ntruth inside its 95% interval: {inside}/{total}")
    print(
        f"transport delay: hidden {latency} frame(s), found {cal.delay} (linear-start window RMSE by delay "
        + ", ".join(f"{v:.3g}" for v in cal.delay_search)
        + " rad)"
    )
    print(
        f"held-out position RMSE ({len(cal.heldout)} episodes): free run {fr['declared']['rmse']:.4g} -> "
        f"{fr['fitted']['rmse']:.4g} rad; {spec.horizon:g} s windows {wi['declared']['rmse']:.4g} -> "
        f"{wi['fitted']['rmse']:.4g} rad (declared -> fitted)"
    )
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"calibration ({units}, {cal.log.frames} frames, {cal.fit.rollouts} rollouts): {wall:.1f} s wall, "
        f"{cpu:.1f} s CPU on one core (load average {load:.2f})"
    )
    return 0


if __name__ == "__main__":
    np.set_printoptions(precision=4)
    raise SystemExit(main(sys.argv[1:]))
