"""What a calibration found, on disk: OUT/calibration.json, OUT/report.md and its PNG plots.

The JSON has no NaN or infinity anywhere: a value that cannot be computed is null.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bench import __version__
from bench.calibrate.apply import verdict
from bench.calibrate.metrics import against_memory
from bench.calibrate.trace import Calibration
from bench.core.io import json_safe, write_atomic, write_text_atomic

SCHEMA = "bench.calibration/1"
ERROR_KEYS = ("one_step_nrmse", "k_step_nrmse", "free_run_nrmse", "free_run_rmse", "r2")


def clean(value: object) -> Any:
    """JSON-safe copy (NaN / inf to None): `bench.core.io.json_safe`, the one owner of that rule."""
    return json_safe(value)


def _versions() -> dict[str, str]:
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated
    import scipy  # scipy: loaded only when this estimate is computed

    return {"bench": __version__, "mujoco": mujoco.__version__, "numpy": np.__version__, "scipy": scipy.__version__}


def to_json(cal: Calibration) -> dict:
    """The `bench.calibration/1` document of a calibration."""
    plant, rec = cal.plant, cal.rec
    final, decl = cal.final_fit, cal.declared_fit
    declared = {}
    for i, slot in enumerate(plant.slots):
        declared[slot.label] = {
            "field": slot.field,
            "value": final.x[i],
            "interval": list(final.interval(i)),
            "value_without_effects": decl.x[i],
            "nominal": slot.nominal,
            "bounds": list(slot.bounds),
        }
    d, f, n = (cal.errors[k]["free_run_nrmse"] for k in ("declared", "final", "nominal"))
    windows = lambda ws: [{"episode": w.episode, "start": w.start, "stop": w.stop} for w in ws]  # noqa: E731
    doc = {
        "schema": SCHEMA,
        "spec": cal.spec.to_json(),
        "model": {"file": str(cal.spec.model), "timestep": plant.model.opt.timestep, "substeps": plant.substeps},
        "data": {
            "fps": rec.fps,
            "episodes": rec.n_episodes,
            "frames": int(rec.offsets[-1]),
            "velocity": "logged" if rec.qvel_logged else "estimated from positions",
            "train": windows(rec.train),
            "holdout": windows(rec.holdout),
            "seed": cal.seed,
        },
        "declared": declared,
        "effects_added": [{k: v for k, v in e.items()} for e in cal.added],
        "effects_rejected": cal.rejected,
        "rounds": [{"round": i + 1, "candidates": r} for i, r in enumerate(cal.rounds)],
        "errors": {
            k: {
                **{key: cal.errors[k].get(key) for key in ERROR_KEYS},
                "k_step_rmse": cal.errors[k].get("k_step_rmse"),
                "one_step_rmse": cal.errors[k].get("one_step_rmse"),
                "k": cal.errors[k].get("k"),
                "per_joint": cal.errors[k].get("per_joint"),
            }
            for k in ("nominal", "declared", "final")
        },
        "repeat_baseline": cal.errors.get("repeat"),  # memory of the fitted log on the same held-out horizons
        "free_run_nrmse_cut": {
            "declared_to_final": (1.0 - f / d) if d else None,
            "nominal_to_final": (1.0 - f / n) if n else None,
        },
        "fit": {
            "declared": {"ssr": decl.ssr, "n": decl.n, "tau": decl.tau, "evaluations": decl.nfev},
            "final": {
                "ssr": final.ssr,
                "n": final.n,
                "tau": final.tau,
                "evaluations": final.nfev,
                "parameters": final.labels,
                "x": final.x,
            },
        },
        "heldout": cal.heldout.to_json() if cal.heldout else None,
        "trust": cal.trust,
        "learned_residual": cal.learned,
        "warnings": cal.warnings,
        "notes": cal.notes,
        "wall_seconds": cal.wall.get("total"),
        "timing": cal.wall,
        "versions": _versions(),
    }
    return clean(doc)


def plots(cal: Calibration, out: Path) -> dict[str, str]:
    """Logged vs simulated (free run, before / after), the k-step residual, the candidates' scores."""
    import matplotlib  # matplotlib: loaded only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # matplotlib: loaded only when a figure is drawn

    rec, fps = cal.rec, cal.rec.fps
    names = cal.plant.joint_names
    files = {}
    nq = rec.qpos.shape[1]

    # 1. free run on the first held-out window
    fig, axes = plt.subplots(nq, 1, figsize=(9, 2.2 * nq + 0.6), sharex=True, squeeze=False)
    tr = cal.traces["final"]
    valid = tr["mask"][0]
    t = (np.arange(valid.sum()) + 1) / fps
    for j in range(nq):
        ax = axes[j, 0]
        ax.plot(t, tr["target"][0, valid, j], color="k", lw=1.4, label="logged")
        for key, style in (("nominal", ":"), ("declared", "--"), ("final", "-")):
            p = cal.traces[key]["pred"][0, valid, j]
            ax.plot(t, p, style, lw=1.0, label=f"{key} ({cal.errors[key]['free_run_nrmse']:.3g})" if j == 0 else None)
        lo, hi = tr["target"][0, valid, j].min(), tr["target"][0, valid, j].max()
        pad = 0.5 * (hi - lo) + 1e-9
        ax.set_ylim(lo - pad, hi + pad)
        ax.set_ylabel(names[j])
    axes[0, 0].legend(loc="upper right", fontsize=8, title="free-run NRMSE", title_fontsize=8)
    axes[-1, 0].set_xlabel("time in the held-out window [s]")
    fig.suptitle("Held-out free run: logged vs simulated positions")
    fig.tight_layout()
    files["freerun"] = "freerun.png"
    fig.savefig(out / files["freerun"], dpi=110)
    plt.close(fig)

    # 2. k-step residual of positions over the held-out horizons, declared fit vs final
    fig, axes = plt.subplots(nq, 1, figsize=(9, 2.0 * nq + 0.6), sharex=True, squeeze=False)
    start = cal.residual["start"]
    first = rec.holdout[0]
    a, b = rec.offsets[first.episode] + first.start, rec.offsets[first.episode] + first.stop
    sel = (start >= a) & (start < b)
    k = cal.residual["final"].shape[1]
    tt = ((start[sel, None] - a) + 1 + np.arange(k)[None, :]) / fps
    for j in range(nq):
        ax = axes[j, 0]
        for key, color in (("declared", "tab:orange"), ("final", "tab:blue")):
            res = cal.residual[key][sel, :, j]
            ax.plot(tt.T, res.T, color=color, lw=0.8, alpha=0.8)
            ax.plot([], [], color=color, label=key)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(f"{names[j]} [std]")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel(f"time [s]; each stroke a {k}-frame horizon from a logged state")
    fig.suptitle("Residual (simulated - logged position, in std of the log) on held-out horizons")
    fig.tight_layout()
    files["residual"] = "residual.png"
    fig.savefig(out / files["residual"], dpi=110)
    plt.close(fig)

    # 3. candidate scores, one panel per round
    if cal.rounds:
        n = len(cal.rounds)
        fig, axes = plt.subplots(1, n, figsize=(4.2 * n + 1, 4.2), squeeze=False)
        added = {(e["name"], e["target"], e["round"]) for e in cal.added}
        for i, rnd in enumerate(cal.rounds):
            ax = axes[0, i]
            top = rnd[:12][::-1]
            labels = [f"{c['name']}@{c['target']}" for c in top]
            colors = ["tab:green" if (c["name"], c["target"], i + 1) in added else "tab:gray" for c in top]
            ax.barh(range(len(top)), [max(c["score"], 0.0) for c in top], color=colors)
            ax.set_yticks(range(len(top)))
            ax.set_yticklabels(labels, fontsize=7)
            ax.set_xlim(0, 1)
            ax.set_xlabel("share of held-out residual explained")
            ax.set_title(f"round {i + 1}", fontsize=9)
        fig.suptitle("Candidate signatures scored against the residual (green: accepted)")
        fig.tight_layout()
        files["scores"] = "scores.png"
        fig.savefig(out / files["scores"], dpi=110)
        plt.close(fig)
    return files


def _fmt(v: object) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def markdown(doc: dict, files: dict[str, str]) -> str:
    """report.md: errors before / after, what was added and why, what was rejected, plots."""
    lines = [f"# Calibration report: {Path(doc['model']['file']).name}", "", verdict_line(doc), ""]
    data = doc["data"]
    lines += [
        f"{data['episodes']} episode(s), {data['frames']} frames at {data['fps']:g} Hz; "
        f"held out: {len(data['holdout'])} window(s); velocity {data['velocity']}. "
        f"Wall time {doc['wall_seconds']:.1f} s.",
        "",
    ]
    lines += [
        "## Held-out errors (positions)",
        "",
        "| model | one-step NRMSE | k-step NRMSE | free-run NRMSE | free-run RMSE | R² |",
        "|---|---|---|---|---|---|",
    ]
    for key in ("nominal", "declared", "final"):
        e = doc["errors"][key]
        lines.append(f"| {key} | " + " | ".join(_fmt(e[k]) for k in ERROR_KEYS) + " |")
    cut = doc["free_run_nrmse_cut"]["declared_to_final"]
    lines += [
        "",
        f"k = {doc['errors']['final']['k']} frames. Free-run NRMSE cut from the declared fit: "
        f"{_fmt(None if cut is None else 100 * cut)}%.",
        "",
    ]
    lines += _trust(doc.get("heldout"), doc.get("repeat_baseline"), doc["errors"]["final"], doc.get("trust"))
    lines += ["## Effects added", ""]
    if doc["effects_added"]:
        lines += ["| effect | target | parameters (95% interval) | held-out drop | ΔIC |", "|---|---|---|---|---|"]
        for e in doc["effects_added"]:
            params = ", ".join(
                f"{k} = {_fmt(v)} [{_fmt((e['interval'].get(k) or [None, None])[0])}, "
                f"{_fmt((e['interval'].get(k) or [None, None])[1])}]"
                for k, v in e["params"].items()
            )
            lines.append(
                f"| {e['name']} | {e['target']} | {params} | {_fmt(100 * e['heldout_drop'])}% | {_fmt(e['delta_ic'])} |"
            )
    else:
        lines.append("None: no candidate passed all three tests (held-out drop, information criterion, interval).")
    lines += ["", "## Declared parameters", "", "| parameter | nominal | fitted | 95% interval |", "|---|---|---|---|"]
    for name, p in doc["declared"].items():
        iv = p["interval"]
        lines.append(f"| {name} | {_fmt(p['nominal'])} | {_fmt(p['value'])} | [{_fmt(iv[0])}, {_fmt(iv[1])}] |")
    lines += [
        "",
        "## Candidates not added (best scores first)",
        "",
        "| effect | target | score | reason |",
        "|---|---|---|---|",
    ]
    for e in doc["effects_rejected"][:15]:
        lines.append(f"| {e['name']} | {e['target']} | {_fmt(e.get('score'))} | {e.get('reason', '')} |")
    if len(doc["effects_rejected"]) > 15:
        lines.append(f"| … | | | {len(doc['effects_rejected']) - 15} more in calibration.json |")
    lines += _learned(doc.get("learned_residual"))
    lines += _apply(doc.get("suite"), doc.get("apply"))
    if doc["warnings"]:
        lines += ["", "## Warnings", ""] + [f"- {w}" for w in doc["warnings"]]
    lines += ["", "## Plots", ""]
    for key, caption in (
        ("freerun", "Held-out free run, logged vs simulated (nominal, declared fit, final)"),
        ("residual", "k-step residual on held-out horizons, declared fit vs final"),
        ("scores", "Candidate scores per round"),
    ):
        if key in files:
            lines += [f"![{caption}]({files[key]})", "", f"*{caption}.*", ""]
    return "\n".join(lines) + "\n"


def verdict_line(doc: dict) -> str:
    """The report's first line, before any table: whether the calibrated model simulates the held-out data better
    than the declared one (`bench.calibrate.apply.verdict`, what a run prints), its k-step error against memory
    (`bench.calibrate.metrics.against_memory`, what the loop logs last), the effects added."""
    e = doc["errors"]
    said = verdict(doc)
    if said.startswith("unchecked"):  # no forward check to quote: the free-run errors instead
        sim = (
            f"Simulation: {said}. Held-out free-run NRMSE: declared fit {_fmt(e['declared']['free_run_nrmse'])} -> "
            f"final {_fmt(e['final']['free_run_nrmse'])}"
        )
    else:
        sim = f"The calibrated model {said}"
    if doc.get("trust") and doc.get("repeat_baseline"):
        sim += f"; {against_memory({**e, 'repeat': doc['repeat_baseline']}, doc['trust'])}"
    added = ", ".join(f"{a['name']}@{a['target']}" for a in doc["effects_added"]) or "none"
    return f"**Verdict.** {sim}. Effects added: {added}."


def _trust(heldout: dict | None, repeat: dict | None, final: dict, trust: dict | None) -> list[str]:
    """How new the held-out data are, what memory scores on them, and whether the model beats both."""
    if not heldout or not trust:
        return []
    lines = ["## How far the held-out errors can be trusted", "", heldout["sentence"] + ".", ""]
    final_k = final["k_step_nrmse"]
    if repeat and repeat.get("k_step_nrmse") is not None:
        verdict = "beats it" if trust["beats_repeat"] else "does NOT beat it"
        lines += [
            f"Repeat baseline, memory of the fitted log (k-step NRMSE {_fmt(repeat['k_step_nrmse'])}): "
            f"{repeat[repeat['best']]['what']}. The final model (k-step NRMSE "
            f"{_fmt(final_k)}) {verdict}.",
            "",
        ]
    fw = trust["forward"]
    lines += [
        f"Simulates the held-out data at least as well as the model as given ({fw['criterion']}): "
        + ("yes" if trust["simulates_better"] else "no (" + "; ".join(fw["rose"]) + ")")
        + ".",
        "",
    ]
    return lines


def _apply(suite: dict | None, apply: dict | None) -> list[str]:
    """A suite calibration's model edits and how to run with them."""
    if not suite or not apply:
        return []
    lines = [
        "",
        f"## Applying it: `bench run suite={suite['name']} ... calibration=FILE`",
        "",
        f"Suite {suite['name']} version {suite['version']}, robot {apply['robot']} (model fingerprint "
        f"{apply['model_hash'][:12]}); the cells of that robot run with these values:",
        "",
        "| field | element | nominal | calibrated |",
        "|---|---|---|---|",
    ]
    lines += [f"| {e['field']} | {e['element']} | {_fmt(e['nominal'])} | {_fmt(e['value'])} |" for e in apply["edits"]]
    if not apply["edits"]:
        lines.append("| – | – | – | nothing changes |")
    return lines


def _learned(res: dict | None) -> list[str]:
    """The learned residual's section: held-out errors of the physics with and without it."""
    if not res:
        return []
    h = res["heldout"]
    lines = [
        "",
        "## Learned residual (not part of the physical model)",
        "",
        f"{res['model']}; target: {res['target']}. {res['samples']} training samples, ridge strength "
        f"{_fmt(res['lambda'])} (cross-validated R² {_fmt(res['cv_r2'])}), seed {res['seed']}.",
        "",
        "| held-out | one-step NRMSE | k-step NRMSE | free-run NRMSE |",
        "|---|---|---|---|",
    ]
    for key, label in (("physics", "physics (final)"), ("physics_plus_residual", "physics + learned residual")):
        cells = [_fmt(h[key][f"{m}_nrmse"]) for m in ("one_step", "k_step", "free_run")]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines += [
        "",
        f"The residual {res['verdict']}. The effects above and their errors are the physics alone; the "
        "residual says how much the library leaves unexplained, not which effect it is.",
    ]
    return lines


def write_report(cal: Calibration, out: str | Path, extra: dict | None = None) -> Path:
    """Write calibration.json (with `extra` sections, e.g. a suite calibration's `suite` and `apply`),
    report.md and the plots into `out`; returns the JSON path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {**to_json(cal), **clean(extra or {})}
    files = plots(cal, out)
    path = out / "calibration.json"
    write_atomic(path, doc)
    write_text_atomic(out / "report.md", markdown(doc, files))
    return path
