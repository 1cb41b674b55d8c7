"""A servo calibration's outputs: OUT/calibration.json (schema `bench.calibration.servo/1`) and OUT/report.md,
opening with its verdict (does the calibrated servo simulate the held-out runs better than the declared one, per run
and per held-out metric: `bench.calibrate.servo.verdict`), then
per held-out run the errors before and after, the parameters with their intervals beside BAM's published ones (when
BAM's parameter files lie in `params/` next to the logs' folder, as in `../shared/data/real/servo_bam`), the physics
recovered and the calibration's wall and CPU time."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench.calibrate.servo.loop import ServoCalibration
from bench.calibrate.servo.verdict import verdict_lines, verdicts


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x, digits) for x in v) + "]"
    return f"{v:.{digits}g}" if isinstance(v, float) else str(v)


# BAM's identified model folder for each servo of a spec (the STS3250 has none: its sibling STS3215, same firmware)
BAM_MODELS = {"xl330": "xl330", "sts3250": "feetech_sts3215_7_4V", "sts3215": "feetech_sts3215_7_4V"}
# rows of the side-by-side table: our quantity, its unit, BAM's formula from its parameter file
BAM_ROWS: tuple[tuple[str, str, Callable[[dict[str, float]], float | str | None]], ...] = (
    ("kt/R (declared)", "N·m/V", lambda b: b["kt"] / b["R"]),
    ("kt", "V·s/rad", lambda b: b["kt"]),
    ("kt²/R + viscous", "N·m·s/rad", lambda b: b["kt"] ** 2 / b["R"] + b.get("friction_viscous", 0.0)),
    ("armature (inertia - m l²)", "kg·m²", lambda b: b["armature"]),
    ("offset", "rad", lambda b: b.get("q_offset")),
    ("coulomb", "N·m", lambda b: b.get("friction_base")),
    ("stribeck", "N·m", lambda b: b.get("friction_stribeck")),
    ("load_friction", "1", lambda b: _load_friction(b)),
)


def _load_friction(b: dict[str, float]) -> str | None:
    """BAM's M3-M4 one load-friction term, or M5-M6's two (on the motor's torque and on the external one)."""
    if "load_friction_base" in b:
        return _fmt(b["load_friction_base"])
    if "load_friction_motor" in b:
        return f"{_fmt(b['load_friction_motor'])} motor, {_fmt(b.get('load_friction_external', 0.0))} external"
    return None


def bam_models(cal: ServoCalibration) -> dict[str, dict[str, float]]:
    """BAM's published parameter files for this servo ({model: parameters}), found beside the logs' folder."""
    folder = BAM_MODELS.get(cal.spec.servo)
    if folder is None or not cal.sources:
        return {}
    where = Path(cal.sources[0]).parent.parent / "params" / folder
    out = {}
    for f in sorted(where.glob("m*.json")):
        try:
            raw = json.loads(f.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        if isinstance(raw, dict) and "kt" in raw and "R" in raw:
            out[f.stem] = {k: float(v) for k, v in raw.items() if isinstance(v, (int, float))}
    return out


def ours(cal: ServoCalibration) -> dict[str, tuple[float | None, list[float] | None]]:
    """Our final values (with intervals) of the quantities of `BAM_ROWS`."""
    par = cal.parameters(cal.final)
    val = lambda n: (par[n]["value"], par[n]["interval"]) if n in par else (None, None)  # noqa: E731
    kt, _ = val("kt")
    visc = par.get("viscous", {"value": 0.0})["value"]
    armature = cal.physics.get("inertia", {}).get("implied_armature")
    return {
        "kt/R (declared)": (cal.spec.kt_over_r, None),
        "kt": val("kt"),
        "kt²/R + viscous": (cal.spec.kt_over_r * kt + visc if kt is not None else None, None),
        "armature (inertia - m l²)": (armature, None),
        "offset": val("offset"),
        "coulomb": val("coulomb"),
        "stribeck": val("stribeck"),
        "load_friction": val("load_friction"),
    }


def bam_table(cal: ServoCalibration) -> list[str]:
    """Markdown: our final parameters beside BAM's published models (empty when BAM's files are not there)."""
    models = bam_models(cal)
    if not models:
        return []
    mine = ours(cal)
    head = f"| quantity | unit | ours (95% interval) | {' | '.join('BAM ' + m for m in models)} |"
    lines = [head, "|" + "---|" * (3 + len(models))]
    for name, unit, bam in BAM_ROWS:
        v, iv = mine[name]
        cells = [_fmt(bam(b)) for b in models.values()]
        lines.append(f"| {name} | {unit} | {_fmt(v)} {_fmt(iv) if iv else ''} | {' | '.join(cells)} |")
    return lines


def verdict(cal: ServoCalibration) -> list[str]:
    """The verdict: the held-out free-run and k-step errors before and after over every held-out run, then per run
    which held-out metric did not improve (an after counts only where the calibrated servo predicts better)."""
    rms = lambda tag, key: float(np.sqrt(np.mean([cal.errors[tag][n][key] ** 2 for n in cal.heldout])))  # noqa: E731
    fb, fa = rms("declared", "free_run_rmse"), rms("final", "free_run_rmse")
    kb, ka = rms("declared", "k_step_rmse"), rms("final", "k_step_rmse")
    v = verdicts(cal.errors, cal.heldout)
    every = v["runs_better_on_every_metric"] == v["runs"]
    better = (
        "simulates every held-out run better"
        if every
        else (
            "simulates the held-out runs better on the whole"
            if fa < fb and ka < kb
            else "does NOT simulate the held-out runs better"
        )
    )
    added = ", ".join(x["name"] for x in cal.added) or "no effect"
    lines = [
        f"The calibrated {cal.spec.servo} ({added} added) {better} than the declared servo: free-run position RMSE "
        f"{fb:.4f} -> {fa:.4f} rad, k-step {kb:.4f} -> {ka:.4f} rad over {len(cal.heldout)} held-out run(s)."
    ]
    labels = {n: f"{e['trajectory']}, {e['label']}" for n, e in cal.errors["declared"].items()}
    return lines + ["", *(f"- {line}" for line in verdict_lines(cal.errors, cal.heldout, labels))]


def _run_word(v: dict[str, Any]) -> str:
    """A run's verdict in the table: better, or mixed/worse with the metrics that did not improve."""
    return v["verdict"] if v["verdict"] == "better" else f"{v['verdict']}: {', '.join(v['worse_on'])} worse"


def write_servo_report(cal: ServoCalibration, out: Path) -> None:
    """calibration.json and report.md into `out`."""
    (out / "calibration.json").write_text(json.dumps(cal.to_json(), indent=1, allow_nan=False) + "\n")
    lines = [f"# Servo calibration: {cal.spec.servo}", "", *verdict(cal), ""]
    lines += [
        "## Held-out runs (never fitted)",
        "",
        "| run | trajectory | setting | free-run RMSE declared -> final (rad) "
        "| k-step RMSE (rad) | torque off: free-run RMSE (rad) | verdict |",
        "|---|---|---|---|---|---|---|",
    ]
    per_run = verdicts(cal.errors, cal.heldout)["per_run"]
    for n in cal.heldout:
        b, a = cal.errors["declared"][n], cal.errors["final"][n]
        ff = f"{_fmt(b['free_fall_rmse'])} -> {_fmt(a['free_fall_rmse'])}" if b["free_fall_rmse"] is not None else "-"
        lines.append(
            f"| {n} | {b['trajectory']} | {b['label']} | {_fmt(b['free_run_rmse'])} -> {_fmt(a['free_run_rmse'])} | "
            f"{_fmt(b['k_step_rmse'])} -> {_fmt(a['k_step_rmse'])} | {ff} | {_run_word(per_run[n])} |"
        )
    lines += ["", "## Effects", ""]
    for r in cal.rounds:
        cands = ", ".join(f"{k} {v:.4g}" for k, v in r["candidates"].items())
        lines.append(f"- validation k-step MSE {r['before']:.4g}; candidates: {cands}")
    lines.append(f"- added: {', '.join(a['name'] for a in cal.added) or 'none'}")
    lines += [
        "",
        "## Parameters (final fit; 95% intervals: Jacobian + jackknife over training runs + kt/R's sd for torques)",
        "",
        "| parameter | value | unit | interval | sd: Jacobian, jackknife, kt/R |",
        "|---|---|---|---|---|",
    ]
    for n, v in cal.parameters(cal.final).items():
        sd = v.get("sd")
        parts = f"{_fmt(sd['jacobian'], 2)}, {_fmt(sd['jackknife'], 2)}, {_fmt(sd['torque_scale'], 2)}" if sd else "-"
        lines.append(f"| {n} | {_fmt(v['value'])} | {v['unit']} | {_fmt(v['interval'])} | {parts} |")
    table = bam_table(cal)
    if table:
        lines += [
            "",
            f"## Beside BAM's published models ({BAM_MODELS[cal.spec.servo]}; fitted by BAM with the bench's "
            "mass and length known)",
            "",
            *table,
        ]
    g = cal.physics["gravity_torque"]
    inside = cal.physics["truths_inside"]
    lines += [
        "",
        "## Physics recovered (the bench's known values are read from the logs, never fitted)",
        "",
        f"Known values inside their 95% intervals: {inside['inside']} of {inside['checked']}.",
        "",
        f"- gravity torque m·g·l: {_fmt(g['fitted'])} N·m, interval {_fmt(g['interval_data'])} (data), "
        f"{_fmt(g['interval_with_torque_scale'])} (with the declared kt/R's sd); known {_fmt(g['known_mgl'])}, "
        f"error {_fmt(g['relative_error'])}",
    ]
    for lab, k in cal.physics["gains"].items():
        ratio = next(v for key, v in k.items() if key.startswith("ratio_to_"))
        lines.append(
            f"- {lab}: fitted {_fmt(k['fitted'])} {_fmt(k['interval'])} (known {_fmt(k['known'])}), ratio "
            f"{_fmt(ratio)} {_fmt(k['ratio_interval']) if k['ratio_interval'] else ''} (known {_fmt(k['known_ratio'])})"
        )
    lines += [
        "",
        f"Torque scale: kt/R = {cal.spec.kt_over_r} N·m/V declared, relative sd {cal.spec.kt_over_r_sd} "
        f"({cal.spec.source}).",
        "",
        f"Time: {cal.wall['total']:.2f} s wall, {cal.wall['cpu']:.2f} s CPU (search {cal.wall['search']:.2f} s, "
        f"intervals {cal.wall['intervals']:.2f} s wall).",
        "",
    ]
    (out / "report.md").write_text("\n".join(lines))
