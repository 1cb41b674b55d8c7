"""What a real-arm calibration found, on disk: OUT/calibration.json, OUT/report.md and a plot.

calibration.json is `bench.calibration/1` with `method: idim`; for a suite's robot it carries the same
`suite` and `apply` sections as `bench calibrate suite=...` (so `bench run ... calibration=OUT` runs
the calibrated robot), and a `draws` section: the window-bootstrap replicates of every model edit,
which `perturb.AXIS=from(OUT)` samples from.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bench import __version__
from bench.calibrate.apply import edits, model_hash, robot_hash
from bench.calibrate.arm.loop import ArmCalibration, summary_line
from bench.calibrate.arm.model import realise
from bench.core.io import json_safe, write_atomic, write_text_atomic

SCHEMA = "bench.calibration/1"


def _key(e: dict[str, Any]) -> str:
    return f"{e['field']}:{e['element']}" + (f":{e['column']}" if "column" in e else "")


def draws_section(cal: ArmCalibration, final_edits: list[dict[str, Any]]) -> dict[str, Any]:
    """Every bootstrap replicate as the values of the final edits (same fields, elements and columns)."""
    keys = [_key(e) for e in final_edits]
    rows = []
    for values in cal.draws:
        by_key = {_key(e): e["value"] for e in edits(cal.am.model, realise(cal.am, values))}
        nominal = {_key(e): e["nominal"] for e in final_edits}
        rows.append([by_key.get(k, nominal[k]) for k in keys])
    return {
        "method": "window bootstrap of the training data (0.5 s windows), one Gauss-Newton step per replicate",
        "keys": keys,
        "values": rows,
    }


def to_json(cal: ArmCalibration) -> dict[str, Any]:
    """The `bench.calibration/1` document of a real-arm calibration."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated
    import scipy  # scipy: loaded only when a fit is computed

    am, log = cal.am, cal.log
    fitted = cal.fitted_model if cal.fitted_model is not None else realise(am, cal.values)
    final_edits = edits(am.model, fitted)
    doc: dict[str, Any] = {
        "schema": SCHEMA,
        "method": "idim",
        "spec": cal.spec.to_json(),
        "model": {
            "source": str(cal.spec.model) if cal.spec.model else f"suite {cal.spec.suite}, robot {cal.spec.robot}",
            "joints": am.joints,
            "links": am.links,
            "payload_frame": am.payload_name,
        },
        "data": {
            "rate_hz": log.rate,
            "source_fps": log.source_fps,
            "samples": int(len(log.t)),
            "train_samples": int(log.train.sum()),
            "holdout_samples": int((~log.train).sum()),
            "velocity": "logged" if log.qvel_logged else "central difference of the filtered positions",
            "acceleration": "central difference of the filtered velocities",
            "filter": f"4th-order zero-phase Butterworth low-pass at {cal.spec.filter_hz:g} Hz on every signal",
            "resampled": log.resampled,
        },
        "parameters": cal.params,
        "links": cal.links,
        "effects_searched": cal.searched,
        "effects_added": cal.added,
        "effects_rejected": cal.rejected,
        "errors": cal.errors,
        "warnings": cal.warnings,
        "not_carried": cal.not_carried,
        "summary": summary_line(cal),
        "fit": {"tau": cal.final.tau, "n": cal.final.n, "ssr": cal.final.ssr, "weights": cal.final.weights},
        "wall_seconds": cal.wall.get("total"),
        "timing": cal.wall,
        "versions": {
            "bench": __version__,
            "mujoco": mujoco.__version__,
            "numpy": np.__version__,
            "scipy": scipy.__version__,
        },
    }
    if am.suite is not None:
        doc["suite"] = {**am.suite, "logs": None}
        doc["apply"] = {
            "robot": am.suite["robot"],
            "joints": am.joints,
            "model_hash": model_hash(am.model, am.joints),
            "robot_hash": robot_hash(am.model, am.joints),
            "edits": final_edits,
        }
    doc["draws"] = draws_section(cal, final_edits)
    return json_safe(doc)


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def _what(a: dict) -> str:
    """A found effect's physical values with their intervals, for the report."""
    if a["name"] == "payload":
        mi = a["mass_interval"]
        com = ", ".join(f"{c:.4f} [{lo:.4f}, {hi:.4f}]" for c, (lo, hi) in zip(a["com"], a["com_interval"]))
        return f": {a['mass']:.4g} kg [{mi[0]:.4g}, {mi[1]:.4g}], centre of mass {com} m in its frame"
    if a["name"] == "actuator_gain":
        gi = a["gain_interval"]
        return f": gain {a['gain']:.4g} [{gi[0]:.4g}, {gi[1]:.4g}]"
    return ""


def markdown(doc: dict[str, Any], plot: str | None) -> str:
    """report.md: errors per joint before and after, parameters with status and interval, effects, warnings."""
    tq = doc["errors"]["torque"]
    lines = [
        "# Real-arm calibration (inverse dynamics)",
        "",
        f"Model: {doc['model']['source']}. Data: {doc['data']['samples']} samples at {doc['data']['rate_hz']:g} Hz "
        f"({doc['data']['train_samples']} fitted, {doc['data']['holdout_samples']} held out); "
        f"{doc['data']['filter']}; velocity: {doc['data']['velocity']}.",
    ]
    for r in doc["data"]["resampled"]:
        lines.append(
            f"Episode {r['episode']}: irregular clock (periods {1e3 * r['source_period_s']['min']:.2f}-"
            f"{1e3 * r['source_period_s']['max']:.2f} ms), resampled to {r['fps']:g} Hz: {r['method']}."
        )
    lines += ["", "## Held-out error per joint", "", "| joint | torque RMSE nominal | declared fit | final |"]
    lines.append("|---|---|---|---|")
    for i, j in enumerate(tq["joints"]):
        lines.append(
            f"| {j} | {_fmt(tq['nominal']['rmse'][i])} | {_fmt(tq['declared']['rmse'][i])} | "
            f"{_fmt(tq['final']['rmse'][i])} |"
        )
    lines.append(
        f"| mean NRMSE | {_fmt(tq['nominal']['nrmse'])} | {_fmt(tq['declared']['nrmse'])} | "
        f"{_fmt(tq['final']['nrmse'])} |"
    )
    fw = doc["errors"].get("forward", {})
    if "k_step" in fw:
        lines += [
            "",
            f"Forward check: both models driven by the logged torque from logged states, "
            f"{1e3 * fw['horizon_s']:.0f} ms horizons, contacts and air drag off (position RMSE, rad or m):",
            "",
            "| joint | nominal | final |",
            "|---|---|---|",
        ]
        k0, k1 = fw["k_step"]["nominal"], fw["k_step"]["final"]
        for i, j in enumerate(tq["joints"]):
            lines.append(f"| {j} | {_fmt(k0['rmse'][i])} | {_fmt(k1['rmse'][i])} |")
        lines.append(f"| mean NRMSE | {_fmt(k0['nrmse'])} | {_fmt(k1['nrmse'])} |")
    elif "skipped" in fw:
        lines += ["", f"Forward check: {fw['skipped']}."]
    if plot:
        lines += ["", f"![held-out torque]({plot})"]
    lines += [
        "",
        "## Parameters",
        "",
        "| parameter | value | 95% interval | declared | status |",
        "|---|---|---|---|---|",
    ]
    for p in doc["parameters"]:
        iv = p.get("interval")
        status = p["status"] + (f" (with {', '.join(p['with'])})" if p.get("with") else "")
        if p.get("at_bound"):
            status += "; **at a bound**"
        lines.append(
            f"| {p['name']} | {_fmt(p['value'])} | {'-' if not iv else f'[{_fmt(iv[0])}, {_fmt(iv[1])}]'} | "
            f"{_fmt(p['declared'])} | {status} |"
        )
    lines += [
        "",
        "## Links",
        "",
        "| link | mass declared -> fitted | centre of mass (m) | physical |",
        "|---|---|---|---|",
    ]
    for li in doc["links"]:
        com = "-" if li["com"] is None else "[" + ", ".join(f"{c:.3f}" for c in li["com"]) + "]"
        lines.append(
            f"| {li['link']} | {li['declared_mass']:.3g} -> {li['mass']:.3g} ({li['mass_status']}) | {com} | "
            f"{'yes' if li['physical'] else 'no'} |"
        )
    lines += ["", "## Effects", "", "Searched: " + "; ".join(doc["effects_searched"]) + "."]
    added = ", ".join(
        f"{a['name']} at {a['target']}{_what(a)} (held-out -{100 * a['heldout_drop']:.1f}%)"
        for a in doc["effects_added"]
    )
    lines.append(f"Added: {added or 'none'}.")
    if doc["not_carried"]:
        lines += ["", "Not carried into runs: " + "; ".join(doc["not_carried"]) + "."]
    if doc["warnings"]:
        lines += ["", "## Warnings", ""] + [f"- {w}" for w in doc["warnings"]]
    lines += ["", f"Summary: {doc['summary']}", ""]
    return "\n".join(lines)


def plot(cal: ArmCalibration, out: Path) -> str | None:
    """Held-out measured vs predicted torque per joint (declared model as given, and final)."""
    import matplotlib  # matplotlib: loaded only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # matplotlib: loaded only when a figure is drawn

    hold = ~cal.log.train
    t = cal.log.t[hold]
    meas, nom, fin = cal.log.tau[hold], cal.torques["nominal"][hold], cal.torques["final"][hold]
    n = meas.shape[1]
    fig, axes = plt.subplots(n, 1, figsize=(9, 1.6 * n + 0.6), sharex=True, squeeze=False, layout="constrained")
    for j in range(n):
        ax = axes[j, 0]
        ax.plot(t, meas[:, j], color="black", lw=1.0, label="measured")
        ax.plot(t, nom[:, j], color="tab:gray", lw=0.8, label="declared model")
        ax.plot(t, fin[:, j], color="tab:orange", lw=0.8, label="calibrated")
        ax.set_ylabel(cal.am.joints[j].split("_")[-1], fontsize=8)
    axes[0, 0].legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time (s, held-out)")
    path = out / "torque.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path.name


def write_arm_report(cal: ArmCalibration, out: str | Path) -> Path:
    """calibration.json, report.md and torque.png into `out`; returns the JSON path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    doc = to_json(cal)
    png = plot(cal, out)
    path = out / "calibration.json"
    write_atomic(path, doc)
    write_text_atomic(out / "report.md", markdown(doc, png))
    return path
