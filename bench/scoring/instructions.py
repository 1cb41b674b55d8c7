"""Does behaviour depend on the words? Per instruction variant: the action difference and the success drop.

An `instruction` episode records (`bench.execution.rollout`, `extras["instruction"]`) the mean normalised difference
between the actions the policy took under the variant and those a shadow instance of it would have taken with the
true instruction on the same observations (`action_diff`: 0 = the words changed nothing; 1 = a half-range apart on
average), and the share of steps whose actions differ. Scored here per variant, pooled over the run's cells: the
mean action difference with a percentile bootstrap interval over episodes (stratified by cell), and the success drop from
nominal paired by seed (as `bench.scoring.sensitivity` computes it). Summary key `instructions`; no NaN (null with
a reason).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from typing import Any

import numpy as np

from bench.records import EpisodeRecord, dedupe
from bench.scoring import stats as scoring
from bench.scoring.sensitivity import paired_arrays

AXIS = "instruction"  # = bench.sims.perturb.language.NAME (scoring reads records, not the axis table)


def _shadowed(r: EpisodeRecord) -> dict[str, Any] | None:
    """The record's instruction measurement when the episode completed with one, else None."""
    entry = r.extras.get("instruction") if r.error is None else None
    return entry if isinstance(entry, dict) and isinstance(entry.get("action_diff"), (int, float)) else None


def _by_cell(recs: Sequence[EpisodeRecord]) -> dict[str, dict[int, EpisodeRecord]]:
    out: dict[str, dict[int, EpisodeRecord]] = defaultdict(dict)
    for r in recs:
        if r.error is None:
            out[f"{r.task}/{r.robot}/{r.env}"][r.episode] = r
    return out


def _mean_of_cells(
    cells: list[np.ndarray], rng: np.random.Generator, n_boot: int, confidence: float
) -> dict[str, object]:
    """The mean over cells of each cell's mean, with a percentile bootstrap interval (`stats.bootstrap_aggregate`:
    it stays within the values' range, as a difference of actions (>= 0) must)."""
    if not cells:
        return {"value": None, "ci": None, "reason": "no completed episode with a measurement"}
    est = scoring.bootstrap_aggregate(cells, rng, scoring.Boot("mean", n_boot, confidence, binary=False))
    if est.value is None or est.lo is None or est.hi is None:
        return {"value": None, "ci": None, "reason": est.reason or "no completed episode with a measurement"}
    return {"value": round(est.value, 9), "ci": [round(est.lo, 9), round(est.hi, 9)]}


def instructions(
    records: Sequence[EpisodeRecord],
    rng: np.random.Generator,
    metric: str,
    n_boot: int = 2000,
    confidence: float = 0.95,
) -> list[dict[str, object]]:
    """One entry per instruction condition: `variant`, `n` (episodes with a measurement), `action_diff` and
    `steps_differ` (means with stratified bootstrap intervals) and `success_drop` (nominal - variant in `metric`,
    paired by cell and seed, with its interval and `n_pairs`)."""
    records = dedupe(records)
    by_cond: dict[str, list[EpisodeRecord]] = defaultdict(list)
    for r in records:
        by_cond[r.condition].append(r)
    nominal = _by_cell(by_cond.get("nominal", []))
    out: list[dict[str, object]] = []
    for cond, recs in by_cond.items():
        if recs[0].axis != AXIS:
            continue
        measured = [(r, m) for r in recs if (m := _shadowed(r)) is not None]
        entry: dict[str, object] = {
            "condition": cond,
            "variant": str(recs[0].level),
            "metric": metric,
            "n": len(measured),
        }
        for key in ("action_diff", "steps_differ"):
            cells: dict[str, list[float]] = defaultdict(list)
            for r, m in measured:
                cells[f"{r.task}/{r.robot}/{r.env}"].append(float(m.get(key, 0.0)))
            entry[key] = _mean_of_cells([np.asarray(v) for v in cells.values()], rng, n_boot, confidence)
        ref, tgt = paired_arrays(nominal, _by_cell(recs), "return_" if metric == "return" else metric)
        drop = dict(scoring.paired_gap(ref, tgt, rng, n_boot=n_boot, confidence=confidence).to_dict())
        if drop.get("value") is None:
            drop["reason"] = "no episode completed under both nominal and this variant"
        entry["success_drop"] = {**drop, "n_pairs": int(ref.size)}
        out.append(entry)
    return out


def _interval(est: dict[str, Any], pct: bool) -> str:
    if est.get("value") is None:
        return f"n/a ({est.get('reason', 'not measured')})"
    v, ci = est["value"], est.get("ci")
    if pct:
        return f"{v * 100:+.0f} points" + (f" [{ci[0] * 100:+.0f}, {ci[1] * 100:+.0f}]" if ci else "")
    return f"{v:.3f}" + (f" [{ci[0]:.3f}, {ci[1]:.3f}]" if ci else "")


def sentence(entry: dict[str, Any]) -> str:
    """One line per variant, e.g. `with a nonsense instruction the actions differ by 0.412 [0.310, 0.520] (...) and
    success drops +80 points [+60, +100]`."""
    article = "an" if entry["variant"][0] in "aeiou" else "a"
    return (
        f"with {article} {entry['variant']} instruction the actions differ by {_interval(entry['action_diff'], False)} "
        f"(mean |a - a_true| / half-range, {entry['n']} episodes) and "
        f"{'the return' if entry.get('metric') == 'return' else 'success'} drops "
        f"{_interval(entry['success_drop'], entry.get('metric') != 'return')}"
    )
