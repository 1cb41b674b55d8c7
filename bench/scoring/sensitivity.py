"""Per-axis sensitivity: success under each perturbation level and its gap to nominal, paired by seed.

For every condition (axis, level) of a run: the success rate (success_once and
success_at_end) pooled over the run's cells with a Wilson interval, and the drop
from nominal = rate(nominal) - rate(condition) over the episodes present under both,
paired by (cell, episode index), i.e. the same initial state under both. The drop
carries Tango's paired score interval (`bench.scoring.stats.paired_gap`; a paired bootstrap, episode seeds
resampled jointly across cells, for returns) and an exact McNemar p-value (two-sided binomial
test on the discordant pairs). Entries are computed for all cells pooled
(`scope: "all"`) and, when the run has more than one cell, for each cell.
Entries are JSON-able with no NaN: what cannot be computed is null with a reason.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from bench.core.console import table_console
from bench.records import SUCCESS_METRICS, EpisodeRecord, dedupe
from bench.scoring import stats as scoring
from bench.scoring.rows import cell_row

if TYPE_CHECKING:
    from rich.console import Console

# a cell's completed episodes by their index, per cell key (`task/robot/env`)
Indexed = dict[str, dict[int, EpisodeRecord]]


class McNemar(TypedDict):
    """The exact McNemar test of paired 0/1 outcomes (`mcnemar_exact`)."""

    lost: int  # reference success, target failure
    gained: int  # the reverse
    p_value: float


def mcnemar_exact(ref: np.ndarray, tgt: np.ndarray) -> McNemar:
    """Exact McNemar test on paired 0/1 outcomes.

    Returns {"lost": reference success & target failure, "gained": the reverse,
    "p_value": two-sided binomial p on the discordant pairs (1.0 when there are none)}.
    """
    ref, tgt = np.asarray(ref, bool), np.asarray(tgt, bool)
    lost, gained = int(np.sum(ref & ~tgt)), int(np.sum(~ref & tgt))
    if lost + gained == 0:
        p = 1.0
    else:
        from scipy.stats import binomtest  # scipy: loaded only when this estimate is computed

        p = float(binomtest(lost, lost + gained, 0.5).pvalue)
    return {"lost": lost, "gained": gained, "p_value": round(min(1.0, p), 6)}


def _level_key(level: object) -> tuple[int, float, float]:
    if isinstance(level, (int, float)):
        return (0, float(level), 0.0)
    if isinstance(level, (list, tuple)) and len(level) == 2:
        return (1, float(level[0]), float(level[1]))
    return (2, 0.0, 0.0)


def _param_summary(recs: Sequence[EpisodeRecord]) -> dict[str, dict[str, float]]:
    """min / mean / max of each sampled numeric parameter (what a range actually drew)."""
    values: dict[str, list[float]] = defaultdict(list)
    for r in recs:
        for k, v in (r.params or {}).items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                values[k].append(float(v))
    return {
        k: {"min": round(min(v), 6), "mean": round(float(np.mean(v)), 6), "max": round(max(v), 6)}
        for k, v in sorted(values.items())
    }


def paired_arrays(nominal: Indexed, target: Indexed, metric: str) -> tuple[np.ndarray, np.ndarray]:
    """(cells, episodes) arrays over the cells and episode indices completed under both conditions.

    When every cell has the same set of paired episodes the arrays are rectangular and the
    bootstrap resamples seeds jointly across cells; otherwise pairs are flattened to one row.
    """
    per_cell: dict[str, list[tuple[int, float, float]]] = {}
    for cell, eps in target.items():
        ref_eps = nominal.get(cell, {})
        both = sorted(set(eps) & set(ref_eps))
        if both:
            per_cell[cell] = [(e, float(getattr(ref_eps[e], metric)), float(getattr(eps[e], metric))) for e in both]
    if not per_cell:
        return np.zeros((1, 0)), np.zeros((1, 0))
    episode_sets = {tuple(e for e, _, _ in rows) for rows in per_cell.values()}
    if len(episode_sets) == 1:
        ref = np.array([[a for _, a, _ in rows] for rows in per_cell.values()])
        tgt = np.array([[b for _, _, b in rows] for rows in per_cell.values()])
        return ref, tgt
    rows = [row for cell_rows in per_cell.values() for row in cell_rows]
    return np.array([[a for _, a, _ in rows]]), np.array([[b for _, _, b in rows]])


def _entry(
    cond: str,
    axis: str | None,
    level: float | list[float] | None,
    kind: str,
    scope: dict[str, str],
    recs: list[EpisodeRecord],
    nominal: Indexed,
    target: Indexed,
    rng: np.random.Generator,
    n_boot: int,
    confidence: float,
) -> dict[str, object]:
    head = {"condition": cond, "axis": axis, "level": level, "kind": kind, **scope}
    entry = cell_row(head, recs, confidence, lambda ok: {"params": _param_summary(ok)})
    gap: dict[str, dict[str, object]] = {}
    for m in (*SUCCESS_METRICS, "return"):
        if axis is None:
            gap[m] = {"value": None, "ci": None, "reason": "nominal is the reference", "n_pairs": 0}
            continue
        ref, tgt = paired_arrays(nominal, target, "return_" if m == "return" else m)
        est = scoring.paired_gap(ref, tgt, rng, n_boot=n_boot, confidence=confidence).to_dict()
        if est.get("value") is None:
            est["reason"] = "no episode completed under both nominal and this condition"
        gap[m] = {**est, "n_pairs": int(ref.size)}
        if m != "return":  # success is paired binary: McNemar's exact test beside the interval
            gap[m].update(mcnemar_exact(ref.ravel(), tgt.ravel()))
    entry["drop_vs_nominal"] = gap
    return entry


def sensitivity(
    records: Sequence[EpisodeRecord], rng: np.random.Generator, n_boot: int = 2000, confidence: float = 0.95
) -> list[dict[str, object]]:
    """Per-condition success and paired drop from nominal, pooled over cells and (if several) per cell.

    Args:
        records: a run's episode records (nominal and perturbed conditions).
        rng: generator for the bootstrap (seeded from the run seed by the caller).
        n_boot: bootstrap resamples; confidence: two-sided interval level.

    Returns:
        JSON-able entries, nominal first then by axis and level; `drop_vs_nominal[metric]`
        is nominal minus condition (positive = the perturbation hurts); `drop_vs_nominal["return"]` is the same for the
        episode return (no McNemar test: returns are not binary).
    """
    records = dedupe(records)
    by_cond: dict[str, list[EpisodeRecord]] = defaultdict(list)
    for r in records:
        by_cond[r.condition].append(r)
    if not by_cond:
        return []

    def index(recs: list[EpisodeRecord]) -> Indexed:
        out: dict[str, dict[int, EpisodeRecord]] = defaultdict(dict)
        for r in recs:
            if r.error is None:
                out[f"{r.task}/{r.robot}/{r.env}"][r.episode] = r
        return out

    nominal_idx = index(by_cond.get("nominal", []))
    cells = sorted({(r.task, r.robot, r.env) for r in records})

    def order(cond: str) -> tuple[bool, str, tuple[int, float, float], str]:
        r0 = by_cond[cond][0]
        return (cond != "nominal", r0.axis or "", _level_key(r0.level), cond)

    out: list[dict[str, object]] = []
    for cond in sorted(by_cond, key=order):
        recs = by_cond[cond]
        r0 = recs[0]
        kind = "nominal" if r0.axis is None else ("range" if isinstance(r0.level, list) else "grid")
        target_idx = index(recs)
        out.append(
            _entry(
                cond, r0.axis, r0.level, kind, {"scope": "all"}, recs, nominal_idx, target_idx, rng, n_boot, confidence
            )
        )
        if len(cells) > 1:
            for task, robot, env in cells:
                key = f"{task}/{robot}/{env}"
                cell_recs = [r for r in recs if (r.task, r.robot, r.env) == (task, robot, env)]
                if not cell_recs:
                    continue
                scope = {"scope": "cell", "task": task, "robot": robot, "env": env}
                out.append(
                    _entry(
                        cond,
                        r0.axis,
                        r0.level,
                        kind,
                        scope,
                        cell_recs,
                        {key: nominal_idx.get(key, {})},
                        {key: target_idx.get(key, {})},
                        rng,
                        n_boot,
                        confidence,
                    )
                )
    return out


def _pct(est: dict[str, Any]) -> str:
    if est.get("value") is None:
        return "n/a"
    ci = est.get("ci")
    return f"{est['value'] * 100:.0f}% [{ci[0] * 100:.0f},{ci[1] * 100:.0f}]" if ci else f"{est['value'] * 100:.0f}%"


def _drop(est: dict[str, Any]) -> str:
    if est.get("value") is None:
        return "—"
    ci = est.get("ci")
    text = f"{est['value'] * 100:+.0f} [{ci[0] * 100:.0f},{ci[1] * 100:.0f}]" if ci else f"{est['value'] * 100:+.0f}"
    return f"{text} p={est['p_value']:.2g}"


def _sampled(params: dict[str, Any]) -> str:
    return ", ".join(
        f"{k} {v['min']:.3g}–{v['max']:.3g}" if v["min"] != v["max"] else f"{k} {v['min']:.3g}"
        for k, v in params.items()
    )


def render(entries: Sequence[dict[str, Any]], console: Console | None = None) -> None:  # JSON: summary rows
    """Print the sensitivity table: per condition, success with Wilson intervals and the paired drop
    from nominal (percentage points, bootstrap interval, McNemar p); per-cell rows follow when present."""
    from rich.table import Table  # rich: loaded only when something is drawn on the terminal

    console = console or table_console()
    if not entries:
        return
    t = Table(
        title="sensitivity: success per condition and drop from nominal "
        "(paired by seed; drop in points, Tango score CI, exact McNemar p)",
        title_justify="left",
    )
    # tasks without a success predicate (most Gymnasium control tasks): the return is the score
    show_return = all(e["success_once"]["successes"] == 0 for e in entries)
    many_cells = any(e.get("scope") == "cell" for e in entries)
    cols = ["condition"] + (["cell"] if many_cells else []) + ["n", "success once"]
    cols += ["mean return", "return drop [CI]"] if show_return else ["drop once", "success at end", "drop at end"]
    show_sampled = any(e.get("kind") == "range" for e in entries)  # a grid's value is its level
    for col in cols + (["sampled"] if show_sampled else []):
        t.add_column(col, justify="right" if col == "n" else "left")
    cell_rows = sorted(
        (e for e in entries if e.get("scope") == "cell"), key=lambda e: (e.get("task"), e.get("robot"), e.get("env"))
    )
    for e in [e for e in entries if e.get("scope") == "all"] + cell_rows:
        d = e["drop_vs_nominal"]
        row = [e["condition"]]
        if many_cells:
            row.append(
                "all"
                if e.get("scope") == "all"
                else str(e.get("robot") if e.get("robot") != "default" else e.get("task"))
            )
        row += [str(e["n"]), _pct(e["success_once"])]
        if show_return:
            r = d["return"]
            ret = "n/a" if e.get("mean_return") is None else f"{e['mean_return']:.4g}"
            drop = (
                "—"
                if r.get("value") is None
                else (
                    f"{r['value']:+.4g} [{r['ci'][0]:+.4g}, {r['ci'][1]:+.4g}]" if r.get("ci") else f"{r['value']:+.4g}"
                )
            )
            row += [ret, drop]
        else:
            row += [_drop(d["success_once"]), _pct(e["success_at_end"]), _drop(d["success_at_end"])]
        t.add_row(*row, *([_sampled(e.get("params", {}))] if show_sampled else []))
    console.print(t)
