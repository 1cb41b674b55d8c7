"""A servo calibration's outputs: OUT/calibration.json (schema `bench.calibration.servo/1`) and OUT/report.md,
opening with its verdict (does the calibrated servo simulate the held-out runs better than the declared one)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from bench.calibrate.servo.loop import ServoCalibration


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x, digits) for x in v) + "]"
    return f"{v:.{digits}g}" if isinstance(v, float) else str(v)


def verdict(cal: ServoCalibration) -> str:
    """One line: the held-out free-run error before and after, summed over the held-out runs."""
    b = [cal.errors["declared"][n]["free_run_rmse"] for n in cal.heldout]
    a = [cal.errors["final"][n]["free_run_rmse"] for n in cal.heldout]
    rb, ra = float(np.sqrt(np.mean(np.square(b)))), float(np.sqrt(np.mean(np.square(a))))
    better = "simulates the held-out runs better" if ra < rb else "does NOT simulate the held-out runs better"
    added = ", ".join(x["name"] for x in cal.added) or "no effect"
    return (
        f"The calibrated {cal.spec.servo} ({added} added) {better} than the declared servo: free-run position RMSE "
        f"{rb:.4f} -> {ra:.4f} rad over {len(cal.heldout)} held-out run(s)."
    )


def write_servo_report(cal: ServoCalibration, out: Path) -> None:
    """calibration.json and report.md into `out`."""
    (out / "calibration.json").write_text(json.dumps(cal.to_json(), indent=1, allow_nan=False) + "\n")
    lines = [f"# Servo calibration: {cal.spec.servo}", "", verdict(cal), ""]
    lines += [
        "## Held-out runs (never fitted)",
        "",
        "| run | trajectory | setting | free-run RMSE declared -> final (rad) "
        "| k-step RMSE (rad) | torque off: free-run RMSE (rad) |",
        "|---|---|---|---|---|---|",
    ]
    for n in cal.heldout:
        b, a = cal.errors["declared"][n], cal.errors["final"][n]
        ff = f"{_fmt(b['free_fall_rmse'])} -> {_fmt(a['free_fall_rmse'])}" if b["free_fall_rmse"] is not None else "-"
        lines.append(
            f"| {n} | {b['trajectory']} | {b['label']} | {_fmt(b['free_run_rmse'])} -> {_fmt(a['free_run_rmse'])} | "
            f"{_fmt(b['k_step_rmse'])} -> {_fmt(a['k_step_rmse'])} | {ff} |"
        )
    lines += ["", "## Effects", ""]
    for r in cal.rounds:
        cands = ", ".join(f"{k} {v:.4g}" for k, v in r["candidates"].items())
        lines.append(f"- validation k-step MSE {r['before']:.4g}; candidates: {cands}")
    lines.append(f"- added: {', '.join(a['name'] for a in cal.added) or 'none'}")
    lines += [
        "",
        "## Parameters (final fit, 95% intervals from the data)",
        "",
        "| parameter | value | unit | interval |",
        "|---|---|---|---|",
    ]
    for n, v in cal.parameters(cal.final).items():
        lines.append(f"| {n} | {_fmt(v['value'])} | {v['unit']} | {_fmt(v['interval'])} |")
    g = cal.physics["gravity_torque"]
    lines += [
        "",
        "## Physics recovered (the bench's known values are read from the logs, never fitted)",
        "",
        f"- gravity torque m·g·l: {_fmt(g['fitted'])} N·m, interval {_fmt(g['interval_data'])} (data), "
        f"{_fmt(g['interval_with_torque_scale'])} (with the declared kt/R's sd); known {_fmt(g['known_mgl'])}, "
        f"error {_fmt(g['relative_error'])}",
    ]
    for lab, k in cal.physics["gains"].items():
        ratio = next(v for key, v in k.items() if key.startswith("ratio_to_"))
        lines.append(
            f"- {lab}: fitted {_fmt(k['fitted'])} {_fmt(k['interval'])}, ratio {_fmt(ratio)} (known {_fmt(k['known_ratio'])})"
        )
    lines += ["", f"Torque scale: kt/R = {cal.spec.kt_over_r} N·m/V declared ({cal.spec.source}).", ""]
    (out / "report.md").write_text("\n".join(lines))
