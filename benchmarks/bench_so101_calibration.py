"""The SO-101's six servos calibrated from a LeRobot dataset recorded in simulation with hidden servo parameters:
truth vs fitted, held-out position error before (the MJCF's declared servos) and after, and the time.

    python benchmarks/bench_so101_calibration.py [episodes=8] [seed=0] [units=rad|deg|normalized] [latency=0] [out=DIR]

It writes HIDDEN/calibration.json (known per-joint kp, damping and Coulomb friction; the armature stays the
MJCF's, which positions cannot separate from the stiffness where the rotor dominates), records
`bench run suite=so101 calibration=HIDDEN record=DIR policy=baselines.so101_scripted:excitation` (the scripted
pick moves each joint once, slowly, and squeezes the cube: too little to identify a servo), rewrites the dataset
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
from bench.calibrate.servo.arm.spec import TORQUE_PER_KP, UNITS, read_ranges
from bench.logs import read_dataset, write_dataset

# the hidden servos: per joint kp (firmware units), damping (N·m·s/rad) and Coulomb friction (N·m)
HIDDEN = {
    "shoulder_pan": {"kp": 12, "damping": 0.9, "coulomb": 0.12},
    "shoulder_lift": {"kp": 22, "damping": 0.5, "coulomb": 0.08},
    "elbow_flex": {"kp": 14, "damping": 0.8, "coulomb": 0.10},
    "wrist_flex": {"kp": 18, "damping": 0.4, "coulomb": 0.03},
    "wrist_roll": {"kp": 10, "damping": 0.7, "coulomb": 0.06},
    "gripper": {"kp": 20, "damping": 0.5, "coulomb": 0.05},
}


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


def record(folder: Path, episodes: int, seed: int, latency: int = 0) -> tuple[Path, object]:
    """HIDDEN/calibration.json and the recording under it (with `latency` > 0: its episodes of that delay only);
    returns (dataset folder, the hidden servos)."""
    arm = load_arm("so101")
    hidden = servos_from(arm, HIDDEN, TORQUE_PER_KP, "HIDDEN")
    (folder / "hidden").mkdir(parents=True, exist_ok=True)
    (folder / "hidden" / "calibration.json").write_text(json.dumps(servo_document(arm, hidden, TORQUE_PER_KP)))
    cmd = [
        sys.executable, "-c", "import sys; from bench.cli import main; sys.exit(main())", "run", "suite=so101", "envs=[nominal]", f"episodes={episodes}",
        f"seed={seed}", "workers=1", "policy=baselines.so101_scripted:excitation",
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
    args = script_keys(argv, __doc__, ("episodes", "out", "seed", "units", "latency"))
    bad = {"episodes": "a whole number >= 2 (one episode is held out)", "seed": "a whole number",
           "latency": "a whole number of frames >= 0", "units": " | ".join(UNITS)}  # fmt: skip
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
    folder = Path(args.get("out") or tempfile.mkdtemp(prefix="so101_servos_"))
    t0 = time.perf_counter()
    logs, hidden = record(folder, episodes, seed, latency)
    print(f"recorded {episodes} episodes of the hidden servos in {time.perf_counter() - t0:.1f} s: {logs}")
    raw = {"method": "servo_arm", "arm": "so101", "units": units}
    if units != "rad":
        arm = load_arm("so101")
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
