"""Records -> summary: per-cell rates, split aggregates, transfer gaps; the terminal table.

The summary is a leaderboard entry: it validates against the shipped JSON Schema
(`bench/core/schemas/summary-1.json`) and is written atomically (temp file + rename).
It is a pure function of the records plus the run's config, so `bench score RUN`
recomputes exactly what `bench run` wrote.
"""

from __future__ import annotations

import json
import math
from collections import Counter, defaultdict
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bench.core.config import MAX_N_BOOT
from bench.core.console import table_console
from bench.core.errors import DataError
from bench.protocols.suite import METRICS as ALL_METRICS
from bench.records import (
    EPISODES,
    SUCCESS_METRICS,
    EpisodeRecord,
    dedupe,
    read_records,
)
from bench.remote.latency import run_latency
from bench.scoring import stats as scoring
from bench.scoring.curves import breaking_sentence, curves_of
from bench.scoring.instructions import instructions
from bench.scoring.instructions import sentence as instruction_sentence
from bench.scoring.interactions import interactions
from bench.scoring.interactions import sentence as interaction_sentence
from bench.scoring.rows import cell_row
from bench.scoring.sensitivity import render as render_sensitivity
from bench.scoring.sensitivity import sensitivity
from bench.scoring.typed import Summary
from bench.sims.perturb.combine import SEP

if TYPE_CHECKING:
    from rich.console import Console

SCHEMA_ID = "bench.summary/1"
CellKey = tuple[str, str, str, str, str]  # task, robot, env, split, condition
Row = Mapping[str, object]  # a row of summary.json as it is written (a cell, an estimate, a gap)
SplitsOut = dict[str, dict[str, dict[str, Row]]]  # split -> metric -> statistic -> estimate
EstimateDoc = Mapping[str, Any]  # an estimate as a JSON document holds it: {"value", "ci", "reason"}


def _cells(records: list[EpisodeRecord]) -> dict[CellKey, list[EpisodeRecord]]:
    groups: dict[CellKey, list[EpisodeRecord]] = defaultdict(list)
    for r in records:
        groups[(r.task, r.robot, r.env, r.split, r.condition)].append(r)
    for key in groups:
        groups[key].sort(key=lambda r: r.episode)
    return dict(
        sorted(groups.items(), key=lambda kv: (kv[0][4] != "nominal", kv[0][4], kv[0][3], kv[0][0], kv[0][1], kv[0][2]))
    )


def _outcomes(recs: list[EpisodeRecord], metric: str) -> np.ndarray:
    attr = "return_" if metric == "return" else metric
    return np.array([getattr(r, attr) for r in recs if r.error is None], dtype=float)


CURVE_BOOT = 1000  # bootstrap refits per curve (fewer than the run's n_boot when that is larger: each is a fit)


def build(records: list[EpisodeRecord], *, run_meta: dict[str, Any]) -> Summary:
    """The summary of `records`, typed (`Summary.to_json()` is summary.json); `run_meta` (run.json, checked by
    `check_run_meta`) carries run_id, suite, policy, config, provenance."""
    cfg = run_meta["config"]
    n_boot, conf = int(cfg.get("n_boot", 2000)), float(cfg.get("confidence", 0.95))
    records = dedupe(records)
    groups = _cells(records)
    cells_out = []
    for (task, robot, env, split, cond), recs in groups.items():
        entry = cell_row(
            {"task": task, "robot": robot, "env": env, "split": split, "condition": cond},
            recs,
            conf,
            lambda ok: {"mean_length": round(float(np.mean([r.length for r in ok])), 3) if ok else None},
        )
        cells_out.append(entry)

    rng = np.random.default_rng([int(cfg.get("seed", 0)), 7919])  # scoring draws, seeded from the run seed
    splits_out: SplitsOut = {}
    gaps_out: list[Row] = []
    nominal = {k: v for k, v in groups.items() if k[4] == "nominal"}
    for m in SUCCESS_METRICS:
        by_split = {s: [_outcomes(v, m) for k, v in nominal.items() if k[3] == s] for s in ("seen", "unseen")}
        for s, cells in by_split.items():
            if not any(len(c) for c in cells):
                continue
            splits_out.setdefault(s, {})[m] = {
                stat: scoring.aggregate(cells, rng, scoring.Boot(stat, n_boot, conf)).to_dict()
                for stat in ("mean", "iqm")
            }
        g = scoring.gap(by_split["seen"], by_split["unseen"], rng, scoring.Boot("mean", n_boot, conf))
        if not any(len(c) for c in by_split["seen"]) and not any(len(c) for c in by_split["unseen"]):
            continue
        gaps_out.append(
            {
                "kind": "seen-unseen",
                "metric": m,
                "statistic": "mean",
                "reference": "seen",
                "target": "unseen",
                **g.to_dict(),
            }
        )
    if cfg.get("metric") == "return":  # envs without a success signal are scored by their return
        _score_returns(groups, nominal, cells_out, splits_out, gaps_out, int(cfg.get("seed", 0)), n_boot, conf)

    expected = run_meta.get("expected_episodes")
    n_err = sum(1 for r in records if r.error is not None)
    summary: dict[str, object] = {
        "schema": SCHEMA_ID,
        "run_id": run_meta["run_id"],
        "suite": run_meta["suite"],
        "policy": run_meta["policy"],
        "metric": cfg.get("metric", "success_once"),
        "confidence": conf,
        "counts": {
            "episodes": len(records),
            "errors": n_err,
            "expected": expected,
            "complete": expected is not None and len(records) >= expected,
        },
        "cells": cells_out,
        "splits": splits_out,
        "gaps": gaps_out,
        "config": cfg,
        "provenance": run_meta["provenance"],
    }

    latency = run_latency(records)
    if latency is not None:
        summary["policy_latency"] = latency
    if any(r.condition != "nominal" for r in records):
        summary["sensitivity"] = sensitivity(records, rng, n_boot=n_boot, confidence=conf)
    metric = str(cfg.get("metric", "success_once"))
    if metric != "return" and any("~" in r.condition for r in records):  # ranges: success against the factor
        curve_rng = np.random.default_rng([int(cfg.get("seed", 0)), 7919, 2])  # a generator of their own
        found = curves_of(records, curve_rng, metric, n_boot=min(n_boot, CURVE_BOOT), confidence=conf)
        if found:
            summary["curves"] = found
    if any(SEP in r.condition for r in records):  # perturb.combine: each combination against its parts
        inter_rng = np.random.default_rng([int(cfg.get("seed", 0)), 7919, 3])  # a generator of their own
        summary["interactions"] = interactions(records, inter_rng, metric, n_boot=n_boot, confidence=conf)
    if any(r.axis == "instruction" for r in records):  # perturb.instruction: do the words steer the actions?
        words_rng = np.random.default_rng([int(cfg.get("seed", 0)), 7919, 4])  # a generator of their own
        summary["instructions"] = instructions(records, words_rng, metric, n_boot=n_boot, confidence=conf)
    return Summary.from_json(summary, "summary of " + str(run_meta["run_id"]))


def _score_returns(
    groups: dict[CellKey, list[EpisodeRecord]],
    nominal: dict[CellKey, list[EpisodeRecord]],
    cells_out: list[dict[str, object]],
    splits_out: SplitsOut,
    gaps_out: list[Row],
    seed: int,
    n_boot: int,
    conf: float,
) -> None:
    """Mean return per cell (bootstrap over episodes), per split and the seen-unseen gap (stratified bootstrap).

    Draws from a generator of their own (from the run `seed`), so the success scores of a run are the same
    whatever its metric.
    """
    rng = np.random.default_rng([seed, 7919, 1])
    for entry, recs in zip(cells_out, groups.values()):
        values = _outcomes(recs, "return")
        est = (
            scoring.aggregate([values], rng, scoring.Boot("mean", n_boot, conf, binary=False))
            if len(values)
            else scoring.Estimate(None, reason="no completed episodes")
        )
        entry["return"] = est.to_dict()
    by_split = {s: [_outcomes(v, "return") for k, v in nominal.items() if k[3] == s] for s in ("seen", "unseen")}
    for split, cells in by_split.items():
        if any(len(c) for c in cells):
            splits_out.setdefault(split, {})["return"] = {
                stat: scoring.aggregate(cells, rng, scoring.Boot(stat, n_boot, conf, binary=False)).to_dict()
                for stat in ("mean", "iqm")
            }
    if any(len(c) for c in by_split["seen"]) and any(len(c) for c in by_split["unseen"]):
        g = scoring.gap(by_split["seen"], by_split["unseen"], rng, scoring.Boot("mean", n_boot, conf, binary=False))
        gaps_out.append(
            {
                "kind": "seen-unseen",
                "metric": "return",
                "statistic": "mean",
                "reference": "seen",
                "target": "unseen",
                **g.to_dict(),
            }
        )


def fmt_estimate(est: EstimateDoc | None, pct: bool = True, signed: bool = True) -> str:
    """An estimate {"value", "ci"} as text: `82% [70, 91]`, or `+0.120 [+0.010, +0.230]` with pct=False
    (`-1.2e+03 [...]`-style three significant digits for unsigned values such as returns)."""
    if not est or est.get("value") is None:
        return "n/a"
    v, ci = est["value"], est.get("ci")
    if pct:
        return f"{v * 100:.0f}% [{ci[0] * 100:.0f}, {ci[1] * 100:.0f}]" if ci else f"{v * 100:.0f}%"
    if not signed:
        return f"{v:.4g} [{ci[0]:.4g}, {ci[1]:.4g}]" if ci else f"{v:.4g}"
    return f"{v:+.3f} [{ci[0]:+.3f}, {ci[1]:+.3f}]" if ci else f"{v:+.3f}"


def render(summary: dict[str, Any], console: Console | None = None) -> None:  # summary.json, read by key
    """Print the per-cell table, the split aggregates, the gaps and one sentence on how to read the gap."""
    from rich.table import Table  # rich: loaded only when something is drawn on the terminal

    console = console or table_console()
    conf = int(round(summary.get("confidence", 0.95) * 100))
    by_return = summary.get("metric") == "return"
    cal = (summary.get("provenance") or {}).get("calibration") or {}
    calibrated = cal.get("robot")  # its cells ran the calibrated model: the leaderboard's key, on their rows
    t = Table(
        title=f"{summary['suite']['name']} · policy {summary['policy']['name']} · run {summary['run_id']}"
        + (f" · calibration={calibrated}:{str(cal.get('sha256'))[:12]}" if calibrated else ""),
        title_justify="left",
    )
    show_env = len({c.get("env") for c in summary["cells"]}) > 1  # e.g. scenes: rows differ only by env
    scores = (
        (f"return [{conf}% bootstrap]",)
        if by_return
        else (f"success once [{conf}% Wilson]", f"success at end [{conf}% Wilson]")
    )
    for col in ("task", "robot", *(("env",) if show_env else ()), "split", "condition", "n", *scores, "err"):
        t.add_column(col, justify="right" if col in ("n", "err") else "left")
    for c in summary["cells"]:
        values = (
            (fmt_estimate(c.get("return"), pct=False, signed=False),)
            if by_return
            else (fmt_estimate(c["success_once"]), fmt_estimate(c["success_at_end"]))
        )
        t.add_row(
            c["task"],
            c["robot"],
            *((str(c.get("env")),) if show_env else ()),
            c["split"],
            c["condition"] + (" (calibrated)" if calibrated and c["robot"] == calibrated else ""),
            str(c["n"]),
            *values,
            str(c["errors"]) if c["errors"] else "",
        )
    console.print(t)
    agg = aggregates(summary)
    if agg is not None:
        title, header, rows = agg
        a = Table(title=title, title_justify="left")
        for name in header:
            a.add_column(name)
        for row in rows:
            a.add_row(*row)
        console.print(a)
    gaps = [g for g in summary["gaps"] if (g["metric"] == "return") == by_return]
    if gaps and all(g.get("value") is None for g in gaps) and "unseen" not in summary["splits"]:
        console.print("no held-out (unseen) cell was scored in this run: no seen → unseen transfer gap")
    elif gaps:
        method = "stratified bootstrap" if by_return else "MOVER of stratified Wilson intervals"
        g_t = Table(title=f"transfer gaps (reference − target, {conf}% {method})", title_justify="left")
        for col in ("gap", "metric", "value [CI]"):
            g_t.add_column(col)
        for g in gaps:
            g_t.add_row(
                f"{g['reference']} → {g['target']}",
                g["metric"],
                fmt_estimate(g, pct=False) if g.get("value") is not None else f"n/a ({g.get('reason')})",
            )
        console.print(g_t)
        sentence = gap_sentence(summary)
        if sentence:
            console.print(sentence)
    if summary.get("sensitivity"):
        render_sensitivity(summary["sensitivity"], console)
    for entry in summary.get("curves") or []:
        console.print(breaking_sentence(entry), soft_wrap=True, highlight=False)
    for entry in summary.get("interactions") or []:
        console.print(interaction_sentence(entry), soft_wrap=True, highlight=False)
    for entry in summary.get("instructions") or []:
        console.print(instruction_sentence(entry), soft_wrap=True, highlight=False)
    errored = errored_line(summary)
    if errored:
        console.print(f"[yellow]{errored}[/]", soft_wrap=True)


def aggregates(summary: dict[str, Any]) -> tuple[str, list[str], list[list[str]]] | None:
    """The aggregates table `bench run` prints and `bench report` shows: (title, header, rows of text), one row per
    split: the mean (and IQM) of its nominal cells' rates with stratified Wilson intervals, or returns with
    stratified bootstrap intervals; None when no split was scored."""
    if not summary["splits"]:
        return None
    conf = int(round(summary.get("confidence", 0.95) * 100))
    by_return = summary.get("metric") == "return"
    what = "mean return of cells" if by_return else "mean of cell rates"
    cols = (
        (("return", "return", "mean"), ("IQM return", "return", "iqm"))
        if by_return
        else (
            ("success once", "success_once", "mean"),
            ("success at end", "success_at_end", "mean"),
            ("IQM once", "success_once", "iqm"),
        )
    )
    rows = [
        [s, *[fmt_estimate(v.get(m, {}).get(stat), pct=not by_return, signed=False) for _, m, stat in cols]]
        for s, v in summary["splits"].items()
    ]
    return (
        f"aggregates over nominal cells ({what}, {conf}% stratified {'bootstrap' if by_return else 'Wilson'})",
        ["split", *[name for name, _, _ in cols]],
        rows,
    )


def _cell_label(c: dict[str, Any]) -> str:
    return f"{c['task']}/{c['robot']}/{c['env']}" + ("" if c["condition"] == "nominal" else f" {c['condition']}")


def _listed(labels: list[str], most: int = 8) -> str:
    return ", ".join(labels[:most]) + (f" and {len(labels) - most} more" if len(labels) > most else "")


def errored_line(summary: dict[str, Any]) -> str | None:
    """How many episodes errored or timed out, per cell (None when none did): a partly failed run's last line."""
    cells = [c for c in summary["cells"] if c["errors"]]
    if not cells:
        return None
    counts = summary["counts"]
    per_cell = [f"{_cell_label(c)} {c['errors']} of {c['n'] + c['errors']}" for c in cells]
    return (
        f"{counts['errors']} of {counts['episodes']} episodes errored or timed out ({_listed(per_cell)}); "
        "see 'error' in episodes.jsonl"
    )


def nothing_measured(summary: dict[str, Any], records: list[EpisodeRecord] | None = None) -> str | None:
    """Why the scores of `summary` measure nothing (one line), or None when every cell has a completed episode.

    Nothing is measured when no episode is recorded, when every episode errored, or when a cell has
    no completed episode while others have: its rates would be missing from every aggregate and
    gap, and the rest would read as if the run were whole. With `records`, the line ends with the
    most frequent error of those cells (e.g. a renderer or a policy server that is missing).
    """
    cells = summary["cells"]
    if not cells:
        return "episodes.jsonl holds no episode record"
    empty = [c for c in cells if c["n"] == 0]
    if not empty:
        return None
    if len(empty) == len(cells):
        head = f"no episode completed: all {summary['counts']['episodes']} errored or timed out"
    else:
        head = (
            f"{len(empty)} of {len(cells)} cells completed no episode ({_listed([_cell_label(c) for c in empty])}) "
            "while the others did"
        )
    keys = {(c["task"], c["robot"], c["env"], c["split"], c["condition"]) for c in empty}
    errors = Counter(
        " ".join(str(r.error).split())
        for r in records or []
        if r.error is not None and (r.task, r.robot, r.env, r.split, r.condition) in keys
    )
    if not errors:
        return head
    reason, n = errors.most_common(1)[0]
    total = sum(errors.values())
    return f"{head}; {'error' if n == total else f'most frequent error ({n} of {total})'}: {reason[:400]}"


_HELD_OUT_WORDS = {"robots": "robots", "envs": "environments", "tasks": "tasks"}


def gap_sentence(summary: dict[str, Any]) -> str | None:
    """How to read the headline seen -> unseen gap, in one sentence built from its numbers."""
    metric = summary.get("metric", "success_once")
    g = next((g for g in summary["gaps"] if g["metric"] == metric and g["kind"] == "seen-unseen"), None)
    if g is None or g.get("value") is None or not g.get("ci"):
        return None
    axes = [a for a, split in summary["suite"].get("manifest", {}).items() if split.get("unseen")]
    held = _HELD_OUT_WORDS.get(axes[0], axes[0]) if axes else "cells"
    conf = int(round(summary.get("confidence", 0.95) * 100))
    v, (lo, hi) = g["value"], g["ci"]
    what = "mean return" if metric == "return" else "success rate"
    amount = f"{abs(v):.3g}" if metric == "return" else f"{abs(v) * 100:.0f} points"
    if v == 0:
        size = f"{what} is the same as"
    elif amount == "0 points":  # under half a point: "0 points higher" would read as no difference
        size = f"{what} is less than 1 point {'lower' if v > 0 else 'higher'} than"
    else:
        size = f"{what} is {amount} {'lower' if v > 0 else 'higher'} than"
    where = f"on {held} it never saw, the policy's {size} on the seen ones (gap {fmt_estimate(g, pct=False)})"
    if lo > 0:
        return f"How to read this: {where}; the {conf}% interval excludes 0, so it transfers worse to unseen {held}."
    if hi < 0:
        return f"How to read this: {where}; the {conf}% interval excludes 0, so it does better on unseen {held}."
    return (
        f"How to read this: {where}; the {conf}% interval includes 0, so no transfer gap is detectable at this "
        "many episodes (more episodes narrow it)."
    )


def load_run(run_dir: Path) -> tuple[list[EpisodeRecord], dict[str, Any]]:
    """Records and stored run metadata of a run directory."""
    run_dir = Path(run_dir)
    meta_path = run_dir / "run.json"
    if not meta_path.exists():
        raise DataError(f"{meta_path}: missing; is {run_dir} a run directory written by `bench run`?")
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError, ValueError) as exc:
        raise DataError(f"{meta_path}: not valid JSON ({str(exc).splitlines()[0][:160]})") from None
    if not isinstance(meta, dict):
        raise DataError(f"{meta_path}: expected a JSON object (the run's metadata), found {type(meta).__name__}")
    check_run_meta(meta, str(meta_path))
    return read_records(run_dir / EPISODES), meta


def check_run_meta(meta: dict[str, Any], source: str) -> None:
    """Validate the parts of run.json that scoring reads (types and the runner's own ranges).

    Raises:
        DataError: one line naming run.json, the field, what was found and what is valid.
    """
    for key, typ, valid in (
        ("run_id", str, "a string"),
        ("suite", dict, "an object"),
        ("policy", dict, "an object"),
        ("config", dict, "an object"),
        ("provenance", dict, "an object"),
    ):
        if key not in meta:
            raise DataError(f"{source}: not a bench run.json: field {key!r} missing")
        if not isinstance(meta[key], typ):
            raise DataError(f"{source}: field {key!r} is {meta[key]!r:.60}; valid: {valid}")
    cfg = meta["config"]

    def number(
        key: str,
        lo: float,
        hi: float,
        integer: bool,
        default: float | None,
        lo_open: bool = False,
        hi_open: bool = False,
    ) -> None:
        v = cfg.get(key, default)
        if v is None and default is None:
            return
        kind = "an integer" if integer else "a number"
        if (
            isinstance(v, bool)
            or not isinstance(v, int if integer else (int, float))
            or (isinstance(v, float) and not math.isfinite(v))
        ):
            raise DataError(f"{source}: field config.{key} is {v!r:.60}; valid: {kind}")
        if v < lo or v > hi or (lo_open and v == lo) or (hi_open and v == hi):
            rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
            raise DataError(f"{source}: field config.{key} is {v!r}; valid: {kind} in {rng}")

    number("n_boot", 1, MAX_N_BOOT, True, 2000)
    number("confidence", 0, 1, False, 0.95, lo_open=True, hi_open=True)
    number("seed", 0, 2**63 - 1, True, 0)
    metric = cfg.get("metric")
    if metric is not None and metric not in ALL_METRICS:
        raise DataError(f"{source}: field config.metric is {metric!r:.60}; valid: {', '.join(ALL_METRICS)}")
    exp = meta.get("expected_episodes")
    if exp is not None and (isinstance(exp, bool) or not isinstance(exp, int) or exp < 0):
        raise DataError(f"{source}: field expected_episodes is {exp!r:.60}; valid: an integer >= 0 or null")
