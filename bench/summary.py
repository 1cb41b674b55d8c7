"""Records -> summary: per-cell rates, split aggregates, transfer gaps; the terminal table.

The summary is a leaderboard entry: it validates against the shipped JSON Schema
(`bench/schemas/summary-1.json`) and is written atomically (temp file + rename).
It is a pure function of the records plus the run's config, so `bench score RUN`
recomputes exactly what `bench run` wrote.
"""
from __future__ import annotations

import json
import os
import tempfile
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from bench import scoring
from bench.errors import ConfigError, DataError
from bench.records import EPISODES, EpisodeRecord, dedupe, read_records

SCHEMA_ID = "bench.summary/1"
METRICS = ("success_once", "success_at_end")


def _cells(records: list[EpisodeRecord]) -> dict[tuple, list[EpisodeRecord]]:
    groups: dict[tuple, list[EpisodeRecord]] = defaultdict(list)
    for r in records:
        groups[(r.task, r.robot, r.env, r.split, r.condition)].append(r)
    for key in groups:
        groups[key].sort(key=lambda r: r.episode)
    return dict(sorted(groups.items(), key=lambda kv: (kv[0][4] != "nominal", kv[0][4], kv[0][3], kv[0][0], kv[0][1], kv[0][2])))


def _outcomes(recs: list[EpisodeRecord], metric: str) -> np.ndarray:
    return np.array([getattr(r, metric) for r in recs if r.error is None], dtype=float)


def build(records: list[EpisodeRecord], *, run_meta: dict[str, Any]) -> dict[str, Any]:
    """The summary dict for `records`; `run_meta` carries run_id, suite, policy, config, provenance."""
    cfg = run_meta["config"]
    n_boot, conf = int(cfg.get("n_boot", 2000)), float(cfg.get("confidence", 0.95))
    records = dedupe(records)
    groups = _cells(records)
    cells_out = []
    for (task, robot, env, split, cond), recs in groups.items():
        ok = [r for r in recs if r.error is None]
        entry: dict[str, Any] = {
            "task": task, "robot": robot, "env": env, "split": split, "condition": cond,
            "n": len(ok), "errors": len(recs) - len(ok),
            "mean_return": round(float(np.mean([r.return_ for r in ok])), 6) if ok else None,
            "mean_length": round(float(np.mean([r.length for r in ok])), 3) if ok else None,
        }
        for m in METRICS:
            k = int(sum(getattr(r, m) for r in ok))
            entry[m] = {"successes": k, **scoring.wilson(k, len(ok), conf).to_dict()}
        cells_out.append(entry)

    rng = np.random.default_rng([int(cfg.get("seed", 0)), 7919])  # scoring draws, seeded from the run seed
    splits_out: dict[str, Any] = {}
    gaps_out: list[dict[str, Any]] = []
    nominal = {k: v for k, v in groups.items() if k[4] == "nominal"}
    for m in METRICS:
        by_split = {s: [_outcomes(v, m) for k, v in nominal.items() if k[3] == s] for s in ("seen", "unseen")}
        for s, cells in by_split.items():
            if not any(len(c) for c in cells):
                continue
            splits_out.setdefault(s, {})[m] = {
                stat: scoring.aggregate(cells, rng, stat, n_boot, conf).to_dict() for stat in ("mean", "iqm")
            }
        g = scoring.gap(by_split["seen"], by_split["unseen"], rng, "mean", n_boot, conf)
        if not any(len(c) for c in by_split["seen"]) and not any(len(c) for c in by_split["unseen"]):
            continue
        gaps_out.append({"kind": "seen-unseen", "metric": m, "statistic": "mean", "reference": "seen",
                         "target": "unseen", **g.to_dict()})

    expected = run_meta.get("expected_episodes")
    n_err = sum(1 for r in records if r.error is not None)
    summary = {
        "schema": SCHEMA_ID,
        "run_id": run_meta["run_id"],
        "suite": run_meta["suite"],
        "policy": run_meta["policy"],
        "metric": cfg.get("metric", "success_once"),
        "confidence": conf,
        "counts": {"episodes": len(records), "errors": n_err, "expected": expected,
                   "complete": expected is not None and len(records) >= expected},
        "cells": cells_out,
        "splits": splits_out,
        "gaps": gaps_out,
        "config": cfg,
        "provenance": run_meta["provenance"],
    }
    if any(r.condition != "nominal" for r in records):
        from bench.sensitivity import sensitivity  # per-axis gaps to nominal, paired by seed

        summary["sensitivity"] = sensitivity(records, rng, n_boot=n_boot, confidence=conf)
    return summary


_UMASK = os.umask(0o022)
os.umask(_UMASK)  # read the process umask (set and restored at import)


def write_atomic(path: Path, obj: Any) -> None:
    """Write JSON (indented, no NaN) to `path` atomically: see `write_text_atomic`."""
    write_text_atomic(path, json.dumps(obj, indent=2, sort_keys=False, allow_nan=False) + "\n")


def write_text_atomic(path: Path, text: str) -> None:
    """Write `text` to `path` via a temp file in the same folder + fsync + rename (never a half-written file)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
            os.fchmod(fh.fileno(), 0o666 & ~_UMASK)  # mkstemp makes 0600; give what open() would
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def fmt_estimate(est: dict | None, pct: bool = True) -> str:
    """An estimate {"value", "ci"} as text: `82% [70, 91]`, or `+0.120 [+0.010, +0.230]` with pct=False."""
    if not est or est.get("value") is None:
        return "n/a"
    v, ci = est["value"], est.get("ci")
    if pct:
        return f"{v * 100:.0f}% [{ci[0] * 100:.0f}, {ci[1] * 100:.0f}]" if ci else f"{v * 100:.0f}%"
    return f"{v:+.3f} [{ci[0]:+.3f}, {ci[1]:+.3f}]" if ci else f"{v:+.3f}"


def render(summary: dict[str, Any], console=None) -> None:
    """Print the per-cell table, the split aggregates and the gaps."""
    from rich.console import Console
    from rich.table import Table

    console = console or Console(width=None if Console().is_terminal else 120)
    conf = int(round(summary.get("confidence", 0.95) * 100))
    t = Table(title=f"{summary['suite']['name']} · policy {summary['policy']['name']} · run {summary['run_id']}",
              title_justify="left")
    show_env = len({c.get("env") for c in summary["cells"]}) > 1  # e.g. scenes: rows differ only by env
    for col in ("task", "robot", *(("env",) if show_env else ()), "split", "condition", "n",
                f"success once [{conf}% Wilson]", f"success at end [{conf}% Wilson]", "err"):
        t.add_column(col, justify="right" if col in ("n", "err") else "left")
    for c in summary["cells"]:
        t.add_row(c["task"], c["robot"], *((str(c.get("env")),) if show_env else ()), c["split"], c["condition"],
                  str(c["n"]), fmt_estimate(c["success_once"]), fmt_estimate(c["success_at_end"]), str(c["errors"]) if c["errors"] else "")
    console.print(t)
    if summary["splits"]:
        a = Table(title=f"aggregates over nominal cells (mean of cell rates, {conf}% stratified bootstrap)",
                  title_justify="left")
        for col in ("split", "success once", "success at end", "IQM once"):
            a.add_column(col)
        for s, v in summary["splits"].items():
            a.add_row(s, fmt_estimate(v.get("success_once", {}).get("mean")), fmt_estimate(v.get("success_at_end", {}).get("mean")),
                      fmt_estimate(v.get("success_once", {}).get("iqm")))
        console.print(a)
    if summary["gaps"]:
        g_t = Table(title=f"transfer gaps (reference − target, {conf}% bootstrap)", title_justify="left")
        for col in ("gap", "metric", "value [CI]"):
            g_t.add_column(col)
        for g in summary["gaps"]:
            g_t.add_row(f"{g['reference']} → {g['target']}", g["metric"], fmt_estimate(g, pct=False) if g.get("value") is not None
                        else f"n/a ({g.get('reason')})")
        console.print(g_t)
    if summary.get("sensitivity"):
        from bench.sensitivity import render as render_sensitivity

        render_sensitivity(summary["sensitivity"], console)
    counts = summary["counts"]
    if counts["errors"]:
        console.print(f"[yellow]{counts['errors']} episode(s) errored or timed out; see 'error' in episodes.jsonl[/]")


def load_run(run_dir: Path) -> tuple[list[EpisodeRecord], dict[str, Any]]:
    """Records and stored run metadata of a run directory."""
    run_dir = Path(run_dir)
    meta_path = run_dir / "run.json"
    if not meta_path.exists():
        raise DataError(f"{meta_path}: missing; is {run_dir} a run directory written by `bench run`?")
    try:
        meta = json.loads(meta_path.read_text())
    except json.JSONDecodeError as exc:
        raise DataError(f"{meta_path}: not valid JSON ({exc})") from None
    return read_records(run_dir / EPISODES), meta


def main_score(argv: list[str]) -> int:
    """`bench score RUN_DIR`: recompute summary.json from episodes.jsonl and print the table."""
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: bench score RUN_DIR\n\nRecomputes RUN_DIR/summary.json from RUN_DIR/episodes.jsonl (the records are\n"
              "the source of truth) and prints the table.")
        return 0 if argv else 2
    if len(argv) != 1:
        raise ConfigError(f"score takes one RUN_DIR, got {argv}")
    records, meta = load_run(Path(argv[0]))
    summary = build(records, run_meta=meta)
    from bench.leaderboard import validate

    validate(summary)
    write_atomic(Path(argv[0]) / "summary.json", summary)
    render(summary)
    return 0
