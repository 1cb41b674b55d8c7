"""`bench report RUN|LEADERBOARD out=DIR`: a static HTML page with matplotlib figures.

For a run (a run directory or its summary.json): success per task and robot/env with
Wilson intervals, seen and unseen cells side by side; split means and the transfer
gaps with their intervals; per-axis sensitivity curves (success against the
perturbation level, pooled and per cell) when the run has perturbed conditions; for a
remote policy (`policy=remote`), the distribution of its round-trip latency per condition.
For a leaderboard: each entry's score, seen and unseen success and gap, ranked.
With `calibration=DIR|FILE` (a `bench calibrate` output with calibration.json,
schema `bench.calibration/1`): held-out error before/after calibration (nominal,
declared fit, final) as a table and bars. With `verdict=FILE` (a `bench regress`
verdict): the per-cell paired comparison. Given a run directory, the page also embeds the
run's episode videos (`bench run video=N`) in the cell table, next to their cell, and a
per-axis robustness table (`bench.robustness`: each axis' levels pooled, drop from nominal).

Everything is read and validated before anything is written; figures are PNGs
next to index.html, so the folder can be published as it is (CI artifact, Pages).
"""
from __future__ import annotations

import html
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from bench import config as config_mod
from bench.errors import ConfigError, DataError

SEEN, UNSEEN = "#3b6fb6", "#e07b28"
COLOURS = {"seen": SEEN, "unseen": UNSEEN}


@dataclass(frozen=True)
class ReportConfig:
    """Keys of `bench report` (the input RUN|LEADERBOARD is positional)."""

    out: Optional[str] = None           # output folder (index.html + PNG figures); replaced if it exists
    calibration: Optional[str] = None   # a calibrate output dir or its calibration.json: errors before/after
    verdict: Optional[str] = None       # a `bench regress` verdict.json to include
    title: Optional[str] = None         # page title; default from the input


USAGE = """usage: bench report RUN|SUMMARY|LEADERBOARD out=DIR [calibration=DIR] [verdict=FILE] [title=TEXT]

Writes DIR/index.html with matplotlib figures (PNG, next to it):
  run:          success per task x robot/env with Wilson intervals, seen and unseen side by side; split
                means and transfer gaps with intervals; sensitivity curves per perturbation axis when
                the run has perturbed conditions; round-trip latency distribution for remote policies;
                per-cell table. Given a run directory: its episode videos (bench run video=N) in the
                cell table, copied into DIR/videos, and a robustness table (per axis, levels pooled:
                nominal vs perturbed success, drop with its interval).
  leaderboard:  score, seen/unseen success and gap per entry with intervals, ranked by the lower bound.
  calibration=  held-out error (one-step, k-step, free-run NRMSE) nominal -> declared fit -> final.
  verdict=      a bench regress verdict: per-cell baseline vs candidate and the looks.
Inputs are validated before anything is written; an existing DIR is replaced atomically.

examples:
  bench report runs/my_run out=report/
  bench report results/leaderboard.json out=report/ calibration=runs/calib1
"""


# -- inputs -------------------------------------------------------------------------------------
def load_input(arg: str) -> tuple[str, dict, Path]:
    """(kind, document, path) for a run dir, summary.json or leaderboard.json; validated."""
    from bench.schema import load_json, validate

    path = Path(arg)
    if path.is_dir():
        if not (path / "summary.json").is_file():
            raise DataError(f"{path}: no summary.json (is it a run directory? `bench score {path}` rebuilds it)")
        path = path / "summary.json"
    doc = load_json(path)
    sid = validate(doc, str(path))
    kinds = {"bench.summary/1": "run", "bench.leaderboard/1": "leaderboard"}
    if sid not in kinds:
        raise DataError(f"{path}: schema {sid} cannot be the report's input; give a run or a leaderboard")
    return kinds[sid], doc, path


def load_calibration(arg: str) -> dict:
    """A calibration result (calibration.json, schema bench.calibration/1) with errors.nominal/declared/final."""
    from bench.schema import load_json

    path = Path(arg)
    if path.is_dir():
        path = path / "calibration.json"
    doc = load_json(path)
    if not isinstance(doc, dict) or doc.get("schema") != "bench.calibration/1":
        raise DataError(f"{path}: not a calibration result (schema {doc.get('schema') if isinstance(doc, dict) else None!r}; "
                        "expected bench.calibration/1)")
    errors = doc.get("errors")
    if not isinstance(errors, dict) or not any(isinstance(errors.get(s), dict) for s in ("nominal", "declared", "final")):
        raise DataError(f"{path}: field errors must hold nominal/declared/final error summaries")
    return doc


def load_verdict(arg: str) -> dict:
    from bench.schema import load_json, validate

    doc = load_json(Path(arg))
    sid = validate(doc, arg)
    if sid != "bench.regress/1":
        raise DataError(f"{arg}: schema {sid} is not a regress verdict (bench.regress/1)")
    return doc


# -- figures ------------------------------------------------------------------------------------
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"figure.dpi": 110, "font.size": 9, "axes.spines.top": False, "axes.spines.right": False})
    return plt


def _err(est: dict | None) -> tuple[float, float, float] | None:
    """(value, minus, plus) of an estimate with an interval, or None."""
    if not est or est.get("value") is None:
        return None
    v = est["value"]
    lo, hi = est["ci"] if est.get("ci") else (v, v)
    return v, max(v - lo, 0.0), max(hi - v, 0.0)


def fig_cells(summary: dict, path: Path) -> bool:
    """Success per task, robot/env with Wilson intervals; seen then unseen, coloured by split."""
    plt = _plt()
    metric = summary["metric"]
    other = "success_at_end" if metric == "success_once" else "success_once"
    cells = [c for c in summary["cells"] if c["condition"] == "nominal"]
    if not cells:
        return False
    tasks = sorted({c["task"] for c in cells})
    envs = len({c["env"] for c in cells}) > 1
    fig, axes = plt.subplots(len(tasks), 1, figsize=(max(6.0, 0.75 * max(len([c for c in cells if c["task"] == t]) for t in tasks) + 2), 2.8 * len(tasks)),
                             squeeze=False)
    for ax, task in zip(axes[:, 0], tasks):
        rows = sorted((c for c in cells if c["task"] == task), key=lambda c: (c["split"] != "seen", c["robot"], c["env"]))
        xs = range(len(rows))
        for x, c in zip(xs, rows):
            e = _err(c[metric])
            if e:
                ax.bar(x, e[0], color=COLOURS[c["split"]], alpha=0.85, width=0.65)
                ax.errorbar(x, e[0], yerr=[[e[1]], [e[2]]], color="black", capsize=3, lw=1)
                ax.text(x, e[0] + e[2] + 0.02, f"{e[0] * 100:.0f}%", ha="center", va="bottom", fontsize=7)
            o = _err(c[other])
            if o:
                ax.plot(x, o[0], marker="_", ms=16, mew=2, color="black", alpha=0.6)
        ax.set_xticks(list(xs))
        ax.set_xticklabels([f"{c['robot']}\n{c['env']}" if envs else c["robot"] for c in rows], fontsize=8)
        n_seen = sum(c["split"] == "seen" for c in rows)
        if 0 < n_seen < len(rows):
            ax.axvline(n_seen - 0.5, color="grey", ls=":", lw=1)
        ax.set_ylim(0, 1.15)
        ax.set_ylabel(f"{metric}")
        ax.set_title(f"{task}: success per cell ({int(summary['confidence'] * 100)}% Wilson); "
                     f"bar = {metric}, tick = {other}", fontsize=9, loc="left")
    handles = [plt.Rectangle((0, 0), 1, 1, color=COLOURS[s]) for s in ("seen", "unseen")]
    fig.legend(handles, ["seen", "unseen"], loc="lower center", fontsize=8, frameon=False, ncols=2)
    fig.tight_layout(rect=(0, 0.07 / len(tasks), 1, 1))
    fig.savefig(path)
    plt.close(fig)
    return True


def fig_splits_gaps(summary: dict, path: Path) -> bool:
    """Split means/IQM (left) and transfer gaps (right), with bootstrap intervals."""
    plt = _plt()
    metric = summary["metric"]
    splits = summary["splits"]
    gaps = [g for g in summary["gaps"] if g.get("value") is not None]
    if not splits and not gaps:
        return False
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 2.8), gridspec_kw={"width_ratios": [1.3, 1]})
    labels, i = [], 0
    for split in ("seen", "unseen"):
        for stat in ("mean", "iqm"):
            e = _err(splits.get(split, {}).get(metric, {}).get(stat))
            if e:
                a1.barh(i, e[0], color=COLOURS[split], alpha=0.85 if stat == "mean" else 0.45, height=0.6)
                a1.errorbar(e[0], i, xerr=[[e[1]], [e[2]]], color="black", capsize=3, lw=1)
                labels.append(f"{split} {stat}")
                i += 1
    a1.set_yticks(range(len(labels)))
    a1.set_yticklabels(labels)
    a1.invert_yaxis()
    a1.set_xlim(0, 1.02)
    a1.set_title(f"{metric} over nominal cells", fontsize=9, loc="left")
    for j, g in enumerate(gaps):
        e = _err(g)
        a2.errorbar(e[0], j, xerr=[[e[1]], [e[2]]], fmt="o", color="black", capsize=3)
    a2.axvline(0, color="grey", lw=1)
    if not gaps:
        reason = next((g.get("reason") for g in summary["gaps"] if g.get("reason")), "no seen/unseen pair of groups")
        a2.text(0.5, 0.5, f"no gap computable:\n{reason}", ha="center", va="center", fontsize=8, color="grey",
                transform=a2.transAxes, backgroundcolor="white")
    a2.set_yticks(range(len(gaps)))
    a2.set_yticklabels([f"{g['reference']}→{g['target']}\n{g['metric']}" for g in gaps], fontsize=8)
    a2.invert_yaxis()
    a2.set_xlim(-1.02, 1.02)
    a2.set_title("transfer gap (reference − target)", fontsize=9, loc="left")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


def _level_x(level: Any) -> tuple[float, float] | None:
    """(x, half-width) of a perturbation level: a scale, or the midpoint of a [low, high] range."""
    if isinstance(level, bool):
        return None
    if isinstance(level, (int, float)):
        return float(level), 0.0
    if isinstance(level, list) and len(level) == 2 and all(isinstance(v, (int, float)) for v in level):
        return (level[0] + level[1]) / 2.0, abs(level[1] - level[0]) / 2.0
    return None


def fig_sensitivity(summary: dict, path: Path) -> list[str]:
    """One panel per axis: success vs level (pooled, with Wilson intervals; thin lines per cell)."""
    entries = summary.get("sensitivity") or []
    metric = summary["metric"]
    axes_names = sorted({e["axis"] for e in entries if e.get("axis")})
    if not axes_names:
        return []
    plt = _plt()
    nominal = next((e for e in entries if e.get("axis") is None and e.get("scope") == "all"), None)
    ncol = min(3, len(axes_names))
    nrow = (len(axes_names) + ncol - 1) // ncol
    fig, axs = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.0 * nrow), squeeze=False)
    for k, axis in enumerate(axes_names):
        ax = axs[k // ncol, k % ncol]
        pooled = sorted(((_level_x(e["level"]), e) for e in entries
                         if e.get("axis") == axis and e.get("scope") == "all" and _level_x(e["level"])),
                        key=lambda t: t[0][0])
        per_cell: dict[tuple, list] = {}
        for e in entries:
            if e.get("axis") == axis and e.get("scope") == "cell" and _level_x(e["level"]):
                per_cell.setdefault((e.get("task"), e.get("robot"), e.get("env")), []).append(e)
        for key, es in sorted(per_cell.items()):
            pts = sorted((_level_x(e["level"])[0], e[metric]["value"]) for e in es if e[metric].get("value") is not None)
            if pts:
                ax.plot([p[0] for p in pts], [p[1] for p in pts], lw=0.8, alpha=0.35, color="grey")
                ax.annotate(key[1], pts[-1], fontsize=6, color="grey", xytext=(2, 0), textcoords="offset points")
        xs, ys, lo, hi, xerr = [], [], [], [], []
        for (x, half), e in pooled:
            est = _err(e[metric])
            if est:
                xs.append(x), ys.append(est[0]), lo.append(est[1]), hi.append(est[2]), xerr.append(half)
        ax.errorbar(xs, ys, yerr=[lo, hi], xerr=xerr if any(xerr) else None, fmt="o-", color="#b23a48", capsize=3,
                    label="all cells")
        if nominal and nominal[metric].get("value") is not None:
            ax.axhline(nominal[metric]["value"], color="black", ls="--", lw=1, label="nominal")
        ax.set_ylim(-0.02, 1.05)
        ax.set_xlabel(f"{axis} level")
        ax.set_ylabel(metric)
        if xs and min(xs) > 0 and max(xs) / min(xs) > 20:
            ax.set_xscale("log")
        ax.set_title(f"sensitivity: {axis}", fontsize=9, loc="left")
        ax.legend(fontsize=7, frameon=False)
    for k in range(len(axes_names), nrow * ncol):
        axs[k // ncol, k % ncol].axis("off")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return axes_names


def fig_leaderboard(board: dict, path: Path) -> bool:
    """Per entry: seen and unseen success side by side with intervals, in ranking order per group."""
    plt = _plt()
    entries = board["entries"]
    if not entries:
        return False
    fig, ax = plt.subplots(figsize=(max(6.0, 1.2 * len(entries) + 2), 3.4))
    width = 0.38
    labels = []
    for i, e in enumerate(entries):
        m = e["metric"]
        for j, split in enumerate(("seen", "unseen")):
            est = _err(e["splits"].get(split, {}).get(m, {}).get("mean"))
            if est:
                x = i + (j - 0.5) * width
                ax.bar(x, est[0], width=width, color=COLOURS[split], alpha=0.85)
                ax.errorbar(x, est[0], yerr=[[est[1]], [est[2]]], color="black", capsize=3, lw=1)
                ax.text(x, est[0] + est[2] + 0.02, f"{est[0] * 100:.0f}%", ha="center", va="bottom", fontsize=7)
        sha = e["policy"].get("checkpoint_sha256")
        labels.append(f"#{e['rank'] or '–'} {e['policy']['name']}" + (f"\n{sha[:8]}" if sha else "")
                      + f"\n{e['suite']['name']}")
    ax.set_xticks(range(len(entries)))
    ax.set_xticklabels(labels, fontsize=7)
    groups = [e["group"] for e in entries]
    for i in range(1, len(entries)):
        if groups[i] != groups[i - 1]:
            ax.axvline(i - 0.5, color="grey", ls=":", lw=1)
    ax.set_ylim(0, 1.15)
    ax.set_ylabel("mean success")
    handles = [plt.Rectangle((0, 0), 1, 1, color=COLOURS[s]) for s in ("seen", "unseen")]
    fig.legend(handles, ["seen", "unseen"], fontsize=8, frameon=False, ncols=2, loc="lower center")
    ax.set_title("leaderboard: seen vs unseen mean success per entry (intervals from each run)", fontsize=9, loc="left")
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(path)
    plt.close(fig)
    return True


NRMSE_KEYS = (("one_step_nrmse", "one-step"), ("k_step_nrmse", "k-step"), ("free_run_nrmse", "free-run"))


def fig_calibration(cal: dict, path: Path) -> bool:
    """Held-out NRMSE per horizon for the nominal model, the declared fit and the final model."""
    plt = _plt()
    stages = [s for s in ("nominal", "declared", "final") if isinstance(cal["errors"].get(s), dict)]
    fig, ax = plt.subplots(figsize=(6.5, 2.8))
    width = 0.8 / len(stages)
    colours = {"nominal": "#9aa0a6", "declared": "#3b6fb6", "final": "#2e8b57"}
    for j, stage in enumerate(stages):
        vals = [cal["errors"][stage].get(k) for k, _ in NRMSE_KEYS]
        xs = [i + (j - (len(stages) - 1) / 2) * width for i in range(len(NRMSE_KEYS))]
        ax.bar([x for x, v in zip(xs, vals) if v is not None], [v for v in vals if v is not None], width=width,
               color=colours[stage], label=stage)
    ax.set_xticks(range(len(NRMSE_KEYS)))
    ax.set_xticklabels([lbl for _, lbl in NRMSE_KEYS])
    ax.set_ylabel("held-out NRMSE")
    ax.legend(fontsize=8, frameon=False)
    ax.set_title("calibration: error before → after (held-out)", fontsize=9, loc="left")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


# -- HTML ---------------------------------------------------------------------------------------
CSS = """
body{font-family:-apple-system,'Segoe UI',Helvetica,Arial,sans-serif;margin:24px auto;max-width:1100px;color:#222;
line-height:1.4;padding:0 16px}
h1{font-size:22px;margin-bottom:2px} h2{font-size:17px;margin-top:28px;border-bottom:1px solid #ddd;padding-bottom:4px}
.meta{color:#666;font-size:12px} img{max-width:100%;border:1px solid #eee;margin:6px 0}
table{border-collapse:collapse;font-size:12px;margin:8px 0} th,td{border-bottom:1px solid #eee;padding:3px 8px;
text-align:left} th{background:#f6f6f6} td.num{text-align:right;font-variant-numeric:tabular-nums}
.seen{color:#3b6fb6;font-weight:600} .unseen{color:#e07b28;font-weight:600} .bad{color:#b00020;font-weight:600}
.good{color:#1b7f3b;font-weight:600} .note{color:#555;font-size:12px}
figure{display:inline-block;margin:2px 4px} figcaption{font-size:11px}
"""


def _e(x: Any) -> str:
    return html.escape(str(x))


def _estimate(est: dict | None, pct: bool) -> str:
    """`summary.fmt_estimate`, or n/a with the reason (escaped) when there is no value."""
    from bench.summary import fmt_estimate

    if not est or est.get("value") is None:
        return f"n/a{' (' + _e(est.get('reason')) + ')' if est and est.get('reason') else ''}"
    return fmt_estimate(est, pct)


def _pct(est: dict | None) -> str:
    return _estimate(est, pct=True)


def _signed(est: dict | None) -> str:
    return _estimate(est, pct=False)


def _table(header: list[str], rows: list[list[str]], num: set[int] = frozenset()) -> str:
    th = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td class='num'>{c}</td>" if i in num else f"<td>{c}</td>"
                                    for i, c in enumerate(r)) + "</tr>" for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def _img(name: str, alt: str) -> str:
    return f"<img src='{_e(name)}' alt='{_e(alt)}'>"


def _records(run_dir: Path | None) -> list:
    """The run's episode records when the report was given a run directory (else none)."""
    from bench.records import EPISODES, read_records

    if run_dir is None or not (run_dir / EPISODES).is_file():
        return []
    return read_records(run_dir / EPISODES)


def _videos(records: list, run_dir: Path | None, tmp: Path) -> dict[tuple[str, str], list[str]]:
    """Copy the run's episode videos into tmp/videos; per (cell key, condition), their <video> elements."""
    out: dict[tuple[str, str], list[str]] = {}
    for r in sorted(records, key=lambda r: (r.job_id.rsplit("|", 1)[0], r.episode)):
        video = (r.extras or {}).get("video") or {}
        src = run_dir / str(video["path"]) if run_dir is not None and video.get("path") else None
        if src is None or not src.is_file():
            continue
        (tmp / "videos").mkdir(exist_ok=True)
        shutil.copyfile(src, tmp / "videos" / src.name)
        outcome = "error" if r.error else ("success" if r.success_once else "failure")
        label = f"episode {r.episode}: {outcome}"
        out.setdefault((f"{r.task}/{r.robot}/{r.env}", r.condition), []).append(
            f"<figure><video controls preload='metadata' width='192' src='videos/{_e(src.name)}' title='{_e(label)}'>"
            f"</video><figcaption class='{'good' if outcome == 'success' else 'bad'}'>{_e(label)}</figcaption></figure>")
    return out


def robustness_section(summary: dict, records: list) -> str:
    """Per-axis robustness table (levels pooled), in the style of robustness benchmarks."""
    from bench.robustness import table

    if not records or not any(r.axis for r in records):
        return ""
    metric = summary["metric"] if summary["metric"] != "return" else "success_once"
    conf = float(summary.get("confidence", 0.95) or 0.95)
    rows = []
    for row in table(records, metric, np.random.default_rng(0), confidence=conf):
        rel = row["relative_drop"]
        rows.append([_e(row["axis"]), _e(row["kind"]), _e(", ".join(row["levels"])), str(row["pairs"]),
                     f"{row['nominal'] * 100:.0f}%" if row["nominal"] is not None else "n/a",
                     f"{row['perturbed'] * 100:.0f}%" if row["perturbed"] is not None else "n/a",
                     _signed(row["drop"]), f"{rel * 100:+.0f}%" if rel is not None else "n/a"])
    return ("<h2>Robustness per axis</h2>" +
            _table(["axis", "kind", "conditions", "pairs", f"nominal {metric}", "perturbed", "drop [CI]",
                    "relative drop"], rows, {3, 4, 5, 7}) +
            "<p class='note'>Each axis' levels pooled; episodes paired with nominal by cell and seed (same initial "
            "state); drop = nominal − perturbed with a paired bootstrap interval; most harmful axis first.</p>")


def run_sections(summary: dict, tmp: Path, run_dir: Path | None = None) -> list[str]:
    metric = summary["metric"]
    records = _records(run_dir)
    videos = _videos(records, run_dir, tmp)
    parts = []
    if fig_cells(summary, tmp / "cells.png"):
        parts.append("<h2>Success per cell</h2>" + _img("cells.png", "success per cell") +
                     f"<p class='note'>Nominal cells; bars are {_e(metric)} with Wilson intervals, "
                     "<span class='seen'>seen</span> then <span class='unseen'>unseen</span>.</p>")
    if fig_splits_gaps(summary, tmp / "gaps.png"):
        rows = [[f"{_e(g['reference'])} → {_e(g['target'])}", _e(g["metric"]), _e(g.get("statistic", "mean")),
                 _signed(g)] for g in summary["gaps"]]
        parts.append("<h2>Splits and transfer gaps</h2>" + _img("gaps.png", "splits and gaps") +
                     _table(["gap", "metric", "statistic", "value [CI]"], rows))
    axes = fig_sensitivity(summary, tmp / "sensitivity.png")
    if axes:
        rows = []
        for e in summary["sensitivity"]:
            if e.get("scope") != "all" or e.get("axis") is None:
                continue
            d = e["drop_vs_nominal"][metric]
            rows.append([_e(e["axis"]), _e(e["level"]), str(e["n"]), _pct(e[metric]), _signed(d),
                         f"{d.get('lost', '')}/{d.get('gained', '')}", _e(d.get("p_value", ""))])
        parts.append("<h2>Sensitivity per perturbation axis</h2>" + _img("sensitivity.png", "sensitivity") +
                     _table(["axis", "level", "n", metric, "drop vs nominal [CI]", "lost/gained", "McNemar p"], rows,
                            {2}))
    robust = robustness_section(summary, records)
    if robust:
        parts.append(robust)
    from bench.remote.report import latency_section

    section = latency_section(summary, tmp)  # remote policies: the run's round-trip latency distribution
    if section:
        parts.append(section)
    rows = [[_e(c["task"]), _e(c["robot"]), _e(c["env"]), f"<span class='{c['split']}'>{_e(c['split'])}</span>",
             _e(c["condition"]), str(c["n"]), _pct(c["success_once"]), _pct(c["success_at_end"]),
             str(c["errors"] or "")] + ([" ".join(videos.get((f"{c['task']}/{c['robot']}/{c['env']}", c["condition"]),
                                                             []))] if videos else [])
            for c in summary["cells"]]
    parts.append("<h2>All cells</h2>" + _table(["task", "robot", "env", "split", "condition", "n", "success once",
                                                "success at end", "errors"] + (["episode videos"] if videos else []),
                                               rows, {5, 8}))
    return parts


def leaderboard_sections(board: dict, tmp: Path) -> list[str]:
    parts = []
    if fig_leaderboard(board, tmp / "leaderboard.png"):
        parts.append("<h2>Entries</h2>" + _img("leaderboard.png", "leaderboard"))
    groups: dict[str, list[dict]] = {}
    for e in board["entries"]:
        groups.setdefault(e["group"], []).append(e)
    for g, es in groups.items():
        rows = []
        for e in es:
            m = e["metric"]
            gap = next((x for x in e["gaps"] if x["metric"] == m and x["kind"] == "seen-unseen"), None)
            sha = e["policy"].get("checkpoint_sha256")
            rows.append([str(e["rank"] or "–"), _e(e["policy"]["name"]), _e(sha[:12]) if sha else "–",
                         f"{_e(e['score']['split'] or '')} {_pct(e['score'])}",
                         _pct(e["splits"].get("seen", {}).get(m, {}).get("mean")),
                         _pct(e["splits"].get("unseen", {}).get(m, {}).get("mean")), _signed(gap),
                         str(e["counts"]["episodes"]), _e(e["run_id"])])
        parts.append(f"<h2>{_e(g)}</h2><p class='note'>Ranked by the lower bound of the score.</p>" +
                     _table(["#", "policy", "checkpoint", "score", "seen", "unseen", "gap seen−unseen", "episodes",
                             "run"], rows, {0, 7}))
    return parts


def calibration_section(cal: dict, tmp: Path) -> str:
    fig_calibration(cal, tmp / "calibration.png")
    keys = [("one_step_nrmse", "one-step NRMSE"), ("k_step_nrmse", "k-step NRMSE"), ("free_run_nrmse", "free-run NRMSE"),
            ("free_run_rmse", "free-run RMSE"), ("r2", "R²")]
    rows = []
    for stage in ("nominal", "declared", "final"):
        err = cal["errors"].get(stage)
        if isinstance(err, dict):
            rows.append([stage] + [f"{err[k]:.4g}" if isinstance(err.get(k), (int, float)) else "n/a" for k, _ in keys])
    extra = ""
    added = cal.get("added") or cal.get("accepted")
    if isinstance(added, list) and added:
        names = [a.get("name", a.get("effect", "?")) if isinstance(a, dict) else str(a) for a in added]
        extra = f"<p>Accepted effects: {_e(', '.join(map(str, names)))}</p>"
    return ("<h2>Calibration (held-out error before → after)</h2>" + _img("calibration.png", "calibration") +
            _table(["model"] + [lbl for _, lbl in keys], rows, {1, 2, 3, 4, 5}) + extra)


def verdict_section(v: dict) -> str:
    cls = {"regression": "bad", "no_regression": "good", "inconclusive": "note"}[v["verdict"]]
    rows = [[_e(c["task"]), _e(c["robot"]), _e(c["condition"]), _e(c["split"]), str(c["pairs"]),
             f"{c['baseline'] * 100:.0f}%", f"{c['candidate'] * 100:.0f}%", f"{c['drop']:+.2f}", f"{c['drop_lcb']:+.2f}"]
            for c in v["cells"]]
    last = v["looks"][-1]
    m = last.get("mean")
    bound = f" — drop {m['value']:+.3f}, one-sided bounds [{m['lcb']:+.3f}, {m['ucb']:+.3f}]" if m else ""
    return (f"<h2>Regression gate</h2><p>candidate <b>{_e(v['candidate']['spec'])}</b> vs baseline "
            f"<b>{_e(v['baseline']['spec'])}</b>: <span class='{cls}'>{_e(v['verdict'].replace('_', ' '))}</span>"
            f"{bound} (margin {v['margin']}, {len(v['looks'])} of {len(v['schedule'])} looks)</p>"
            f"<p class='note'>{_e(v['rule'])}</p>" +
            _table(["task", "robot", "condition", "split", "pairs", "baseline", "candidate", "drop", "drop LCB"], rows,
                   {4, 5, 6, 7, 8}))


def build_page(kind: str, doc: dict, tmp: Path, cal: dict | None, verdict: dict | None, title: str | None,
               run_dir: Path | None = None) -> str:
    """Write the figures into `tmp` and return the HTML text."""
    if kind == "run":
        default = f"{doc['suite']['name']} · {doc['policy']['name']} · run {doc['run_id']}"
        prov = doc["provenance"]
        sha = doc["policy"].get("checkpoint_sha256")
        meta = (f"suite {_e(doc['suite']['name'])} v{_e(doc['suite']['version'])} · policy {_e(doc['policy']['name'])}"
                + (f" (checkpoint {_e(sha[:12])})" if sha else "") +
                f" · metric {_e(doc['metric'])} · {doc['counts']['episodes']} episodes ({doc['counts']['errors']} errors)"
                f" · seed {prov.get('seed')} · git {_e(prov.get('git_sha'))} · finished {_e(prov.get('finished_at'))}")
        parts = run_sections(doc, tmp, run_dir)
    else:
        default = "leaderboard"
        meta = (f"{len(doc['entries'])} entries · suites "
                + ", ".join(f"{_e(s['name'])} v{_e(s['version'])}" for s in doc["suites"]))
        parts = leaderboard_sections(doc, tmp)
    if verdict:
        parts.append(verdict_section(verdict))
    if cal:
        parts.append(calibration_section(cal, tmp))
    t = title or default
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{_e(t)}</title><style>{CSS}</style></head>"
            f"<body><h1>{_e(t)}</h1><div class='meta'>{meta}</div>{''.join(parts)}"
            "<p class='meta'>Generated by bench report; intervals are two-sided at the run's confidence level.</p>"
            "</body></html>\n")


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        return 0 if argv else 2
    positional, overrides = config_mod.split_args(argv)
    cfg: ReportConfig = config_mod.build(ReportConfig, overrides)
    if len(positional) != 1:
        raise ConfigError(f"report takes one RUN|LEADERBOARD, got {len(positional)}: {positional}")
    if not cfg.out:
        raise ConfigError("report: out=DIR is required")
    kind, doc, src = load_input(positional[0])
    cal = load_calibration(cfg.calibration) if cfg.calibration else None
    verdict = load_verdict(cfg.verdict) if cfg.verdict else None
    out = Path(cfg.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"out={cfg.out!r} exists and is not a folder")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        run_dir = src.parent if kind == "run" else None
        (tmp / "index.html").write_text(build_page(kind, doc, tmp, cal, verdict, cfg.title, run_dir), encoding="utf-8")
        os.chmod(tmp, 0o755)
        if out.exists():
            old = out.with_name(f".{out.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    figs = sorted(p.name for p in out.glob("*.png"))
    print(f"report of {src} -> {out / 'index.html'} ({', '.join(figs) or 'no figures'})")
    return 0
