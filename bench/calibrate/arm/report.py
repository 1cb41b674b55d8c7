"""What a real-arm calibration found, on disk: OUT/calibration.json, OUT/report.md and a plot.

calibration.json is `bench.calibration/1` with `method: idim`; for a suite's robot it carries the same
`suite` and `apply` sections as `bench calibrate suite=...` (so `bench run ... calibration=OUT` runs
the calibrated robot), and a `draws` section: the window-bootstrap replicates of every model edit,
which `perturb.AXIS=from(OUT)` samples from.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench import __version__
from bench.calibrate.apply import CalibrationEdit, edits, model_hash, robot_hash
from bench.calibrate.arm.loop import ArmCalibration, summary_line
from bench.calibrate.arm.model import realise
from bench.core.io import json_safe, write_atomic, write_text_atomic
from bench.sims.perturb.reset import ModelEdit

SCHEMA = "bench.calibration/1"


def _key(e: ModelEdit) -> str:
    return f"{e['field']}:{e['element']}" + (f":{e['column']}" if "column" in e else "")


def draws_section(cal: ArmCalibration, final_edits: Sequence[CalibrationEdit]) -> dict[str, object]:
    """Every bootstrap replicate as the values of the final edits (same fields, elements and columns)."""
    keys = [_key(e) for e in final_edits]
    nominal = {_key(e): e["nominal"] for e in final_edits}
    rows = []
    scratch = None
    for values in cal.draws:
        scratch = realise(cal.am, values, into=scratch)
        by_key = {_key(e): e["value"] for e in edits(cal.am.model, scratch)}
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
    chosen = cal.estimates.get(cal.chosen)
    final_edits = chosen.edits if chosen is not None else edits(am.model, realise(am, cal.values))
    doc: dict[str, object] = {
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
            "holdout_samples": int(log.hold.sum()),
            "velocity": "logged" if log.qvel_logged else "central difference of the filtered positions",
            "acceleration": "central difference of the filtered velocities",
            "filter": f"4th-order zero-phase Butterworth low-pass at {cal.spec.filter_hz:g} Hz on every signal",
            "resampled": log.resampled,
        },
        "heldout": log.heldout.to_json(),
        "trust": cal.trust,
        "parameters": cal.params,
        "links": cal.links,
        "effects_searched": cal.searched,
        "effects_added": cal.added,
        "effects_rejected": cal.rejected,
        "errors": cal.errors,
        "estimates": {
            name: {
                "carried": name == cal.chosen,
                "torque_nrmse": e.torque_nrmse,
                "values": e.values,
                "edits": e.edits,
            }
            for name, e in cal.estimates.items()
        },
        "didim": {
            "method": "closed-loop output error (Gautier, Janot and Vandanjon 2013): refits on the states of the "
            "forward check's closed-loop simulation of the training data, from IDIM's estimate",
            "iterations": cal.didim_history,
        },
        "identifiability": cal.identifiability.to_json() if cal.identifiability is not None else None,
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


def _fmt(v: object, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def _what(a: dict) -> str:
    """A found effect's physical values with their intervals, for the report."""
    if a["name"] == "payload":
        mi, ci = a.get("mass_interval"), a.get("com_interval")
        if mi is None:
            com = ", ".join(f"{c:.4f}" for c in a["com"])
            why = a.get("interval_note") or "not identified apart: intervals unbounded"
            return f": {a['mass']:.4g} kg, centre of mass [{com}] m in its frame (intervals {why})"
        com = ", ".join(
            f"{c:.4f} [{iv[0]:.4f}, {iv[1]:.4f}]" if iv else f"{c:.4f} [unbounded]" for c, iv in zip(a["com"], ci or [])
        )
        return f": {a['mass']:.4g} kg [{mi[0]:.4g}, {mi[1]:.4g}], centre of mass {com} m in its frame"
    if a["name"] == "actuator_gain":
        gi = a["gain_interval"]
        return f": gain {a['gain']:.4g} [{gi[0]:.4g}, {gi[1]:.4g}]"
    return ""


def _nr(v: dict[str, Any] | None) -> str:
    return "-" if not v or v.get("nrmse") is None else _fmt(v["nrmse"])


def _verdict(doc: dict[str, Any]) -> list[str]:
    """The report's first lines: what the calibration earned, against what."""
    t = doc.get("trust", {})
    fw = t.get("forward", {})
    tq = doc["errors"]["torque"]
    better = fw.get("simulates_better")
    lines = [
        f"**Verdict.** {doc['summary']}",
        "",
        f"- Held-out data: {t.get('heldout', {}).get('sentence', '-')}.",
        f"- Torque: the carried estimate scores {_fmt(tq['final']['nrmse'])} (mean NRMSE) where the declared model "
        f"scores {_fmt(tq['nominal']['nrmse'])} and memory (the repeat baseline) {_fmt(t.get('repeat_baseline_nrmse'))}: "
        + (
            "it beats the repeat baseline."
            if t.get("torque_beats_repeat")
            else "**it does not beat the repeat baseline**."
        ),
    ]
    if better is None:
        lines.append(f"- Simulation: {fw.get('why', 'no forward check')}.")
    else:
        lines.append(
            f"- Simulation ({fw.get('criterion', '')}): declared {_fmt(fw.get('declared'))} -> calibrated "
            f"{_fmt(fw.get('calibrated'))}: "
            + (
                "the calibrated model simulates better."
                if better
                else "**the calibrated model simulates worse** (" + "; ".join(fw.get("rose", [])) + ")."
            )
        )
    lines.append(f"- Carried into runs: the {t.get('estimate', 'idim')} estimate ({t.get('estimate_why', '')}).")
    return lines


def markdown(doc: dict[str, Any], plot: str | None) -> str:
    """report.md: the verdict first; held-out data; errors before and after beside the repeat baseline; forward
    simulation; both estimates; what the data identify; parameters, links, effects, warnings."""
    tq = doc["errors"]["torque"]
    est = [k for k in ("idim", "didim") if k in tq]
    lines = ["# Real-arm calibration (inverse dynamics)", "", *_verdict(doc), ""]
    lines.append(
        f"Model: {doc['model']['source']}. Data: {doc['data']['samples']} samples at {doc['data']['rate_hz']:g} Hz "
        f"({doc['data']['train_samples']} fitted, {doc['data']['holdout_samples']} held out); "
        f"{doc['data']['filter']}; velocity: {doc['data']['velocity']}."
    )
    for r in doc["data"]["resampled"]:
        lines.append(
            f"Episode {r['episode']}: irregular clock (periods {1e3 * r['source_period_s']['min']:.2f}-"
            f"{1e3 * r['source_period_s']['max']:.2f} ms), resampled to {r['fps']:g} Hz: {r['method']}."
        )
    h = doc.get("heldout", {})
    if h:
        wins = ", ".join(f"episode {w['episode']} {w['start_s']:.3g}-{w['stop_s']:.3g} s" for w in h["windows"][:6])
        lines += ["", "## Held-out data", "", f"{h['sentence']}. Held out: {wins}; {h['method']}."]
    rep = tq.get("repeat", {})
    head = ["nominal", "declared fit", *est, "repeat baseline"]
    lines += ["", "## Held-out torque error per joint (RMSE)", "", "| joint | " + " | ".join(head) + " |"]
    lines.append("|---" * (len(head) + 1) + "|")
    best = rep.get(rep.get("best", ""), {})
    for i, j in enumerate(tq["joints"]):
        cells = [tq["nominal"]["rmse"][i], tq["declared"]["rmse"][i], *(tq[k]["rmse"][i] for k in est)]
        cells.append(best["rmse"][i] if best else None)
        lines.append(f"| {j} | " + " | ".join(_fmt(c) for c in cells) + " |")
    means = [tq["nominal"]["nrmse"], tq["declared"]["nrmse"], *(tq[k]["nrmse"] for k in est), best.get("nrmse")]
    lines.append("| mean NRMSE | " + " | ".join(_fmt(c) for c in means) + " |")
    if best:
        lines.append(f"\nRepeat baseline: {best['what']}.")
    lines += _forward_md(doc["errors"].get("forward", {}))
    if plot:
        lines += ["", f"![held-out torque]({plot})"]
    if len(est) > 1:
        lines += _estimates_md(doc)
    idn = doc.get("identifiability")
    if idn:
        lines += [
            "",
            "## What the data identify",
            "",
            f"{idn['identified_directions']} of {idn['parameters']} parameter directions are identified ({idn['method']}); "
            f"{idn['unidentified_directions']} are not, and a parameter with a share of them has no interval (unbounded).",
        ]
        if idn["combinations"]:
            lines += ["", "Identified only in combination (value [95% interval]):", ""]
            for c in idn["combinations"][:12]:
                lo, hi = c["interval"]
                lines.append(f"- {c['combination']} = {_fmt(c['value'])} [{_fmt(lo)}, {_fmt(hi)}] {c['unit']}")
            if len(idn["combinations"]) > 12:
                lines.append(
                    f"- ... {len(idn['combinations']) - 12} more in calibration.json (identifiability.combinations)"
                )
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
        if p.get("moved"):
            status += "; moved with the parameters it is tied to"
        lines.append(
            f"| {p['name']} | {_fmt(p['value'])} | {'unbounded' if not iv else f'[{_fmt(iv[0])}, {_fmt(iv[1])}]'} | "
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
    lines.append("")
    return "\n".join(lines)


def _forward_md(fw: dict[str, Any]) -> list[str]:
    if "skipped" in fw or "closed_loop" not in fw:
        return ["", f"Forward check: {fw.get('skipped', 'none')}."]
    cl, ol = fw["closed_loop"], fw["open_loop"]
    labels = [k for k in ("nominal", "idim", "didim") if k in cl["free_run"]]
    loop = fw["loop"]
    lines = [
        "",
        "## Forward simulation on the held-out data (position NRMSE, mean over joints)",
        "",
        f"Input: {fw['input']}; contacts and air drag off; integrator {fw['integrator']}. Closed loop: {loop['why']}.",
        "",
        "| closed loop | " + " | ".join(labels) + " |",
        "|---" * (len(labels) + 1) + "|",
    ]
    for h, row in cl["k_step"].items():
        lines.append(f"| k-step {h} s | " + " | ".join(_nr(row.get(k)) for k in labels) + " |")
    lines.append("| free run | " + " | ".join(_nr(cl["free_run"].get(k)) for k in labels) + " |")
    base = ["constant_velocity", "repeat"]
    lines += ["", "| open loop | " + " | ".join(labels + ["constant velocity", "repeat baseline"]) + " |"]
    lines.append("|---" * (len(labels) + 3) + "|")
    for h, row in ol["k_step"].items():
        lines.append(f"| k-step {h} s | " + " | ".join(_nr(row.get(k)) for k in labels + base) + " |")
    lines += ["", f"Open loop {'is' if ol.get('informative') else 'is not'} informative here: {ol.get('why', '')}."]
    return lines


def _estimates_md(doc: dict[str, Any]) -> list[str]:
    """IDIM and DIDIM side by side: errors, and the parameters that differ most between them."""
    e = doc["estimates"]
    fw = doc["errors"].get("forward", {})
    free = fw.get("closed_loop", {}).get("free_run", {})
    lines = [
        "",
        "## Two estimates: inverse dynamics (IDIM) and its forward refinement (DIDIM)",
        "",
        "| estimate | held-out torque NRMSE | held-out closed-loop free-run NRMSE | carried |",
        "|---|---|---|---|",
    ]
    for k, v in e.items():
        lines.append(f"| {k} | {_fmt(v['torque_nrmse'])} | {_nr(free.get(k))} | {'yes' if v['carried'] else ''} |")
    a, b = e.get("idim", {}).get("values", {}), e.get("didim", {}).get("values", {})
    diffs = []
    for jn, vals in a.get("joints", {}).items():
        for key, va in vals.items():
            vb = b.get("joints", {}).get(jn, {}).get(key)
            if vb is not None:
                diffs.append((abs(vb - va) / max(abs(va), 1e-3), f"{jn}.{key}", va, vb))
    for ln, pa in a.get("links", {}).items():
        pb = b.get("links", {}).get(ln)
        if pb is not None:
            diffs.append((abs(pb[0] - pa[0]) / max(abs(pa[0]), 1e-3), f"{ln}.mass", float(pa[0]), float(pb[0])))
    if diffs:
        lines += [
            "",
            "Largest relative differences (IDIM -> DIDIM): "
            + "; ".join(f"{n} {_fmt(va)} -> {_fmt(vb)}" for _, n, va, vb in sorted(diffs, reverse=True)[:6])
            + ".",
        ]
    return lines


def plot(cal: ArmCalibration, out: Path) -> str | None:
    """Held-out measured vs predicted torque per joint (declared model as given, and final)."""
    import matplotlib  # matplotlib: loaded only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # matplotlib: loaded only when a figure is drawn

    hold = cal.log.hold
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
