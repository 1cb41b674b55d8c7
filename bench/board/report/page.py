"""`bench report RUN|LEADERBOARD|SWEEP out=DIR`: a static HTML page with matplotlib figures.

For a run (a run directory or its summary.json): the sentence `bench run` ends with on how to
read the transfer gap; success per task and robot/env with Wilson intervals, seen and unseen
cells side by side; the aggregates table `bench run` prints (split means and IQMs) and the transfer
gaps with their intervals; per-axis sensitivity curves (success against the
perturbation level, pooled and per cell) when the run has perturbed conditions; for a
remote policy (`policy=remote`), the distribution of its round-trip latency per condition.
For a leaderboard: each entry's score, seen and unseen success and gap, ranked.
For a checkpoint sweep (a `bench sweep` folder or its sweep.json, `bench.board.report.sweep`): success
against training step with the simultaneous intervals, the best set and the selection, and the
per-checkpoint leaderboard beside it.
With `calibration=DIR|FILE` (a `bench calibrate` output with calibration.json,
schema `bench.calibration/1`): held-out error before/after calibration (nominal,
declared fit, final) as a table and bars. With `verdict=FILE` (a `bench regress`
verdict): the per-cell paired comparison. Given a run directory, the page also embeds the
run's episode videos (`bench run video=N`) in the cell table, next to their cell, and a
per-axis robustness table (`bench.scoring.robustness`: each axis' levels pooled, drop from nominal).

Everything is read and validated before anything is written; figures are PNGs
next to index.html, so the folder can be published as it is (CI artifact, Pages).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from bench.board.report.figures import (
    fig_calibration,
    fig_cells,
    fig_curves,
    fig_leaderboard,
    fig_sensitivity,
    fig_splits_gaps,
)
from bench.board.report.html import CSS, esc, img_tag, rate_cell, return_cell, signed_cell, table_html
from bench.board.report.remote import latency_section
from bench.board.report.sweep import SWEEP_ID, load_sweep, sweep_sections
from bench.core.errors import DataError
from bench.core.io import first_nonfinite
from bench.core.schema import load_json, validate
from bench.records import EPISODES, read_records
from bench.scoring.curves import breaking_sentence
from bench.scoring.robustness import table
from bench.scoring.summary import aggregates, gap_sentence


# -- inputs -------------------------------------------------------------------------------------
def load_input(arg: str) -> tuple[str, dict, Path]:
    """(kind, document, path) for a run dir, summary.json, leaderboard.json, or a sweep folder or its sweep.json
    (kind "sweep": the document is {"sweep": ..., "leaderboard": ... or None}); validated."""
    path = Path(arg)
    if path.is_dir():
        if (path / "sweep.json").is_file() and not (path / "summary.json").is_file():
            path = path / "sweep.json"
        elif not (path / "summary.json").is_file():
            raise DataError(
                f"{path}: no summary.json or sweep.json (is it a run or sweep directory? `bench score {path}` "
                "rebuilds a run's summary)"
            )
        else:
            path = path / "summary.json"
    doc = load_json(path)
    sid = validate(doc, str(path))
    if sid == SWEEP_ID:
        sweep, board = load_sweep(path)
        return "sweep", {"sweep": sweep, "leaderboard": board}, path
    kinds = {"bench.summary/1": "run", "bench.leaderboard/1": "leaderboard"}
    if sid not in kinds:
        raise DataError(f"{path}: schema {sid} cannot be the report's input; give a run, a leaderboard or a sweep")
    return kinds[sid], doc, path


def load_calibration(arg: str) -> dict:
    """A calibration result (calibration.json, schema bench.calibration/1) with errors.nominal/declared/final."""
    path = Path(arg)
    if path.is_dir():
        path = path / "calibration.json"
    doc = load_json(path)
    if not isinstance(doc, dict) or doc.get("schema") != "bench.calibration/1":
        raise DataError(
            f"{path}: not a calibration result (schema {doc.get('schema') if isinstance(doc, dict) else None!r}; "
            "expected bench.calibration/1)"
        )

    nan_at = first_nonfinite(doc)
    if nan_at:
        raise DataError(f"{path}: field {nan_at} is NaN/inf; a calibration result holds finite numbers or null")
    errors = doc.get("errors")
    if not isinstance(errors, dict) or not any(
        isinstance(errors.get(s), dict) for s in ("nominal", "declared", "final")
    ):
        raise DataError(f"{path}: field errors must hold nominal/declared/final error summaries")
    for stage, summary in errors.items():
        for key, value in summary.items() if isinstance(summary, dict) else ():
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
                raise DataError(f"{path}: field errors.{stage}.{key} is {value!r:.40}; valid: a number or null")
    return doc


def load_verdict(arg: str) -> dict:
    doc = load_json(Path(arg))
    sid = validate(doc, arg)
    if sid not in ("bench.regress/1", "bench.regress/2"):
        raise DataError(f"{arg}: schema {sid} is not a regress verdict (bench.regress/1 or /2)")
    return doc


def _records(run_dir: Path | None) -> list:
    """The run's episode records when the report was given a run directory (else none)."""
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
            f"<figure><video controls preload='metadata' width='192' src='videos/{esc(src.name)}' title='{esc(label)}'>"
            f"</video><figcaption class='{'good' if outcome == 'success' else 'bad'}'>{esc(label)}</figcaption></figure>"
        )
    return out


def robustness_section(summary: dict, records: list) -> str:
    """Per-axis robustness table (levels pooled), in the style of robustness benchmarks."""
    if not records or not any(r.axis for r in records):
        return ""
    metric = summary["metric"] if summary["metric"] != "return" else "success_once"
    conf = float(summary.get("confidence", 0.95) or 0.95)
    rows = []
    for row in table(records, metric, np.random.default_rng(0), confidence=conf):
        rel = row["relative_drop"]
        rows.append(
            [
                esc(row["axis"]),
                esc(row["kind"]),
                esc(", ".join(row["levels"])),
                str(row["pairs"]),
                f"{row['nominal'] * 100:.0f}%" if row["nominal"] is not None else "n/a",
                f"{row['perturbed'] * 100:.0f}%" if row["perturbed"] is not None else "n/a",
                signed_cell(row["drop"]),
                f"{rel * 100:+.0f}%" if rel is not None else "n/a",
            ]
        )
    return (
        "<h2>Robustness per axis</h2>"
        + table_html(
            ["axis", "kind", "conditions", "pairs", f"nominal {metric}", "perturbed", "drop [CI]", "relative drop"],
            rows,
            {3, 4, 5, 7},
        )
        + "<p class='note'>Each axis' levels pooled; episodes paired with nominal by cell and seed (same initial "
        "state); drop = nominal − perturbed with Tango's paired score interval; most harmful axis first.</p>"
    )


def interactions_section(entries: list[dict]) -> str:
    """Combined perturbations (`perturb.combine`): each combination's drop against the sum of its single drops."""
    rows = [
        [
            esc(" with ".join(e["parts"])) + (" <b>(all at once)</b>" if e.get("all_at_once") else ""),
            str(e["n"]),
            signed_cell(e["drop"]),
            " + ".join(signed_cell(s) for s in e["single_drops"]) or "n/a",
            signed_cell(e["sum_of_single_drops"]),
            signed_cell(e["interaction"]),
            esc(e["reading"]),
        ]
        for e in entries
    ]
    metric = entries[0]["metric"]
    return (
        "<h2>Combined perturbations</h2>"
        + table_html(
            ["combination", "pairs", "drop [CI]", "single drops", "sum of single drops", "interaction [CI]", "reading"],
            rows,
            {1},
        )
        + f"<p class='note'>Drops of {esc(metric)} from nominal, over the episode seeds completed under nominal, every "
        "part and the combination; interaction = combined drop − sum of single drops (paired bootstrap over "
        "seeds). Above 0: the axes compound; below 0: less than additive (or success hit its floor).</p>"
    )


def run_sections(summary: dict, tmp: Path, run_dir: Path | None = None) -> list[str]:
    metric = summary["metric"]
    records = _records(run_dir)
    videos = _videos(records, run_dir, tmp)
    sentence = gap_sentence(summary)  # how to read the gap: the console's last line, the page's first
    parts = [f"<p><b>{esc(sentence)}</b></p>"] if sentence else []
    if fig_cells(summary, tmp / "cells.png"):
        what = "mean return with bootstrap intervals" if metric == "return" else f"{esc(metric)} with Wilson intervals"
        parts.append(
            f"<h2>{'Return' if metric == 'return' else 'Success'} per cell</h2>"
            + img_tag("cells.png", "score per cell")
            + f"<p class='note'>Nominal cells; bars are {what}, "
            "<span class='seen'>seen</span> then <span class='unseen'>unseen</span>.</p>"
        )
    figure = fig_splits_gaps(summary, tmp / "gaps.png")
    agg = aggregates(summary)  # the table `bench run` prints, from its owner
    if figure or agg:
        rows = [
            [
                f"{esc(g['reference'])} → {esc(g['target'])}",
                esc(g["metric"]),
                esc(g.get("statistic", "mean")),
                signed_cell(g),
            ]
            for g in summary["gaps"]
        ]
        parts.append(
            "<h2>Splits and transfer gaps</h2>"
            + (img_tag("gaps.png", "splits and gaps") if figure else "")
            + (
                f"<p class='note'>{esc(agg[0].capitalize())}</p>"
                + table_html(agg[1], [[esc(c) for c in r] for r in agg[2]])
                if agg
                else ""
            )
            + (table_html(["gap", "metric", "statistic", "value [CI]"], rows) if rows else "")
        )
    axes = fig_sensitivity(summary, tmp / "sensitivity.png")
    if axes:
        rows = []
        for e in summary["sensitivity"]:
            if e.get("scope") != "all" or e.get("axis") is None:
                continue
            d = e["drop_vs_nominal"][metric]
            rows.append(
                [
                    esc(e["axis"]),
                    esc(e["level"]),
                    str(e["n"]),
                    rate_cell(e[metric]),
                    signed_cell(d),
                    f"{d.get('lost', '')}/{d.get('gained', '')}",
                    esc(d.get("p_value", "")),
                ]
            )
        parts.append(
            "<h2>Sensitivity per perturbation axis</h2>"
            + img_tag("sensitivity.png", "sensitivity")
            + table_html(["axis", "level", "n", metric, "drop vs nominal [CI]", "lost/gained", "McNemar p"], rows, {2})
        )
    if fig_curves(summary, tmp / "curves.png"):
        parts.append(
            "<h2>Where the policy breaks</h2><p>Success against a factor drawn per episode, fitted (logistic, with a "
            "bootstrap band); the dashed line is half of nominal success, the vertical line where the fitted curve "
            "crosses it, the shaded span its interval.</p>"
            + img_tag("curves.png", "curves")
            + "".join(f"<p>{esc(breaking_sentence(c))}</p>" for c in summary["curves"])
        )
    robust = robustness_section(summary, records)
    if robust:
        parts.append(robust)
    if summary.get("interactions"):
        parts.append(interactions_section(summary["interactions"]))

    section = latency_section(summary, tmp)  # remote policies: the run's round-trip latency distribution
    if section:
        parts.append(section)
    by_return = metric == "return"
    rows = [
        [
            esc(c["task"]),
            esc(c["robot"]),
            esc(c["env"]),
            f"<span class='{c['split']}'>{esc(c['split'])}</span>",
            esc(c["condition"]),
            str(c["n"]),
            *([return_cell(c.get("return"))] if by_return else []),
            rate_cell(c["success_once"]),
            rate_cell(c["success_at_end"]),
            str(c["errors"] or ""),
        ]
        + ([" ".join(videos.get((f"{c['task']}/{c['robot']}/{c['env']}", c["condition"]), []))] if videos else [])
        for c in summary["cells"]
    ]
    parts.append(
        "<h2>All cells</h2>"
        + table_html(
            ["task", "robot", "env", "split", "condition", "n", *(["mean return"] if by_return else [])]
            + ["success once", "success at end", "errors"]
            + (["episode videos"] if videos else []),
            rows,
            {5, 6, 9} if by_return else {5, 8},
        )
    )
    return parts


def leaderboard_sections(board: dict, tmp: Path) -> list[str]:
    parts = []
    if fig_leaderboard(board, tmp / "leaderboard.png"):
        parts.append("<h2>Entries</h2>" + img_tag("leaderboard.png", "leaderboard"))
    groups: dict[str, list[dict]] = {}
    for e in board["entries"]:
        groups.setdefault(e["group"], []).append(e)
    for g, es in groups.items():
        rows = []
        by_return = all(e["metric"] == "return" for e in es)
        for e in es:
            m = e["metric"]
            value = return_cell if m == "return" else rate_cell  # a return is in the env's units, not a percentage
            gap = next((x for x in e["gaps"] if x["metric"] == m and x["kind"] == "seen-unseen"), None)
            sha = e["policy"].get("checkpoint_sha256")
            rows.append(
                [
                    str(e["rank"] or "–"),
                    esc(e["policy"]["name"]),
                    esc(sha[:12]) if sha else "–",
                    f"{esc(e['score']['split'] or '')} {value(e['score'])}",
                    value(e["splits"].get("seen", {}).get(m, {}).get("mean")),
                    value(e["splits"].get("unseen", {}).get(m, {}).get("mean")),
                    signed_cell(gap),
                    str(e["counts"]["episodes"]),
                    esc(e["run_id"]),
                ]
            )
        what = "mean return (the env's units)" if by_return else "success"
        parts.append(
            f"<h2>{esc(g)}</h2><p class='note'>Scores are {what}; ranked by the lower bound of the score.</p>"
            + table_html(
                ["#", "policy", "checkpoint", "score", "seen", "unseen", "gap seen−unseen", "episodes", "run"],
                rows,
                {0, 7},
            )
        )
    return parts


def calibration_section(cal: dict, tmp: Path) -> str:
    fig_calibration(cal, tmp / "calibration.png")
    keys = [
        ("one_step_nrmse", "one-step NRMSE"),
        ("k_step_nrmse", "k-step NRMSE"),
        ("free_run_nrmse", "free-run NRMSE"),
        ("free_run_rmse", "free-run RMSE"),
        ("r2", "R²"),
    ]
    rows = []
    for stage in ("nominal", "declared", "final"):
        err = cal["errors"].get(stage)
        if isinstance(err, dict):
            rows.append([stage] + [f"{err[k]:.4g}" if isinstance(err.get(k), (int, float)) else "n/a" for k, _ in keys])
    extra = ""
    added = cal.get("added") or cal.get("accepted")
    if isinstance(added, list) and added:
        names = [a.get("name", a.get("effect", "?")) if isinstance(a, dict) else str(a) for a in added]
        extra = f"<p>Accepted effects: {esc(', '.join(map(str, names)))}</p>"
    return (
        "<h2>Calibration (held-out error before → after)</h2>"
        + img_tag("calibration.png", "calibration")
        + table_html(["model"] + [lbl for _, lbl in keys], rows, {1, 2, 3, 4, 5})
        + extra
    )


def verdict_section(v: dict) -> str:
    cls = {"regression": "bad", "no_regression": "good", "inconclusive": "note", "nothing_measured": "bad"}[
        v["verdict"]
    ]
    rows = [
        [
            esc(c["task"]),
            esc(c["robot"]),
            esc(c["condition"]),
            esc(c["split"]),
            str(c["pairs"]),
            f"{c['baseline'] * 100:.0f}%",
            f"{c['candidate'] * 100:.0f}%",
            f"{c['drop']:+.2f}",
            "n/a" if c["drop_lcb"] is None else f"{c['drop_lcb']:+.2f}",
            "yes" if c.get("regressed") else "",
        ]
        for c in v["cells"]
    ]
    last = v["looks"][-1] if v["looks"] else {}
    m = last.get("mean")
    bound = f" — drop {m['value']:+.3f}, one-sided bounds [{m['lcb']:+.3f}, {m['ucb']:+.3f}]" if m else ""
    named = "".join(
        f"<li>{esc(r['kind'])} <b>{esc(r['name'])}</b>: drop {r['drop']:+.2f} [{r['lcb']:+.2f}, {r['ucb']:+.2f}]</li>"
        for r in v.get("regressed", [])
    )
    return (
        f"<h2>Regression gate</h2><p>candidate <b>{esc(v['candidate']['spec'])}</b> vs baseline "
        f"<b>{esc(v['baseline']['spec'])}</b>: <span class='{cls}'>{esc(v['verdict'].replace('_', ' '))}</span>"
        f"{bound} (margin {v['margin']}, {len(v['looks'])} of {len(v['schedule'])} looks)</p>"
        + (f"<p>Regressed:</p><ul>{named}</ul>" if named else "")
        + (f"<p class='note'>{esc(v['note'])}</p>" if v.get("note") else "")
        + f"<p class='note'>{esc(v['rule'])}</p>"
        + table_html(
            ["task", "robot", "condition", "split", "pairs", "baseline", "candidate", "drop", "drop LCB", "regressed"],
            rows,
            {4, 5, 6, 7, 8},
        )
    )


def build_page(
    kind: str,
    doc: dict,
    tmp: Path,
    cal: dict | None,
    verdict: dict | None,
    title: str | None,
    run_dir: Path | None = None,
) -> str:
    """Write the figures into `tmp` and return the HTML text."""
    if kind == "run":
        default = f"{doc['suite']['name']} · {doc['policy']['name']} · run {doc['run_id']}"
        prov = doc["provenance"]
        sha = doc["policy"].get("checkpoint_sha256")
        meta = (
            f"suite {esc(doc['suite']['name'])} v{esc(doc['suite']['version'])} · policy {esc(doc['policy']['name'])}"
            + (f" (checkpoint {esc(sha[:12])})" if sha else "")
            + f" · metric {esc(doc['metric'])} · {doc['counts']['episodes']} episodes ({doc['counts']['errors']} errors)"
            f" · seed {prov.get('seed')} · git {esc(prov.get('git_sha'))} · finished {esc(prov.get('finished_at'))}"
        )
        parts = run_sections(doc, tmp, run_dir)
    elif kind == "sweep":
        sweep, board = doc["sweep"], doc["leaderboard"]
        default = f"checkpoint sweep · {len(sweep['checkpoints'])} checkpoints · {sweep['metric']}"
        meta = f"selected {esc(sweep['selected'] or 'none')} · best set {esc(', '.join(sweep['best_set']) or 'empty')}"
        parts = sweep_sections(sweep, tmp) + (leaderboard_sections(board, tmp) if board else [])
    else:
        default = "leaderboard"
        meta = f"{len(doc['entries'])} entries · suites " + ", ".join(
            f"{esc(s['name'])} v{esc(s['version'])}" for s in doc["suites"]
        )
        parts = leaderboard_sections(doc, tmp)
    if verdict:
        parts.append(verdict_section(verdict))
    if cal:
        parts.append(calibration_section(cal, tmp))
    t = title or default
    return (
        f"<!doctype html><html><head><meta charset='utf-8'><title>{esc(t)}</title><style>{CSS}</style></head>"
        f"<body><h1>{esc(t)}</h1><div class='meta'>{meta}</div>{''.join(parts)}"
        "<p class='meta'>Generated by bench report; intervals are two-sided at the run's confidence level.</p>"
        "</body></html>\n"
    )
