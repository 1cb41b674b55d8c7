"""OUT/README.md of `python -m baselines.real_panda`: the calibration's errors, the population's moved predictions, the sweep."""

from __future__ import annotations

from typing import Any

from baselines.real_panda.args import Args


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
