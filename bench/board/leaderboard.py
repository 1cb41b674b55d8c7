"""Leaderboard files: merging run summaries, ranking, the table.

A leaderboard (`bench.leaderboard/1`) has one entry per policy x checkpoint (sha256)
x suite version (x headline metric x cell selection, for runs limited with robots=,
tasks=, ... and for runs with a suite calibration, `calibration=`), built from run summaries
(`bench.summary/1`) or other leaderboards.
When several runs share that key, the one with the most scored episodes (then the
latest finished) is the entry and the others are listed in its `superseded` field:
runs with different seeds do not pool, since their episodes share job ids. Entries
are ranked within a group — same suite, version, split manifest, headline metric
and selected cells — by the one-sided lower bound of their score (the mean success
on the unseen split, or the seen split when a suite has no unseen cells). Inputs
with the same suite name but another version or manifest are refused: their numbers
do not compare. Nothing is written unless every input is valid.
"""

from __future__ import annotations

import json
from pathlib import Path

from bench.core.console import table_console
from bench.core.errors import DataError
from bench.core.schema import load_json, validate
from bench.protocols.suite import SuiteSpec
from bench.scoring.summary import fmt_estimate
from bench.scoring.typed import Summary

# -- merging ------------------------------------------------------------------------------------
LEADERBOARD_ID = "bench.leaderboard/1"
SELECTION_KEYS = ("robots", "tasks", "envs", "splits", "perturb", "env_id", "horizon")


def _canonical(obj: object) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


def read_input(arg: str) -> tuple[str, dict]:
    """A validated summary or leaderboard document from a run dir, summary.json or leaderboard.json."""
    path = Path(arg)
    if path.is_dir():
        if not (path / "summary.json").is_file():
            raise DataError(
                f"{path}: no summary.json; is it a run directory written by bench run? "
                "(`bench score RUN` rebuilds it from episodes.jsonl)"
            )
        path = path / "summary.json"
    doc = load_json(path)
    sid = validate(doc, str(path))
    if sid not in ("bench.summary/1", LEADERBOARD_ID):
        raise DataError(
            f"{path}: schema {sid} cannot be merged; give run summaries (bench.summary/1) or "
            f"leaderboards ({LEADERBOARD_ID})"
        )
    return str(path), doc


def _score(summary: dict) -> tuple[str | None, dict]:
    """The ranking score: mean success on the unseen split (else seen) for the run's headline metric."""
    metric = summary["metric"]
    for split in ("unseen", "seen"):
        est = summary["splits"].get(split, {}).get(metric, {}).get("mean")
        if est is not None:
            return split, est
    return None, {"value": None, "ci": None, "reason": "no scored nominal cell"}


def _drops(summary: dict) -> list[dict]:
    """Per perturbation condition, pooled over the run's cells: the headline metric and its drop from nominal,
    paired by episode seed, with intervals (copied from the summary's sensitivity table)."""
    metric = summary["metric"]
    out = []
    for row in summary.get("sensitivity") or []:
        if row.get("scope") != "all" or row.get("kind") == "nominal" or metric not in row.get("drop_vs_nominal", {}):
            continue
        rate = {"value": row.get("mean_return"), "ci": None} if metric == "return" else row.get(metric, {})
        out.append(
            {
                "condition": row["condition"],
                "axis": row.get("axis"),
                "level": row.get("level"),
                "n": row.get("n"),
                "value": rate.get("value"),
                "ci": rate.get("ci"),
                "drop": row["drop_vs_nominal"][metric],
            }
        )
    return out


def _breaks(summary: dict) -> list[dict]:
    """Per range condition: where the policy breaks (the factor at half of nominal success) with its interval,
    copied from the summary's curves (`bench.scoring.curves`)."""
    out = []
    for c in summary.get("curves") or []:
        row = {k: c.get(k) for k in ("condition", "axis", "n", "breaks_at", "ci")}
        out.append({**row, **({"reason": c["reason"]} if c.get("reason") else {})})
    return out


def _interactions(summary: dict) -> list[dict]:
    """Per combined condition (`perturb.combine`): its drop, the sum of its parts' single drops and the interaction,
    with intervals, copied from the summary's interactions (`bench.scoring.interactions`)."""
    keys = ("condition", "all_at_once", "metric", "n", "drop", "sum_of_single_drops", "interaction")
    return [{k: e.get(k) for k in keys} for e in summary.get("interactions") or []]


def entry_from_summary(summary: dict, source: str) -> dict:
    """One leaderboard entry from a run summary (scores copied, nothing recomputed), read through the
    typed `Summary` (a field of the wrong type is one line naming it); `drops` when the run perturbed the
    physics or the interface (per axis and level, pooled over cells), `interactions` when it combined axes."""
    split, score = _score(summary)
    typed = Summary.from_json(summary, source)
    cells = sorted(c.key for c in typed.nominal_cells())
    cfg = typed.config
    selection = {k: cfg.get(k) for k in SELECTION_KEYS if cfg.get(k) not in (None, [], {}, 0)}
    prov = summary.get("provenance", {})
    if prov.get("calibration"):  # a calibrated simulator is another simulator: never pooled or ranked with nominal
        cal = prov["calibration"]
        selection["calibration"] = f"{cal['robot']}:{cal['sha256'][:12]}"
    return {
        "policy": summary["policy"],
        "suite": {"name": summary["suite"]["name"], "version": summary["suite"]["version"]},
        "run_id": summary["run_id"],
        "source": source,
        "metric": summary["metric"],
        "confidence": summary["confidence"],
        "score": {"split": split, "statistic": "mean", **score},
        "splits": summary["splits"],
        "gaps": summary["gaps"],
        "counts": summary["counts"],
        "cells": cells,
        "selection": selection,
        "finished_at": prov.get("finished_at"),
        "git_sha": prov.get("git_sha"),
        "superseded": [],
        **({"drops": drops} if (drops := _drops(summary)) else {}),
        **({"curves": curves} if (curves := _breaks(summary)) else {}),
        **({"interactions": inter} if (inter := _interactions(summary)) else {}),
    }


def _entry_key(e: dict) -> tuple:
    # selection and metric too: a Panda-only run must not replace (or be ranked against) a full-suite run
    return (
        e["policy"]["name"],
        e["policy"].get("checkpoint_sha256"),
        e["suite"]["name"],
        e["suite"]["version"],
        e["metric"],
        _canonical(e["selection"]),
    )


def _group_key(e: dict) -> str:
    s = e["suite"]
    sel = ",".join(f"{k}={_canonical(v)}" for k, v in sorted(e["selection"].items()))
    return f"{s['name']} v{s['version']} · {e['metric']}" + (f" · {sel}" if sel else "")


def merge(docs: list[tuple[str, dict]], allow_spec_change: bool = False) -> dict:
    """The leaderboard of validated input documents (summaries and/or leaderboards).

    Runs of one suite must have the same suite spec (`bench.protocols.suite.SuiteSpec`: version,
    split manifest, options, simulator versions) to be ranked together; `allow_spec_change` ranks
    them anyway (options and simulator versions only: another version or manifest never pairs).

    Raises:
        DataError: inputs with the same suite name but another version, split manifest or spec.
    """
    suites: dict[str, dict] = {}
    specs: dict[str, tuple[SuiteSpec, str]] = {}
    entries: list[dict] = []
    for source, doc in docs:
        if doc["schema"] == LEADERBOARD_ID:
            found = [(dict(s), source) for s in doc["suites"]]
            new = [dict(e) for e in doc["entries"]]
        else:
            found = [(dict(doc["suite"]), source)]
            new = [entry_from_summary(doc, source)]
        for suite, src in found:
            old = suites.get(suite["name"])
            if old is None:
                suites[suite["name"]] = {**suite, "_source": src}
            elif old["version"] != suite["version"]:
                raise DataError(
                    f"{src}: suite {suite['name']} v{suite['version']} but {old['_source']} is "
                    f"v{old['version']}; refusing to rank across suite versions"
                )
            elif _canonical(old["manifest"]) != _canonical(suite["manifest"]):
                raise DataError(
                    f"{src}: suite {suite['name']} v{suite['version']} has another split manifest "
                    f"than {old['_source']}; refusing to rank across split manifests"
                )
        if doc["schema"] != LEADERBOARD_ID:  # a run: its spec holds options and simulator versions too
            spec = SuiteSpec.of(doc["suite"], doc.get("provenance", {}).get("packages"))
            seen = specs.get(spec.name)
            if seen is None:
                specs[spec.name] = (spec, source)
            elif (why := seen[0].differs(spec)) and not allow_spec_change:
                raise DataError(
                    f"{source}: {why} (in {seen[1]}): refusing to rank runs of different suite specs "
                    "(allow_spec_change=true ranks them anyway)"
                )
        entries.extend(new)
    by_key: dict[tuple, list[dict]] = {}
    for e in entries:
        by_key.setdefault(_entry_key(e), []).append(e)
    merged = []
    for group in by_key.values():
        group.sort(
            key=lambda e: (e["counts"]["episodes"] - e["counts"]["errors"], e.get("finished_at") or ""), reverse=True
        )
        best = dict(group[0])
        superseded = list(best.get("superseded", []))
        for other in group[1:]:
            superseded += [other["run_id"], *other.get("superseded", [])]
        best["superseded"] = sorted(set(superseded) - {best["run_id"]})
        merged.append(best)
    return {
        "schema": LEADERBOARD_ID,
        "suites": [{k: v for k, v in s.items() if k != "_source"} for _, s in sorted(suites.items())],
        "ranking": "within each group (suite, version, metric, selection): by the lower end of the score's "
        "interval (for 95% intervals a one-sided 97.5% lower bound), then the value",
        "entries": rank(merged),
    }


def rank(entries: list[dict]) -> list[dict]:
    """Entries sorted by group, then by the score's lower bound (descending); `rank` and `group` set."""
    out = []
    groups: dict[str, list[dict]] = {}
    for e in entries:
        groups.setdefault(_group_key(e), []).append(e)
    for g in sorted(groups):

        def order(e: dict) -> tuple:
            sc = e["score"]
            if sc.get("value") is None:
                return (1, 0.0, 0.0, e["policy"]["name"], e["run_id"])
            lo = sc["ci"][0] if sc.get("ci") else sc["value"]
            return (0, -lo, -sc["value"], e["policy"]["name"], e["run_id"])

        ranked = sorted(groups[g], key=order)
        for i, e in enumerate(ranked):
            out.append({**e, "group": g, "rank": i + 1 if e["score"].get("value") is not None else None})
    return out


def render(board: dict, console=None) -> None:
    """Terminal tables, one per group, ranked by the score's lower bound."""
    from rich.table import Table  # rich: loaded only when something is drawn on the terminal

    console = console or table_console()
    groups: dict[str, list[dict]] = {}
    for e in board["entries"]:
        groups.setdefault(e["group"], []).append(e)
    for g, entries in groups.items():
        conf = int(round(entries[0]["confidence"] * 100))
        t = Table(title=f"{g} · ranked by the lower bound of the score ({conf}% intervals)", title_justify="left")
        for col in ("#", "policy", "checkpoint", "score", "seen", "unseen", "gap seen−unseen", "episodes", "run"):
            t.add_column(col, justify="right" if col in ("#", "episodes") else "left")
        for e in entries:
            m = e["metric"]

            def _pct(est, _m=m):  # returns are plain numbers, success rates percentages
                return fmt_estimate(est, pct=_m != "return", signed=False)

            gap = next((x for x in e["gaps"] if x["metric"] == m and x["kind"] == "seen-unseen"), None)
            gap_s = (
                "n/a"
                if not gap or gap.get("value") is None
                else (
                    f"{gap['value']:+.2f} [{gap['ci'][0]:+.2f}, {gap['ci'][1]:+.2f}]"
                    if gap.get("ci")
                    else f"{gap['value']:+.2f}"
                )
            )
            sha = e["policy"].get("checkpoint_sha256")
            c = e["counts"]
            t.add_row(
                str(e["rank"] or "–"),
                e["policy"]["name"],
                sha[:12] if sha else "–",
                f"{e['score']['split'] or ''} {_pct(e['score'])}",
                _pct(e["splits"].get("seen", {}).get(m, {}).get("mean")),
                _pct(e["splits"].get("unseen", {}).get(m, {}).get("mean")),
                gap_s,
                f"{c['episodes'] - c['errors']}" + ("" if c["complete"] else " (incomplete)"),
                e["run_id"],
            )
        console.print(t)
